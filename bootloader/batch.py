"""Run a :class:`~bootloader.plan.FlashPlan` on a hand: preflight, four fingers at once.

:func:`run_plan` first checks, touching nothing, that the palm answers and that every finger
of the plan answers (its fmcb, in its application or its bootloader); it reads the nodes'
versions, stops the palm's finger polling for the run (a polled finger sitting in its
bootloader would be declared lost) and restores it at the end.  Then one
:class:`~bootloader.node_session.FingerChannel` per finger runs, all interleaved on the one
:class:`~host.hand.session.HandSession` (each finger has one request in flight; the palm
serves the fingers' links in parallel).  A finger whose flow fails is started again from
its power cycle (:data:`FINGER_ATTEMPTS` in all); blocks already verified are not written
again.  With ``all_or_nothing`` every finger is staged first and activated only if every
node verified; otherwise nothing is activated and the nodes wait in their bootloaders.
"""

from __future__ import annotations

from collections.abc import Callable, Generator, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from typing import Any, Final

from bootloader.errors import PlanError, StepFailed
from bootloader.node_session import (
    FingerChannel,
    NodeReport,
    NodeState,
    Op,
    Outcome,
    Send,
    Sleep,
)
from bootloader.plan import FlashPlan, NodeJob
from bootloader.slot_update import SlotChannel
from host.errors import HostError, NodeError
from host.hand.session import LINK_NODE, HandSession, PendingReply, Target
from protocol.messages.common import Running, TxnStatus
from protocol.messages.palm import FingerPower
from protocol.topology import Hop

#: Runs of one finger's flow in one run (the first, and restarts after a failure).
FINGER_ATTEMPTS: Final = 2
_EPSILON_S: Final = 1e-6


@dataclass
class RunReport:
    """The outcome of a run: one report per node, the run's time (s, link clock), and why
    it stopped early (``stopped``: ``"interrupted"``, the link's error) or None."""

    nodes: list[NodeReport]
    total_seconds: float
    stopped: str | None = None
    #: A ``--rollback`` run: every node must end back on its previous image.
    rollback: bool = False

    @property
    def ok(self) -> bool:
        """Every node ends verified and running the requested version (a rollback: every
        node runs its previous image again)."""
        if self.rollback:
            return self.stopped is None and all(r.result == "rolled back" for r in self.nodes)
        return self.stopped is None and all(
            r.result in ("flashed", "skipped") and r.state == NodeState.DONE
            and r.version == r.job.version for r in self.nodes)

    @property
    def next_step(self) -> str | None:
        """What to do after a run that did not verify every node (None after one that did)."""
        if self.ok:
            return None
        if self.rollback:
            return ("not every node went back: a node on the one-slot layout keeps no "
                    "previous image (flash it with the image you want); for the others fix "
                    "the cause shown and run --rollback again")
        if any(r.result == "rolled back" for r in self.nodes):
            return ("the update was rolled back: the nodes marked 'rolled back' run their "
                    "previous image again, confirmed. Fix the cause shown for the failed "
                    "node and run the same command again (--no-fleet-rollback keeps the "
                    "nodes that passed their check)")
        left: dict[int, list[str]] = {}
        for r in self.nodes:
            if not (r.state == NodeState.DONE and r.version == r.job.version):
                left.setdefault(r.job.finger, []).append(r.job.board.name.lower())
        which = ", ".join(f"finger {f} ({' '.join(b)})" for f, b in left.items())
        return (f"not verified: {which}. A node stopped mid-flash waits in its bootloader "
                "and never boots a partial image: fix the cause shown (a finger off its pogo "
                "pins or unpowered, the link, an image the node refuses), then run the same "
                "command again; it resumes, and blocks that already verify are not rewritten")

    def to_dict(self) -> dict[str, Any]:
        """The ``--json`` object."""
        return {"ok": self.ok, "mode": "rollback" if self.rollback else "update",
                "nodes": [r.to_dict() for r in self.nodes],
                "total_seconds": round(self.total_seconds, 3), "stopped": self.stopped,
                "next_step": self.next_step}


def new_reports(plan: FlashPlan) -> dict[NodeJob, NodeReport]:
    """A pending report for every job of ``plan`` (for :func:`run_plan`'s ``reports``)."""
    return {job: NodeReport(job) for job in plan.jobs}


def settle(reports: dict[NodeJob, NodeReport], started: float, now: float,
           stopped: str | None = None) -> RunReport:
    """The run's report (``started``, ``now``: the link's clock, s): every node not done
    marked failed, with the state it stopped in.  ``stopped`` says why the run ended early
    (a run that raised: Ctrl-C, the link lost)."""
    why = (stopped or "stopped").split(":")[0]  # "link lost: <the error>": said once
    for r in reports.values():
        if r.started is not None and r.finished is None:
            r.finished = now
        if r.state not in (NodeState.DONE, NodeState.ROLLED_BACK) and r.result != "failed":
            r.result = "failed"
            if r.state == NodeState.PENDING:
                r.error = r.error or f"not started ({why})"
            else:
                r.error = r.error or f"{why} in state {r.state.value}"
    return RunReport(list(reports.values()), now - started, stopped)


#: How long preflight keeps asking a powered finger that does not answer (s, on the link's
#: clock): a finger just pushed back on its pogo pins settles its contacts and sits in its
#: bootloader for a few seconds; one that stays silent this long is reported.
ANSWER_WAIT_S: Final = 6.0


#: How long a request of an earlier, interrupted run may still be answered after it ended
#: (s, beyond the link's budget): the palm's longest route, a hash behind the tendon tunnel.
#: Preflight first lets such replies arrive and drops them, so none is taken for the answer
#: to a new request that happens to reuse its sequence number.
STALE_REPLY_S: Final = 0.05


def _identify(session: HandSession, finger: int, hop: Hop) -> dict[str, Any]:
    return session.request("identify", to=Target(finger, hop), retries=2)


def _identify_patiently(session: HandSession, finger: int, hop: Hop) -> dict[str, Any]:
    """identify, asked again until :data:`ANSWER_WAIT_S` has passed on the link's clock."""
    deadline = session.transport.now() + ANSWER_WAIT_S
    while True:
        try:
            return _identify(session, finger, hop)
        except HostError:
            if session.transport.now() >= deadline:
                raise
            session.transport.sleep(0.1)


def _palm_status(session: HandSession) -> dict[str, Any]:
    """``palm.hand_status``, asked again while the palm still runs its bootloader (a hand
    just switched on starts its application after the autoboot window), at most
    :data:`ANSWER_WAIT_S` on the link's clock.  Raises :class:`PlanError`."""
    url = session.transport.url
    deadline = session.transport.now() + ANSWER_WAIT_S
    while True:
        try:
            return session.request("palm.hand_status", retries=2)
        except NodeError as exc:
            if exc.status != TxnStatus.UNKNOWN_TYPE:
                raise PlanError(f"the palm on {url} refused palm.hand_status: {exc}") from exc
            if session.transport.now() >= deadline:
                raise PlanError(
                    f"the palm on {url} runs its bootloader, not its application, "
                    f"{ANSWER_WAIT_S:g} s on (halted there, or its image does not verify): "
                    "switch the hand off and on, wait 5 s and run again; `handctl --port "
                    f"{url} ping` shows what it runs; nothing was touched") from exc
            session.transport.sleep(0.2)
        except HostError as exc:
            raise PlanError(f"the palm does not answer on {url}: {exc}") from exc


def preflight(session: HandSession, plan: FlashPlan,
              reports: dict[NodeJob, NodeReport]) -> dict[str, Any]:
    """Check, touching nothing, that the palm and every planned finger answer; read the
    versions before.  Returns the hand status read.  Raises :class:`PlanError`."""
    session.sleep(session.timeouts.link_s + STALE_REPLY_S)
    status = _palm_status(session)
    for finger in plan.fingers:
        if status["fingers"][finger]["power"] == FingerPower.OFF:
            continue  # unpowered: the power cycle brings it up
        try:
            _identify_patiently(session, finger, Hop.FMCB)
        except HostError as exc:
            others = ",".join(str(f) for f in plan.fingers if f != finger)
            leave_out = f" or leave it out (--fingers {others})" if others else ""
            raise PlanError(f"finger {finger} is not answering (its fmcb got no identify "
                            f"through the palm): {exc}. Push the finger back on its pogo "
                            f"pins{leave_out} and run again; nothing was flashed") from exc
    for job in plan.jobs:
        try:
            who = _identify(session, job.finger, job.hop)
        except HostError:
            continue  # a phalange behind an fmcb in its bootloader: read later by bl.info
        if who["running"] == Running.APPLICATION:
            v = who["fw_version"]
            reports[job].version_before = f"{v['major']}.{v['minor']}.{v['patch']}"
    return status


class Driver:
    """Interleaves channel flows on one session: each yields :class:`Send` / :class:`Sleep`
    and is resumed with the :class:`Outcome`."""

    def __init__(self, session: HandSession) -> None:
        self.session = session

    def run(self, flows: dict[int, Generator[Op, Outcome, Any]],
            on_end: Callable[[int, BaseException | None], None]) -> None:
        """Run ``flows`` (finger → flow) to their ends; ``on_end(finger, error)`` each."""
        waiting: dict[int, PendingReply | float] = {}

        def advance(finger: int, outcome: Outcome | None) -> None:
            flow = flows[finger]
            try:
                op = next(flow) if outcome is None else flow.send(outcome)
            except StopIteration:
                waiting.pop(finger, None)
                on_end(finger, None)
                return
            except (StepFailed, HostError) as exc:
                waiting.pop(finger, None)
                on_end(finger, exc)
                return
            if isinstance(op, Sleep):
                waiting[finger] = self.session.now() + op.seconds
            else:
                waiting[finger] = self._start(finger, op)

        for finger in list(flows):
            advance(finger, None)
        while waiting:
            now = self.session.now()
            wake = min(w if isinstance(w, float) else w.deadline for w in waiting.values())
            if not any(isinstance(w, PendingReply) and w.done for w in waiting.values()):
                self.session.pump(max(0.0, wake - now))
            now = self.session.now()
            for finger, w in list(waiting.items()):
                if isinstance(w, float):
                    if now >= w - _EPSILON_S:
                        advance(finger, Outcome())
                elif w.done or now >= w.deadline - _EPSILON_S:
                    try:
                        outcome = Outcome(self.session.wait(w))
                    except HostError as exc:
                        outcome = Outcome(error=exc)
                    advance(finger, outcome)

    def _start(self, finger: int, op: Send) -> PendingReply:
        to = LINK_NODE if op.hop is None else Target(finger, op.hop)
        return self.session.start(op.name, op.fields, to=to, retries=0, extra_ms=op.extra_ms)


def run_plan(session: HandSession, plan: FlashPlan,
             on_change: Callable[[NodeReport], None] | None = None, *,
             reports: dict[NodeJob, NodeReport] | None = None) -> RunReport:
    """Flash ``plan`` over ``session`` (see the module docs) and report every node.

    ``reports`` (from :func:`new_reports`) is filled in as the run goes, so a caller still
    has every node's state when the run raises (Ctrl-C, the link lost): :func:`settle`."""
    reports = new_reports(plan) if reports is None else reports
    started = session.now()
    status = preflight(session, plan, reports)
    with _palm_poll_paused(session, int(status["poll_hz"])):
        one_slot = list(plan.fingers)
        if plan.slots:
            one_slot = _run_slot_update(session, plan, reports, status, on_change)
        if one_slot:
            plan = replace(plan, jobs=tuple(j for j in plan.jobs if j.finger in one_slot))
            _run_one_slot(session, plan, reports, status, on_change)
    return settle(reports, started, session.now())


@contextmanager
def _palm_poll_paused(session: HandSession, poll_hz: int) -> Iterator[None]:
    """The palm's polling of the fingers off while a run uses their links, and back at
    ``poll_hz`` (Hz; 0: it was off) after it, however the run ends."""
    if poll_hz:
        session.request("palm.poll", {"rate_hz": 0}, retries=2)
    try:
        yield
    finally:
        if poll_hz:
            try:
                session.request("palm.poll", {"rate_hz": poll_hz}, retries=2)
            except HostError:
                pass


def _run_one_slot(session: HandSession, plan: FlashPlan, reports: dict[NodeJob, NodeReport],
                  status: dict[str, Any], on_change: Callable[[NodeReport], None] | None
                  ) -> None:
    """Flash ``plan`` the one-slot way: each node halted in its bootloader and written."""
    if plan.all_or_nothing:
        _run_phase(session, plan, reports, status, "stage", on_change)
        # An fmcb an earlier run left in its bootloader is finished while staging.
        staged = all(r.state in (NodeState.STAGED, NodeState.DONE)
                     for j, r in reports.items() if j in plan.jobs)
        if staged:
            _run_phase(session, plan, reports, status, "activate", on_change)
        else:
            failed = ", ".join(r.job.name for r in reports.values()
                               if r.state == NodeState.FAILED) or "another node"
            for j, r in reports.items():
                if j in plan.jobs and r.state not in (NodeState.FAILED, NodeState.DONE):
                    r.result = "failed"
                    waits = "; waits in its bootloader" if r.state == NodeState.STAGED else ""
                    r.error = f"not activated: {failed} failed to stage (all-or-nothing){waits}"
    else:
        _run_phase(session, plan, reports, status, "all", on_change)


def _fail_finger(session: HandSession, reports: dict[NodeJob, NodeReport], finger: int,
                 error: BaseException, on_change: Callable[[NodeReport], None] | None,
                 states: tuple[NodeState, ...]) -> None:
    """Mark the node of ``finger`` that was in one of ``states`` failed with ``error``."""
    for j, r in reports.items():
        if j.finger == finger and r.state in states:
            r.result = "failed"
            r.error = str(error)
            r.state = NodeState.FAILED
            r.finished = session.now()
            if on_change is not None:
                on_change(r)


#: Every state but DONE: a finger that gives up fails all its nodes not yet done.
_NOT_DONE: Final = tuple(s for s in NodeState if s is not NodeState.DONE)
_BUSY_STATES: Final = (NodeState.INFO, NodeState.DOWNLOADING, NodeState.SWAPPING,
                       NodeState.CHECKING, NodeState.ROLLING_BACK)


def _run_slot_update(session: HandSession, plan: FlashPlan,
                     reports: dict[NodeJob, NodeReport], status: dict[str, Any],
                     on_change: Callable[[NodeReport], None] | None) -> list[int]:
    """The two-slot update of every finger whose nodes all answer ``slot.info`` (see
    :mod:`bootloader.slot_update`); returns the fingers left for the one-slot way."""
    driver = Driver(session)
    channels = {f: SlotChannel(f, plan, reports, session.now, keep_trial=plan.keep_trial,
                               on_change=on_change) for f in plan.fingers}
    two_slot: list[int] = []

    def probe(finger: int) -> Generator[Op, Outcome, Any]:
        if status["fingers"][finger]["power"] == FingerPower.OFF:
            yield from channels[finger].power_up()  # off when the run began: power it
        if (yield from channels[finger].probe()):
            two_slot.append(finger)

    driver.run({f: probe(f) for f in channels}, lambda f, e: None)  # unanswered: one-slot
    if not two_slot:
        return list(plan.fingers)
    errors: dict[int, BaseException] = {}

    def on_end(finger: int, error: BaseException | None) -> None:
        if error is not None:
            errors[finger] = error
            _fail_finger(session, reports, finger, error, on_change, _BUSY_STATES)

    attempts = dict.fromkeys(two_slot, 0)
    downloads: dict[int, Generator[Op, Outcome, Any]] = {}

    def download(finger: int) -> Generator[Op, Outcome, Any]:
        attempts[finger] += 1
        if attempts[finger] > 1:  # a node lost power or its link: let it boot again
            yield from channels[finger].wait_for_fingers()
        yield from channels[finger].download()

    def on_download_end(finger: int, error: BaseException | None) -> None:
        if error is not None and attempts[finger] < FINGER_ATTEMPTS:
            for j, r in reports.items():
                if j.finger == finger and r.state in _BUSY_STATES:
                    r.error = f"retried after: {error}"
            downloads[finger] = download(finger)
            again.append(finger)
            return
        on_end(finger, error)

    again: list[int] = list(two_slot)
    for f in two_slot:
        downloads[f] = download(f)
    while again:
        batch = {f: downloads[f] for f in again}
        again = []
        driver.run(batch, on_download_end)
    if errors:
        failed = ", ".join(r.job.name for r in reports.values() if r.state == NodeState.FAILED)
        for j, r in reports.items():
            if j.finger in two_slot and r.state == NodeState.STAGED:
                r.result = "failed"
                r.error = (f"not swapped: {failed} failed to download; this node keeps "
                           "running its image (the new one waits in its secondary slot)")
        return [f for f in plan.fingers if f not in two_slot]
    driver.run({f: channels[f].swap() for f in two_slot}, on_end)
    failed_check = bool(errors) or any(channels[f].failed_check for f in two_slot)
    if failed_check:
        back: dict[int, list[NodeJob]] = {}
        for f in two_slot:
            ch = channels[f]
            if plan.fleet_rollback:
                back[f] = list(ch.swapped)
            else:
                back[f] = [j for j in ch.swapped if reports[j].result == "failed"]
        errors.clear()
        driver.run({f: channels[f].rollback(jobs) for f, jobs in back.items() if jobs},
                   on_end)
    return [f for f in plan.fingers if f not in two_slot]


def run_rollback(session: HandSession, plan: FlashPlan,
                 on_change: Callable[[NodeReport], None] | None = None, *,
                 reports: dict[NodeJob, NodeReport] | None = None) -> RunReport:
    """Every node of ``plan`` (a :func:`~bootloader.plan.rollback_plan`) back to the image
    in its secondary slot, four fingers at once; one-slot nodes are reported, untouched."""
    reports = new_reports(plan) if reports is None else reports
    started = session.now()
    status = preflight(session, plan, reports)
    with _palm_poll_paused(session, int(status["poll_hz"])):
        driver = Driver(session)
        channels = {f: SlotChannel(f, plan, reports, session.now, on_change=on_change)
                    for f in plan.fingers}

        def back(finger: int) -> Generator[Op, Outcome, Any]:
            if not (yield from channels[finger].probe()):
                for j, r in reports.items():
                    if j.finger == finger:
                        r.result = "failed"
                        r.error = ("one-slot layout (no slot.info answer): it keeps no "
                                   "previous image to go back to")
                return
            yield from channels[finger].rollback(channels[finger].jobs)

        def on_end(finger: int, error: BaseException | None) -> None:
            if error is not None:
                _fail_finger(session, reports, finger, error, on_change, _BUSY_STATES)

        driver.run({f: back(f) for f in plan.fingers}, on_end)
    return replace(settle(reports, started, session.now()), rollback=True)


def _run_phase(session: HandSession, plan: FlashPlan, reports: dict[NodeJob, NodeReport],
               status: dict[str, Any], phase: str,
               on_change: Callable[[NodeReport], None] | None) -> None:
    attempts = {f: 0 for f in plan.fingers}
    flows: dict[int, Generator[Op, Outcome, Any]] = {}

    def new_flow(finger: int) -> Generator[Op, Outcome, Any]:
        attempts[finger] += 1
        power = int(status["fingers"][finger]["power"])
        channel = FingerChannel(finger, plan, reports, session.now, phase=phase,
                                power_state=power, on_change=on_change)
        return channel.run()

    def on_end(finger: int, error: BaseException | None) -> None:
        if error is None:
            return
        current = [r for j, r in reports.items() if j.finger == finger
                   and r.state not in (NodeState.DONE, NodeState.STAGED, NodeState.PENDING)]
        if attempts[finger] < FINGER_ATTEMPTS and phase != "activate":
            for r in current:
                r.error = f"retried after: {error}"
            flows[finger] = new_flow(finger)
            restart.append(finger)
            return
        _fail_finger(session, reports, finger, error, on_change, _NOT_DONE)

    driver = Driver(session)
    restart: list[int] = []
    for finger in plan.fingers:
        flows[finger] = new_flow(finger)
    pending = dict(flows)
    while pending:
        restart.clear()
        driver.run(pending, on_end)
        pending = {f: flows[f] for f in restart}

