"""A fleet update through the two image slots: no finger is down longer than its swap.

Per finger, one :class:`SlotChannel` (a generator of :class:`~bootloader.node_session.Send` /
:class:`~bootloader.node_session.Sleep`, run by the batch driver, four fingers at once):

* ``probe``: ``slot.info`` to each planned node; a finger any of whose nodes does not answer
  it (a one-slot bootloader, an fmcb in its bootloader, an unpowered finger) is flashed the
  one-slot way, and the report says ``"layout": "one-slot"``.
* ``download``: while the applications keep running, ``slot.hash`` the secondary slot (a
  node already holding the image there is not written again), ``slot.write`` each page
  (retried), then ``slot.hash`` again: the on-node hash must match the file's and the node's
  verdict be VALID.  A node already running the image, confirmed, is skipped.
* ``swap`` (only once every node of the run downloaded): the fmcb first (``slot.swap``: it
  reboots into the new image on trial; its phalanges lose power meanwhile and boot again
  behind it), then f2 and f3.  After each swap the node must answer ``identify`` with the
  new version within :data:`SWAP_WITHIN_S`, pass its self-test (its sensors answer) and
  report TRIAL of the new image; then the host confirms it (``slot.confirm``), unless
  ``keep_trial``.  Each node's downtime is measured on the link's clock, from its swap (or
  its fmcb's) to the first answer of its new application.
* ``rollback``: a node on trial is reset (its bootloader swaps the previous image back);
  a confirmed one is swapped with its secondary slot (which holds the previous image) and
  confirmed.  Phalanges first, then the fmcb.  The fleet's update rolls back every node it
  swapped as soon as one node fails its check, unless ``fleet_rollback`` is off (then only
  the failed node goes back).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from typing import Any, Final

from bootloader.errors import StepFailed
from bootloader.node_session import (
    HEADER_REFUSALS,
    PAGE_STOPS,
    WRITE_EXTRA_MS,
    Channel,
    Flow,
    NodeReport,
    NodeState,
    Send,
    Sleep,
    refusal,
    send_page,
)
from bootloader.plan import FINGER_BOARDS, FlashPlan, NodeJob
from protocol import topology
from protocol.image import BoardType
from protocol.messages.boot_program import AUTOBOOT_WINDOW_US, ImageStatus, WriteStatus
from protocol.messages.common import Running
from protocol.messages.palm import FingerPower
from protocol.messages.slots import ConfirmBy, SlotResult, SlotState
from protocol.topology import Hop

#: How long a swapped node may take to answer from its new application (s): the swap of a
#: full slot (3 × 492 page writes of 2 ms and the records) with margin.
SWAP_WITHIN_S: Final = 5.0
#: How long a node just powered (a finger, or phalanges behind their rebooted fmcb) may
#: take to answer from its application (s, link clock): its autoboot window, twice over
#: (an emulator on a busy machine runs behind the wall clock a serial link is timed by).
PHALANGE_BOOT_WITHIN_S: Final = 2 * AUTOBOOT_WINDOW_US / 1e6
#: Longest wait (s, link clock) for a node that keeps answering from a bootloader still
#: inside its autoboot window by its own clock.
BOOT_GUARD_S: Final = 60.0
#: Beyond the autoboot window, how long a node's bootloader may run before it is no longer
#: taken as booting (µs, the node's clock): a swap of a full slot and the jump.
BOOT_MARGIN_US: Final = 4_000_000
#: Pause between identify polls of a rebooting node (s).
POLL_S: Final = 0.02
#: The self-test after a swap: requests each board's application must answer.
SELF_TEST: Final = {b.board_type: b.self_test for b in topology.FINGER_BOARDS}


def version_text(v: dict[str, int]) -> str:
    """``{"major": 1, "minor": 2, "patch": 3}`` → ``"1.2.3"``."""
    return f"{v['major']}.{v['minor']}.{v['patch']}"


def slot_summary(info: dict[str, Any]) -> dict[str, Any]:
    """The report's ``slots`` object from a ``slot.info`` reply."""
    def image(prefix: str) -> str | None:
        if info[f"{prefix}_status"] == ImageStatus.EMPTY:
            return None
        return version_text(info[f"{prefix}_version"])

    return {"state": SlotState(info["state"]).name.lower(),
            "event": info["event"].name.lower() if hasattr(info["event"], "name")
            else str(info["event"]),
            "primary": image("primary"), "secondary": image("secondary")}


class SlotChannel(Channel):
    """The slot update of one finger's planned nodes (see the module docs).

    ``swapped`` lists the nodes this run swapped (what a fleet rollback undoes).
    """

    FINISHED = (*Channel.FINISHED, NodeState.ROLLED_BACK)
    #: A node done after a retried download keeps the note that it was retried.
    CLEAR_ERROR_WHEN_DONE = False

    def __init__(self, finger: int, plan: FlashPlan, reports: dict[NodeJob, NodeReport],
                 clock: Callable[[], float], *, keep_trial: bool = False,
                 on_change: Callable[[NodeReport], None] | None = None) -> None:
        super().__init__(finger, plan, reports, clock, on_change)
        self.keep_trial = keep_trial
        self.swapped: list[NodeJob] = []
        self.failed_check = False
        #: Nodes found running the new image on trial (an earlier run stopped before it
        #: confirmed them): checked and confirmed without another swap.
        self.on_trial: set[NodeJob] = set()

    # --- probe and download -----------------------------------------------------------------
    def probe(self) -> Flow:
        """True if every planned node of the finger answers ``slot.info`` (two slots)."""
        powered = False
        for job in self.jobs:
            out = yield Send("slot.info", {}, job.hop)
            if out.error is not None:
                out = yield Send("slot.info", {}, job.hop)
            if out.error is not None and job.board != BoardType.FMCB and not powered:
                # Phalanges unpowered (as after the fmcb's power-up): power them, once.
                powered = True
                try:
                    yield from self.call("fmcb.phalange_power", {"on": 1}, Hop.FMCB)
                    yield from self.wait_application(job, PHALANGE_BOOT_WITHIN_S)
                except StepFailed:
                    return False
                out = yield Send("slot.info", {}, job.hop)
            if out.error is not None or out.fields is None:
                return False
            report = self.reports[job]
            report.layout = "two-slot"
            report.slots = slot_summary(out.fields)
            if out.fields["primary_status"] != ImageStatus.EMPTY:
                report.version_before = version_text(out.fields["primary_version"])
        return True

    def download(self) -> Flow:
        """Write and verify every planned node's secondary slot (applications running)."""
        for job in self.jobs:
            yield from self.download_node(job)

    def download_node(self, job: NodeJob) -> Flow:
        report = self.reports[job]
        self._set(job, NodeState.INFO)
        info = yield from self.call("slot.info", {}, job.hop)
        if info["primary_status"] != ImageStatus.EMPTY:
            report.previous_sha256 = info["primary_sha256"]  # what a rollback returns to
        sha = job.image.header.sha256
        if info["state"] == SlotState.TRIAL and info["primary_sha256"] == sha:
            # An earlier run swapped it and stopped before confirming: check it, confirm it.
            self.on_trial.add(job)
            report.result = "staged"
            self._set(job, NodeState.STAGED)
            return
        if info["state"] == SlotState.TRIAL:
            # On trial of another image: its reset swaps the previous one back first.
            yield from self.call("reset", {}, job.hop)
            yield Sleep(POLL_S)
            yield from self.wait_application(job, SWAP_WITHIN_S)
            info = yield from self.call("slot.info", {}, job.hop)
        if (info["primary_sha256"] == sha and info["primary_status"] == ImageStatus.VALID
                and info["state"] == SlotState.CONFIRMED and not self.plan.force):
            report.result = "skipped"
            report.version = job.version
            self._set(job, NodeState.DONE)
            return
        pages = job.image.pages()
        whole = hashlib.sha256(b"".join(pages)).digest()
        self._set(job, NodeState.DOWNLOADING)
        got = yield from self.call("slot.hash", {"pages": len(pages)}, job.hop,
                                   extra_ms=WRITE_EXTRA_MS)
        if got["sha256"] != whole or self.plan.force:
            for index, data in enumerate(pages):
                yield from self.write_page(job, index, data)
            got = yield from self.call("slot.hash", {"pages": len(pages)}, job.hop,
                                       extra_ms=WRITE_EXTRA_MS)
        if got["sha256"] != whole:
            raise StepFailed(f"{job.name}: the secondary slot does not verify after writing "
                             f"(on-node SHA-256 {got['sha256'].hex()[:16]}…)")
        if got["image_status"] != ImageStatus.VALID:
            raise StepFailed(f"{job.name}: the node refuses the image: "
                             f"{refusal(got['image_status'])}")
        report.result = "staged"
        self._set(job, NodeState.STAGED)

    def write_page(self, job: NodeJob, index: int, data: bytes) -> Flow:
        failed = yield from send_page(self.reports[job], job.hop, "slot.write", "index", index,
                                      data, stop_on=PAGE_STOPS, pause_s=POLL_S)
        if failed is None:
            return
        status, problem = failed
        if status in HEADER_REFUSALS:
            raise StepFailed(f"{job.name}: image refused before anything was written: "
                             f"{HEADER_REFUSALS[WriteStatus(status)]}; the node keeps "
                             "running the image it had")
        if status == WriteStatus.PAGE_PROTECTED:
            problem = ("the secondary slot is protected (a trial still runs, or the "
                       "running image was burnt past its slot: flash with --one-slot)")
        raise StepFailed(f"{job.name}: secondary-slot page {index} not written: {problem}; "
                         "the node keeps running the image it had")

    # --- swap, check, confirm ---------------------------------------------------------------
    def swap(self) -> Flow:
        """Swap the fmcb, then the phalanges; check and confirm each (see the module docs).
        Nodes skipped or not staged are left as they are."""
        staged = [j for j in self.jobs if self.reports[j].state == NodeState.STAGED]
        fmcb = next((j for j in staged if j.board == BoardType.FMCB), None)
        phalanges = [j for j in self.jobs if j.board != BoardType.FMCB]
        down_since: float | None = None
        if fmcb is not None:
            down_since = yield from self.swap_node(fmcb)
            if self.failed_check:
                return
            if phalanges:
                yield from self.call("fmcb.phalange_power", {"on": 1}, Hop.FMCB)
                for job in phalanges:
                    yield from self.wait_application(job, PHALANGE_BOOT_WITHIN_S)
                    self.reports[job].downtime_s = self.clock() - down_since
        for job in staged:
            if job.board != BoardType.FMCB:
                yield from self.swap_node(job)
                if self.failed_check:
                    return
        if fmcb is not None:
            yield from self.call("fmcb.autopoll", {"on": 1}, Hop.FMCB)

    def power_up(self) -> Flow:
        """A finger off when the run began: power it (full) and wait for its nodes."""
        for job in self.jobs:
            self._set(job, NodeState.FORCING)  # its time starts with the power-up
        on = {"finger": self.finger, "state": FingerPower.FULL, "stagger_ms": 0}
        yield from self.call_palm("palm.finger_power", on)
        yield from self.wait_for_fingers()

    def call_palm(self, name: str, fields: dict[str, Any]) -> Flow:
        """Send ``name`` to the palm itself, up to :data:`QUERY_TRIES` times."""
        return (yield from self.call(name, fields))

    def wait_for_fingers(self) -> Flow:
        """After a lost power or link: power the finger (and its phalanges) as the run
        found them, and wait for every planned node's application to answer."""
        for job in self.jobs:
            if job.board == BoardType.FMCB:
                yield from self.wait_application(job, PHALANGE_BOOT_WITHIN_S)
        if any(job.board != BoardType.FMCB for job in self.jobs):
            fmcb = NodeJob(self.finger, BoardType.FMCB, self.jobs[0].image)
            yield from self.wait_application(fmcb, PHALANGE_BOOT_WITHIN_S)
            yield from self.call("fmcb.phalange_power", {"on": 1}, Hop.FMCB)
            for job in self.jobs:
                if job.board != BoardType.FMCB:
                    yield from self.wait_application(job, PHALANGE_BOOT_WITHIN_S)

    def wait_application(self, job: NodeJob, within_s: float) -> Flow:
        """Poll ``identify`` until the node's application answers; return its reply.

        Gives up ``within_s`` after the start (link clock), except while the node answers
        from a bootloader whose own clock (``uptime_us``) is still inside its autoboot
        window (or a swap): a link timed by the wall clock to an emulator running behind
        it must not give up on a node that is merely booting, up to :data:`BOOT_GUARD_S`."""
        start = self.clock()
        last: object = None
        booting = False
        while True:
            now = self.clock()
            if now > start + within_s and not (booting and now <= start + BOOT_GUARD_S):
                break
            out = yield Send("identify", {}, job.hop)
            if out.fields is not None and out.fields["running"] == Running.APPLICATION:
                return out.fields
            booting = (out.fields is not None
                       and out.fields["uptime_us"] < AUTOBOOT_WINDOW_US + BOOT_MARGIN_US)
            last = out.error or "still in its bootloader"
            yield Sleep(POLL_S)
        raise StepFailed(f"{job.name}: no application answered within {within_s:g} s: {last}")

    def swap_node(self, job: NodeJob) -> Flow:
        """Swap one node, wait for its new application, check it, confirm it; returns the
        link time the swap began (s).  A failed check sets :attr:`failed_check`."""
        report = self.reports[job]
        self._set(job, NodeState.SWAPPING)
        began = self.clock()
        if job not in self.on_trial:
            got = yield from self.call("slot.swap", {"sha256": job.image.header.sha256,
                                                     "confirm_by": ConfirmBy.HOST}, job.hop,
                                       extra_ms=WRITE_EXTRA_MS)
            if got["status"] != SlotResult.OK:
                raise StepFailed(f"{job.name}: swap refused: {SlotResult(got['status']).name} "
                                 f"({refusal(got['image_status'])})")
            yield Sleep(POLL_S)
        self.swapped.append(job)
        self._set(job, NodeState.CHECKING)
        try:
            who = yield from self.wait_application(job, SWAP_WITHIN_S)
            report.downtime_s = (report.downtime_s or 0.0) + self.clock() - began
            report.version = version_text(who["fw_version"])
            if report.version != job.version or who["board"] != job.board:
                raise StepFailed(f"{job.name}: runs {report.version} after its swap, not "
                                 f"{job.version} (the new image did not start)")
            for name in SELF_TEST[job.board]:
                yield from self.call(name, {}, job.hop)
            info = yield from self.call("slot.info", {}, job.hop)
            report.slots = slot_summary(info)
            if info["state"] != SlotState.TRIAL or info["primary_sha256"] != job.image.header.sha256:
                raise StepFailed(f"{job.name}: not on trial of the new image after its swap "
                                 f"(state {SlotState(info['state']).name})")
        except StepFailed as exc:
            self.failed_check = True
            report.result = "failed"
            report.error = f"failed its check after the swap: {exc}"
            self._set(job, NodeState.FAILED)
            return began
        if not self.keep_trial:
            done = yield from self.call("slot.confirm", {}, job.hop, extra_ms=WRITE_EXTRA_MS)
            if done["status"] != SlotResult.OK:
                raise StepFailed(f"{job.name}: confirmation refused: "
                                 f"{SlotResult(done['status']).name}")
        report.slots = slot_summary((yield from self.call("slot.info", {}, job.hop)))
        report.result = "flashed"
        self._set(job, NodeState.DONE)
        return began

    # --- rollback ---------------------------------------------------------------------------
    def rollback(self, jobs: list[NodeJob]) -> Flow:
        """Put ``jobs``' nodes back on their previous image: phalanges first, then the fmcb."""
        order = sorted(jobs, key=lambda j: -FINGER_BOARDS.index(j.board))
        fmcb_done = False
        for job in order:
            try:
                yield from self.rollback_node(job)
            except StepFailed as exc:  # the others still go back
                report = self.reports[job]
                report.result = "failed"
                report.error = str(exc)
                self._set(job, NodeState.FAILED)
                continue
            fmcb_done = fmcb_done or job.board == BoardType.FMCB
        if fmcb_done:
            yield from self.call("fmcb.phalange_power", {"on": 1}, Hop.FMCB)
            for job in self.jobs:
                if job.board != BoardType.FMCB:  # powered again behind the fmcb's reboot
                    yield from self.wait_application(job, PHALANGE_BOOT_WITHIN_S)
            yield from self.call("fmcb.autopoll", {"on": 1}, Hop.FMCB)

    def rollback_node(self, job: NodeJob) -> Flow:
        """Put one node back on its previous image (one that already went back on its own,
        a trial that did not start, is only checked)."""
        report = self.reports[job]
        failed = report.result == "failed"
        self._set(job, NodeState.ROLLING_BACK)
        info = yield from self.call("slot.info", {}, job.hop)
        began = self.clock()
        back_already = (report.previous_sha256 is not None
                        and info["primary_sha256"] == report.previous_sha256
                        and info["state"] == SlotState.CONFIRMED)
        if back_already:
            target = info["primary_version"]
        elif info["state"] == SlotState.TRIAL:
            target = info["secondary_version"]
            yield from self.call("reset", {}, job.hop)
        else:
            if info["secondary_status"] != ImageStatus.VALID:
                raise StepFailed(f"{job.name}: no previous image to go back to "
                                 f"({refusal(info['secondary_status'])})")
            target = info["secondary_version"]
            got = yield from self.call("slot.swap", {"sha256": info["secondary_sha256"],
                                                     "confirm_by": ConfirmBy.HOST}, job.hop,
                                       extra_ms=WRITE_EXTRA_MS)
            if got["status"] != SlotResult.OK:
                raise StepFailed(f"{job.name}: rollback swap refused: "
                                 f"{SlotResult(got['status']).name}")
        yield Sleep(POLL_S)
        who = yield from self.wait_application(job, SWAP_WITHIN_S)
        report.rollback_s = self.clock() - began
        report.version = version_text(who["fw_version"])
        if report.version != version_text(target):
            raise StepFailed(f"{job.name}: runs {report.version} after its rollback, not "
                             f"{version_text(target)}")
        info = yield from self.call("slot.info", {}, job.hop)
        if info["state"] == SlotState.TRIAL:
            yield from self.call("slot.confirm", {}, job.hop, extra_ms=WRITE_EXTRA_MS)
            info = yield from self.call("slot.info", {}, job.hop)
        report.slots = slot_summary(info)
        if failed:
            report.error = f"{report.error}; back on {report.version}"
        else:
            report.result = "rolled back"
        self._set(job, NodeState.ROLLED_BACK)
