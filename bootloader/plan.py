"""What a flashing run will do, decided and checked before anything is touched.

A :class:`FlashPlan` is a list of :class:`NodeJob` (finger, board, image) and the run's
options.  :func:`make_plan` reads and checks every image file first — it exists, parses
(header CRC, size, SHA-256), is built for the board it is given for, and is signed with
``public_key`` when one is given — so a bad file never leaves a node half-flashed.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from bootloader.errors import FlashError, PlanError
from bootloader.image_files import read_image
from bootloader.signing import signature_ok
from protocol import topology
from protocol.image import FLASH, BoardType, FirmwareImage
from protocol.topology import FINGERS, Hop

#: Boards of a finger module, in the order a finger is flashed: the fmcb first (the
#: phalanges are reached through its running application), then f2 and f3.
FINGER_BOARDS: Final = tuple(b.board_type for b in topology.FINGER_BOARDS)
HOP_OF_BOARD: Final[dict[BoardType, Hop]] = {
    b.board_type: b.hop for b in topology.FINGER_BOARDS if b.hop is not None}
#: Pages hashed and verified together; a re-run skips every block that already verifies.
BLOCK_PAGES: Final = 8


@dataclass(frozen=True)
class Block:
    """A run of pages of an image: first flash page, the pages' bytes, their SHA-256."""

    first_page: int
    pages: tuple[bytes, ...]

    @property
    def sha256(self) -> bytes:
        """What ``bl.hash`` of these pages must answer."""
        return hashlib.sha256(b"".join(self.pages)).digest()


@dataclass(frozen=True)
class NodeJob:
    """Flash ``image`` into the ``board`` of finger ``finger``."""

    finger: int
    board: BoardType
    image: FirmwareImage

    @property
    def hop(self) -> Hop:
        """Where the node sits behind the palm's finger link."""
        return HOP_OF_BOARD[self.board]

    @property
    def name(self) -> str:
        """``"finger 2 f3"``."""
        return f"finger {self.finger} {self.board.name.lower()}"

    @property
    def version(self) -> str:
        """The version the node must run afterwards."""
        return str(self.image.header.version)

    def blocks(self) -> list[Block]:
        """The header page on its own, then the payload's blocks (from page 33 up).

        The header goes first because the node checks it before it erases anything: an
        image for another board, or one its key refuses, is refused while the installed
        image and its activation are still whole, so the node keeps running it.  An
        interrupted run is still safe: the first payload write erases the activation
        record, and a header whose payload is not all there never verifies."""
        pages = self.image.pages()
        first = self.image.header.start_page(FLASH)
        payload = [Block(first + 1 + i, tuple(pages[1 + i : 1 + i + BLOCK_PAGES]))
                   for i in range(0, len(pages) - 1, BLOCK_PAGES)]
        return [Block(first, (pages[0],)), *payload]

    def whole_hash(self) -> bytes:
        """What ``bl.hash`` over all the image's pages must answer."""
        return hashlib.sha256(b"".join(self.image.pages())).digest()


@dataclass(frozen=True)
class FlashPlan:
    """The jobs of one run and its options.

    ``force`` rewrites every page even when the node already holds the image;
    ``all_or_nothing`` stages and verifies every node first and activates only if all
    verified.
    """

    jobs: tuple[NodeJob, ...]
    force: bool = False
    all_or_nothing: bool = False
    #: Update two-slot nodes through their slots (one-slot nodes are flashed as before).
    slots: bool = True
    #: A node failing its check after the swap rolls back every node of the update.
    fleet_rollback: bool = True
    #: Leave the swapped images unconfirmed: the next reset of a node reverts it.
    keep_trial: bool = False

    @property
    def fingers(self) -> list[int]:
        """Fingers the plan touches, in order."""
        return sorted({job.finger for job in self.jobs})

    def jobs_of(self, finger: int) -> list[NodeJob]:
        """The jobs of ``finger``, fmcb first."""
        return sorted((j for j in self.jobs if j.finger == finger),
                      key=lambda j: FINGER_BOARDS.index(j.board))

    def describe(self) -> list[str]:
        """One line per node: what will happen to it."""
        mode = "rewrite all pages" if self.force else "skip if installed, else write what differs"
        if self.slots:
            mode += ("; two-slot nodes: into the secondary slot while running, then swap, "
                     + ("left on trial" if self.keep_trial else "check and confirm")
                     + (", all back if one fails" if self.fleet_rollback
                        else ", a failed node back alone"))
        lines = [f"{job.name}: {job.image.header.app_name} {job.version} "
                 f"({len(job.image.pages())} pages, {job.image.header.image_size} bytes; "
                 f"{mode})" for job in self.jobs]
        if self.all_or_nothing:
            lines.append("all-or-nothing: stage and verify every node, activate only if all did")
        return lines


def make_plan(images: Mapping[BoardType, Path | FirmwareImage], fingers: Sequence[int] = (),
              *, force: bool = False, all_or_nothing: bool = False,
              public_key: bytes | None = None, slots: bool = True,
              fleet_rollback: bool = True, keep_trial: bool = False) -> FlashPlan:
    """Check ``images`` (board → file or image) and make the plan for ``fingers`` (default:
    all).  With ``public_key`` (32 bytes) every image must be signed with it.  Raises
    :class:`PlanError` naming the file and what is wrong."""
    fingers = list(fingers) or list(range(FINGERS))
    bad = [f for f in fingers if not 0 <= f < FINGERS]
    if bad or len(set(fingers)) != len(fingers):
        raise PlanError(f"fingers {fingers}: each must appear once, in 0..{FINGERS - 1}")
    if not images:
        raise PlanError("no image given: pass at least one of --fmcb, --f2, --f3")
    checked: dict[BoardType, FirmwareImage] = {}
    for board, source in images.items():
        if board not in FINGER_BOARDS:
            raise PlanError(f"{board.name.lower()} is not a finger board (fmcb, f2, f3)")
        what = source if isinstance(source, Path) else f"the {board.name.lower()} image"
        try:
            image = source if isinstance(source, FirmwareImage) else read_image(source)
        except FlashError as exc:
            raise PlanError(str(exc)) from exc
        if image.header.board != board:
            raise PlanError(f"{what}: wrong board: built for {image.header.board.name.lower()}, "
                            f"given for {board.name.lower()}; nothing was flashed")
        if public_key is not None:
            if not image.header.signed:
                raise PlanError(f"{what}: unsigned, but the nodes require images signed "
                                f"with the given key; sign it (fwimage build --sign)")
            if not signature_ok(image, public_key):
                raise PlanError(f"{what}: signature does not verify with the given key")
        checked[board] = image
    jobs = tuple(NodeJob(f, board, checked[board]) for f in sorted(fingers)
                 for board in FINGER_BOARDS if board in checked)
    return FlashPlan(jobs, force=force, all_or_nothing=all_or_nothing, slots=slots,
                     fleet_rollback=fleet_rollback, keep_trial=keep_trial)


@dataclass(frozen=True)
class RollbackJob(NodeJob):
    """Put a node back on the image in its secondary slot (its previous one): no file;
    ``image`` is an empty stand-in (:func:`rollback_plan`)."""

    @property
    def version(self) -> str:
        """Whatever the node ran before: not known until it answers."""
        return "previous"


def rollback_plan(fingers: Sequence[int] = ()) -> FlashPlan:
    """Every finger board of ``fingers`` (default all) back to its previous image."""
    fingers = list(fingers) or list(range(FINGERS))
    bad = [f for f in fingers if not 0 <= f < FINGERS]
    if bad or len(set(fingers)) != len(fingers):
        raise PlanError(f"fingers {fingers}: each must appear once, in 0..{FINGERS - 1}")
    jobs = tuple(RollbackJob(f, board, FirmwareImage.build(b"", board, "0.0.0", "rollback"))
                 for f in sorted(fingers) for board in FINGER_BOARDS)
    return FlashPlan(jobs)
