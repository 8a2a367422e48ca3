"""One finger's flashing, as a state machine per node driven by replies.

A :class:`FingerChannel` flashes the nodes of one finger (fmcb, then f2 and f3, which are
reached through the fmcb's running application).  It is written as a generator that yields
the operations it needs — :class:`Send` a request, :class:`Sleep` — and is resumed with each
:class:`Outcome`, so the :mod:`bootloader.batch` driver can run the four fingers at once over
one :class:`~host.hand.session.HandSession` (one request in flight per finger).  Each node's
:class:`NodeReport` carries its explicit :class:`NodeState`; every transition is reported.

A node's path: FORCING (power off → on through the board upstream: the palm for an fmcb,
the fmcb for the phalanges) → HALTING (``bl.halt`` repeated until it answers, within the
autoboot window; a halted node stays in its bootloader for as long as the run needs it) →
INFO (``bl.info``: board, installed header; a node already holding the image, valid and
activated, is skipped unless forced) → WRITING (per block: ``bl.hash`` first — a block that
already verifies is not written again, which is how an interrupted run resumes — then the
pages, each write retried; then the block is hashed again) → VERIFYING (``bl.hash`` of the
whole image) → STAGED → ACTIVATING (``bl.activate``: the node verifies once more) →
BOOTING → CONFIRMING (``identify``: the application runs the requested version) → DONE.
Any failure makes the node FAILED with the reason.  The bootloader itself never boots an
image that does not verify and is not activated, whatever the host does.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Generator
from dataclasses import dataclass, field
from typing import Any, Final

from bootloader.errors import StepFailed
from bootloader.plan import Block, FlashPlan, NodeJob
from protocol.errors import ImageError
from protocol.image import FLASH, BoardType, parse_header
from protocol.messages.boot_program import (
    AUTOBOOT_WINDOW_US,
    BootResult,
    ImageStatus,
    WriteStatus,
)
from protocol.messages.common import Running
from protocol.messages.palm import FingerPower
from protocol.topology import Hop

#: Power off time when forcing a node into its bootloader (s).
POWER_OFF_S: Final = 0.05
#: How long after power-on the host keeps trying to halt autoboot (s); inside the
#: bootloader's :data:`~protocol.messages.boot_program.AUTOBOOT_WINDOW_US`.
HALT_WITHIN_S: Final = 2.5
#: Pause between halt attempts (s).
HALT_RETRY_S: Final = 0.02
#: Attempts of one page write; writes of one block before the block counts as failed.
PAGE_TRIES: Final = 5
BLOCK_TRIES: Final = 3
#: Attempts of a read-only bootloader request (info, hash) and of power switching.
QUERY_TRIES: Final = 3
#: Extra time (ms) a node may take to answer a page write (erase + program + read-back,
#: plus clearing the activation record first) and a hash of the whole image.
WRITE_EXTRA_MS: Final = 12
HASH_EXTRA_MS: Final = 20
#: How long to wait for a booted application to answer identify (s).
CONFIRM_WITHIN_S: Final = 1.0
#: Pause between identify requests to an fmcb powered up to start its application (s).
BOOT_POLL_S: Final = 0.25


#: Why a node refuses to activate a staged image, in words, with what to do.
REFUSALS: Final = {
    ImageStatus.BAD_SIGNATURE: "the image is not signed with the key this node was "
    "provisioned with: sign the images with that key (fwimage build --sign KEY) and check "
    "them first (fwimage inspect IMAGE --key KEY.pub, flash-all-fingers --key KEY.pub)",
    ImageStatus.UNSIGNED: "this node accepts signed images only: build them with "
    "fwimage build --sign KEY",
    ImageStatus.WRONG_BOARD: "the image is built for another board",
    ImageStatus.TOO_LARGE: "the image does not fit this node's application area",
    ImageStatus.HASH_MISMATCH: "the image on the node does not verify: run again (blocks "
    "that verify are kept, the others rewritten)",
}


#: Why a node refuses an image's header page before writing anything, with what to do.
HEADER_REFUSALS: Final = {
    WriteStatus.NOT_FOR_THIS_NODE: "the image is built for another board or load address, "
    "or does not fit this node's application area",
    WriteStatus.BAD_SIGNATURE: REFUSALS[ImageStatus.BAD_SIGNATURE],
}


#: Page-write statuses that end a page's retries: the image refused, or a page it may not
#: write.
PAGE_STOPS: Final = frozenset({*HEADER_REFUSALS, WriteStatus.PAGE_OUT_OF_RANGE,
                               WriteStatus.PAGE_PROTECTED})


def refusal(image_status: int) -> str:
    """``image_status`` (:class:`ImageStatus`) of a refused activation, in words."""
    try:
        status = ImageStatus(image_status)
    except ValueError:
        return f"image status {image_status}"
    return REFUSALS.get(status, f"image {status.name.lower()}")


class NodeState(enum.Enum):
    """Where a node is in its flashing."""

    PENDING = "pending"
    FORCING = "forcing"
    HALTING = "halting"
    INFO = "info"
    WRITING = "writing"
    VERIFYING = "verifying"
    STAGED = "staged"
    ACTIVATING = "activating"
    BOOTING = "booting"
    CONFIRMING = "confirming"
    DONE = "done"
    FAILED = "failed"
    #: The two-slot path (:mod:`bootloader.slot_update`).
    DOWNLOADING = "downloading"
    SWAPPING = "swapping"
    CHECKING = "checking"
    ROLLING_BACK = "rolling back"
    ROLLED_BACK = "rolled back"


@dataclass
class NodeReport:
    """What happened to one node: state, versions, bytes written (B), page/block retries,
    time (s, link clock), result (``flashed``, ``skipped``, ``failed``), error."""

    job: NodeJob
    state: NodeState = NodeState.PENDING
    result: str = "pending"
    version_before: str | None = None
    #: The version of an incomplete image the node held when found (an interrupted flash).
    partly_written: str | None = None
    version: str | None = None
    bytes_written: int = 0
    retries: int = 0
    started: float | None = None
    finished: float | None = None
    error: str | None = None
    wrote: bool = False
    blocks_done: int = 0
    blocks_total: int = 0
    #: ``"two-slot"`` (updated through the slots) or ``"one-slot"`` (flashed in its
    #: bootloader, as a node with an older bootloader must be).
    layout: str = "one-slot"
    #: The node's slots after the run (``slot_update.slot_summary``), two-slot nodes only.
    slots: dict[str, Any] | None = None
    #: Time (s, link clock) the node ran no application because of the update: from its
    #: swap (or its fmcb's) to the first answer of its new application.
    downtime_s: float | None = None
    #: Time (s, link clock) a rollback of the node took, to its previous application.
    rollback_s: float | None = None
    #: Payload SHA-256 of the image the node ran before the update (two-slot nodes).
    previous_sha256: bytes | None = None

    @property
    def seconds(self) -> float:
        """Time spent on the node (s)."""
        if self.started is None:
            return 0.0
        return (self.finished if self.finished is not None else self.started) - self.started

    def to_dict(self) -> dict[str, Any]:
        """The report as plain data (the ``--json`` node object)."""
        return {"finger": self.job.finger, "board": self.job.board.name.lower(),
                "result": self.result, "version_before": self.version_before,
                "partly_written": self.partly_written,
                "version": self.version, "requested": self.job.version,
                "bytes_written": self.bytes_written, "retries": self.retries,
                "seconds": round(self.seconds, 3), "error": self.error,
                "layout": self.layout, "slots": self.slots,
                "downtime_s": None if self.downtime_s is None else round(self.downtime_s, 3),
                "rollback_s": None if self.rollback_s is None else round(self.rollback_s, 3)}


@dataclass(frozen=True)
class Send:
    """Send request ``name`` to ``hop`` of the channel's finger (None: the palm)."""

    name: str
    fields: dict[str, Any] = field(default_factory=dict)
    hop: Hop | None = None
    extra_ms: int = 0


@dataclass(frozen=True)
class Sleep:
    """Let ``seconds`` pass on the link's clock."""

    seconds: float


@dataclass(frozen=True)
class Outcome:
    """A request's reply fields, or the error it ended with."""

    fields: dict[str, Any] | None = None
    error: Exception | None = None


Op = Send | Sleep
Flow = Generator[Op, Outcome, Any]
#: A page write that did not succeed: the status that stopped it (None: no reply last) and
#: the problem, in words.
PageFailure = tuple[int | None, object]


def send_page(report: NodeReport, hop: Hop, name: str, key: str, index: int, data: bytes, *,
              stop_on: frozenset[int], pause_s: float = 0.0
              ) -> Generator[Op, Outcome, PageFailure | None]:
    """Send the page write ``name`` (``{key: index, "data": data}``) to ``hop`` up to
    :data:`PAGE_TRIES` times until the node acknowledges that page with OK; None when it
    did, else what stopped it.  A status in ``stop_on`` stops at once (the caller says
    why); any other retries, after ``pause_s`` (s, link clock).  ``report`` counts the
    retries and the bytes sent."""
    problem: object = None
    status: int | None = None
    for attempt in range(PAGE_TRIES):
        if attempt:
            report.retries += 1
        out = yield Send(name, {key: index, "data": data}, hop, WRITE_EXTRA_MS)
        if out.error is not None or out.fields is None:
            problem, status = out.error, None
            continue
        status = out.fields["status"]
        report.bytes_written += len(data)
        if status == WriteStatus.OK and out.fields[key] == index:
            return None
        problem = f"status {status!r}"
        if status in stop_on:
            break
        if pause_s:
            yield Sleep(pause_s)
    return status, problem


class Channel:
    """What a finger's flashing channel and its slot update share: the finger, its planned
    jobs and their reports, the link's clock (s), state changes and retried requests.

    ``on_change`` is called with a report on every state change."""

    #: States that end a node's part of the run (its report's ``finished`` is set).
    FINISHED: tuple[NodeState, ...] = (NodeState.DONE, NodeState.FAILED, NodeState.STAGED)
    #: Whether a node that ends DONE drops the note of an earlier, retried failure.
    CLEAR_ERROR_WHEN_DONE = True

    def __init__(self, finger: int, plan: FlashPlan, reports: dict[NodeJob, NodeReport],
                 clock: Callable[[], float],
                 on_change: Callable[[NodeReport], None] | None = None) -> None:
        self.finger = finger
        self.plan = plan
        self.jobs = plan.jobs_of(finger)
        self.reports = reports
        self.clock = clock
        self.on_change = on_change

    def _set(self, job: NodeJob, state: NodeState) -> None:
        report = self.reports[job]
        if report.started is None:
            report.started = self.clock()
        report.state = state
        if state in self.FINISHED:
            report.finished = self.clock()
        if state == NodeState.DONE and self.CLEAR_ERROR_WHEN_DONE:
            report.error = None
        if self.on_change is not None:
            self.on_change(report)

    def call(self, name: str, fields: dict[str, Any] | None = None, hop: Hop | None = None,
             *, tries: int = QUERY_TRIES, extra_ms: int = 0,
             report: NodeReport | None = None) -> Flow:
        """Send ``name`` up to ``tries`` times until it is answered; return its fields."""
        out = Outcome()
        for attempt in range(tries):
            out = yield Send(name, dict(fields or {}), hop, extra_ms)
            if out.error is None:
                return out.fields
            if report is not None and attempt + 1 < tries:
                report.retries += 1
        where = "the palm" if hop is None else f"finger {self.finger} {hop.name.lower()}"
        raise StepFailed(f"{name} to {where} failed {tries} times: {out.error}")


class FingerChannel(Channel):
    """Flashes the jobs of one finger (see the module docs).

    ``phase``: ``"all"`` (stage, activate, boot, confirm each node), ``"stage"`` (write and
    verify every node, leave them halted in their bootloaders, phalanges first; an fmcb an
    earlier run left in its bootloader is finished first, as its phalanges are reached only
    through its application), or ``"activate"`` (activate, boot and confirm nodes staged by
    an earlier ``"stage"``).  ``power_state`` is the finger's power when the run began (off:
    powered before its phalanges are reached) and the power to restore after a power cycle.
    """

    def __init__(self, finger: int, plan: FlashPlan, reports: dict[NodeJob, NodeReport],
                 clock: Callable[[], float], *, phase: str = "all",
                 power_state: int = FingerPower.FULL,
                 on_change: Callable[[NodeReport], None] | None = None) -> None:
        super().__init__(finger, plan, reports, clock, on_change)
        self.phase = phase
        self.power_state = power_state if power_state != FingerPower.OFF else FingerPower.FULL
        #: The finger was unpowered when the run began (its fmcb must be powered and boot
        #: before its phalanges can be reached).
        self.unpowered = power_state == FingerPower.OFF
        #: (node, block first page) written and verified in this run (force writes once).
        self.written: set[tuple[BoardType, int]] = set()

    # --- the channel ----------------------------------------------------------------------
    def run(self) -> Flow:
        """The whole channel: the phase's work on every job of the finger."""
        fmcb = next((j for j in self.jobs if j.board == BoardType.FMCB), None)
        phalanges = [j for j in self.jobs if j.board != BoardType.FMCB]
        if self.phase == "all":
            if fmcb is not None:
                yield from self.force_fmcb(fmcb)
                yield from self.stage(fmcb)
                yield from self.activate(fmcb)
            else:
                yield from self.require_fmcb_application(phalanges)
            if phalanges:
                yield from self.force_phalanges(phalanges, cut=fmcb is None)
                for job in phalanges:
                    yield from self.stage(job)
                    yield from self.activate(job)
            else:
                yield from self.call("fmcb.phalange_power", {"on": 1}, Hop.FMCB)
            yield from self.call("fmcb.autopoll", {"on": 1}, Hop.FMCB)
        elif self.phase == "stage":
            if phalanges:
                if fmcb is not None and (yield from self.fmcb_in_bootloader()):
                    # An earlier run stopped after overwriting this fmcb: its old
                    # application is gone, and the phalanges are reached only through an
                    # application, so the fmcb is finished first.
                    yield from self.force_fmcb(fmcb)
                    yield from self.stage(fmcb)
                    yield from self.activate(fmcb)
                else:
                    yield from self.require_fmcb_application(phalanges)
                yield from self.force_phalanges(phalanges, cut=True)
                for job in phalanges:
                    yield from self.stage(job)
            if fmcb is not None and self.reports[fmcb].state != NodeState.DONE:
                yield from self.force_fmcb(fmcb)
                yield from self.stage(fmcb)
        else:
            if fmcb is not None and self.reports[fmcb].state != NodeState.DONE:
                yield from self.activate(fmcb)
                if phalanges:
                    yield from self.force_phalanges(phalanges, cut=False)
            for job in phalanges:
                yield from self.activate(job)
            if fmcb is not None and not phalanges:
                yield from self.call("fmcb.phalange_power", {"on": 1}, Hop.FMCB)
            yield from self.call("fmcb.autopoll", {"on": 1}, Hop.FMCB)

    # --- into the bootloader ------------------------------------------------------------
    def force_fmcb(self, job: NodeJob) -> Flow:
        """Power-cycle the finger through the palm and halt the fmcb's autoboot."""
        self._set(job, NodeState.FORCING)
        off = {"finger": self.finger, "state": FingerPower.OFF, "stagger_ms": 0}
        yield from self.call("palm.finger_power", off)
        yield Sleep(POWER_OFF_S)
        on = {"finger": self.finger, "state": self.power_state, "stagger_ms": 0}
        yield from self.call("palm.finger_power", on)
        yield from self.halt([job])

    def force_phalanges(self, jobs: list[NodeJob], *, cut: bool) -> Flow:
        """Phalange power (off →) on through the fmcb, then halt every phalange of ``jobs``
        (both are halted before either is flashed: no window expires meanwhile)."""
        for job in jobs:
            self._set(job, NodeState.FORCING)
        if cut:
            yield from self.call("fmcb.phalange_power", {"on": 0}, Hop.FMCB)
            yield Sleep(POWER_OFF_S)
        yield from self.call("fmcb.phalange_power", {"on": 1}, Hop.FMCB)
        yield from self.halt(jobs)

    def halt(self, jobs: list[NodeJob]) -> Flow:
        """``bl.halt`` each node until it answers, at most :data:`HALT_WITHIN_S` after its
        power came up."""
        deadline = self.clock() + HALT_WITHIN_S
        for job in jobs:
            self._set(job, NodeState.HALTING)
            while True:
                out = yield Send("bl.halt", {}, job.hop)
                if out.error is None:
                    break
                if self.clock() > deadline:
                    check = ("is the finger on its pogo pins?" if job.board == BoardType.FMCB
                             else "are the finger's tendons (its power and link) intact?")
                    raise StepFailed(f"{job.name} did not answer within {HALT_WITHIN_S} s of "
                                     f"its power-up to enter its bootloader ({check}): "
                                     f"{out.error}")
                yield Sleep(HALT_RETRY_S)

    def fmcb_running(self, jobs: list[NodeJob]) -> Flow:
        """What the finger's fmcb runs (:class:`Running`); a finger unpowered when the run
        began is powered first (``jobs`` FORCING meanwhile), and its fmcb given its autoboot
        window to start."""
        if self.unpowered:
            self.unpowered = False
            for job in jobs:
                self._set(job, NodeState.FORCING)
            on = {"finger": self.finger, "state": self.power_state, "stagger_ms": 0}
            yield from self.call("palm.finger_power", on)
            yield from self.wait_for_fmcb_application()
        who = yield from self.call("identify", {}, Hop.FMCB)
        return Running(who["running"])

    def fmcb_in_bootloader(self) -> Flow:
        """True if the finger's fmcb answers from its bootloader."""
        return (yield from self.fmcb_running(self.jobs)) == Running.BOOTLOADER

    def require_fmcb_application(self, jobs: list[NodeJob]) -> Flow:
        """The phalanges are reached through the fmcb's application: it must be running."""
        if (yield from self.fmcb_running(jobs)) != Running.APPLICATION:
            names = ", ".join(j.name for j in jobs)
            raise StepFailed(f"finger {self.finger} fmcb runs its bootloader, so {names} "
                             "cannot be reached: flash the fmcb too (--fmcb)")

    def wait_for_fmcb_application(self) -> Flow:
        """Ask the fmcb just powered until its application answers, at most its autoboot
        window and :data:`CONFIRM_WITHIN_S` more."""
        deadline = self.clock() + AUTOBOOT_WINDOW_US / 1e6 + CONFIRM_WITHIN_S
        while self.clock() <= deadline:
            yield Sleep(BOOT_POLL_S)
            out = yield Send("identify", {}, Hop.FMCB)
            if out.fields is not None and out.fields["running"] == Running.APPLICATION:
                return

    # --- the node's image ---------------------------------------------------------------
    def stage(self, job: NodeJob) -> Flow:
        """INFO, then (unless it already holds the image) WRITING and VERIFYING: the node
        ends STAGED, halted in its bootloader with the image verified."""
        report = self.reports[job]
        self._set(job, NodeState.INFO)
        info = yield from self.call("bl.info", {}, job.hop, report=report)
        if info["board"] != job.board:
            raise StepFailed(f"{job.name}: the node says it is a {BoardType(info['board']).name}")
        try:
            installed = parse_header(info["header"])
            if report.version_before is None and report.partly_written is None:
                if info["image_status"] == ImageStatus.VALID:
                    report.version_before = str(installed.version)
                else:  # an interrupted flash's header: that version never ran
                    report.partly_written = str(installed.version)
        except ImageError:
            installed = None
        holds = installed is not None and info["header"] == job.image.header.to_bytes()
        if holds and info["image_status"] == ImageStatus.VALID and not self.plan.force:
            if not report.wrote:
                report.result = "skipped"
            self._set(job, NodeState.STAGED)
            return
        blocks = job.blocks()
        report.blocks_total, report.blocks_done = len(blocks), 0
        self._set(job, NodeState.WRITING)
        for block in blocks:
            yield from self.write_block(job, block)
            report.blocks_done += 1
        self._set(job, NodeState.VERIFYING)
        pages = len(job.image.pages())
        got = yield from self.call("bl.hash", {"start_page": FLASH.header_page, "pages": pages},
                                   job.hop, extra_ms=HASH_EXTRA_MS, report=report)
        if got["sha256"] != job.whole_hash():
            raise StepFailed(f"{job.name}: the image does not verify after writing "
                             f"(on-node SHA-256 {got['sha256'].hex()[:16]}…)")
        report.wrote = True
        report.result = "flashed"
        self._set(job, NodeState.STAGED)

    def block_ok(self, job: NodeJob, block: Block) -> Flow:
        """True if the node's pages of ``block`` hash as they should."""
        got = yield from self.call(
            "bl.hash", {"start_page": block.first_page, "pages": len(block.pages)}, job.hop,
            report=self.reports[job])
        return got["status"] == BootResult.OK and got["sha256"] == block.sha256

    def write_block(self, job: NodeJob, block: Block) -> Flow:
        """Write ``block`` unless it already verifies (always once with force), then
        verify it; rewrite up to :data:`BLOCK_TRIES` times."""
        report = self.reports[job]
        forced = self.plan.force and (job.board, block.first_page) not in self.written
        for attempt in range(BLOCK_TRIES + 1):
            if not forced or attempt:
                if (yield from self.block_ok(job, block)):
                    self.written.add((job.board, block.first_page))
                    return
                if attempt:
                    report.retries += 1
            if attempt == BLOCK_TRIES:
                break
            for i, data in enumerate(block.pages):
                yield from self.write_page(job, block.first_page + i, data)
        last = block.first_page + len(block.pages) - 1
        raise StepFailed(f"{job.name}: pages {block.first_page}..{last} do not verify after "
                         f"{BLOCK_TRIES} writes")

    def write_page(self, job: NodeJob, page: int, data: bytes) -> Flow:
        """One page, retried up to :data:`PAGE_TRIES` times (no reply, busy, bad word)."""
        failed = yield from send_page(self.reports[job], job.hop, "bl.write_page", "page", page,
                                      data, stop_on=PAGE_STOPS)
        if failed is None:
            return
        status, problem = failed
        if status in HEADER_REFUSALS:
            booted = yield from self.boot_installed(job)
            then = ("runs it again" if booted else
                    "stays in its bootloader (that image does not verify either)")
            raise StepFailed(f"{job.name}: image refused before anything was written: "
                             f"{HEADER_REFUSALS[WriteStatus(status)]}; the node keeps "
                             f"the image it had and {then}")
        raise StepFailed(f"{job.name}: page {page} not written: {problem}")

    def boot_installed(self, job: NodeJob) -> Flow:
        """Ask a node that refused the new image to start the one it has (``bl.boot``);
        True if it did (a node whose image does not verify leaves ``bl.boot`` unanswered
        and stays in its bootloader)."""
        self._set(job, NodeState.BOOTING)
        out = yield Send("bl.boot", {}, job.hop)
        return out.error is None

    def activate(self, job: NodeJob) -> Flow:
        """ACTIVATING (the node verifies the staged image again), BOOTING, CONFIRMING."""
        report = self.reports[job]
        self._set(job, NodeState.ACTIVATING)
        sha = job.image.header.sha256
        got = yield from self.call("bl.activate", {"sha256": sha}, job.hop,
                                   extra_ms=WRITE_EXTRA_MS, report=report)
        if got["status"] != BootResult.OK:
            raise StepFailed(f"{job.name}: activation refused: {refusal(got['image_status'])}; "
                             "it waits in its bootloader until it gets an image it accepts")
        self._set(job, NodeState.BOOTING)
        yield from self.call("bl.boot", {}, job.hop, report=report)
        self._set(job, NodeState.CONFIRMING)
        deadline = self.clock() + CONFIRM_WITHIN_S
        last: object = None
        while self.clock() <= deadline:
            yield Sleep(0.01)
            out = yield Send("identify", {}, job.hop)
            if out.error is not None or out.fields is None:
                last = out.error
                continue
            v = out.fields["fw_version"]
            version = f"{v['major']}.{v['minor']}.{v['patch']}"
            if out.fields["running"] == Running.APPLICATION:
                report.version = version
                if version != job.version or out.fields["board"] != job.board:
                    raise StepFailed(f"{job.name}: runs {version}, not {job.version}")
                self._set(job, NodeState.DONE)
                return
            last = "still in its bootloader"
        raise StepFailed(f"{job.name}: did not confirm its application: {last}")
