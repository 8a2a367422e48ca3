"""Bringing the hand up from power-on: palm, fingers, phalanges, autopoll.

A hand just switched on runs its palm only.  Each finger's boards then need, in order:

1. the palm running its application (after its bootloader's autoboot window,
   :data:`protocol.messages.boot_program.AUTOBOOT_WINDOW_US`);
2. the finger's supply: ``palm.finger_power`` full (:meth:`host.hand.facade.Hand.power`);
3. its fmcb running its application, after its own autoboot window;
4. the phalange bus: ``fmcb.phalange_power`` on, which powers f2 and f3;
5. f2 and f3 running their applications, after their autoboot window;
6. ``fmcb.autopoll`` on: the fmcb asks f2 and f3 every 10 ms, which fills the phalange
   fields of ``fmcb.status`` (taxels, accelerometers: homing needs them).

:func:`bring_up` does this on the link's clock (about 10 s of robot time), waiting for each
board by asking it ``identify`` every :data:`POLL_S` until it says it runs its application,
at most ``timeout`` s after its power was switched on.  That time is the board's own when it
answers (``identify``'s ``uptime_us`` counts from its power-up), so a robot whose clock runs
slower than the link's (the emulator on a busy machine) is waited for, up to
:data:`BOOT_WAIT_LIMIT` times ``timeout`` on the link's clock.  A board that does not come up
is reported with a reason (:class:`~host.hand.state.NodeUp`): one still in its bootloader after its autoboot
window is asked ``bl.status`` why (no bootable image, or halted by a flashing tool); the
others carry on.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Final

from host.code_names import code_name
from host.errors import HostError, NodeError, ReplyTimeout, UsageError, why_no_answer
from host.hand.interface import PoweredHand
from host.hand.node import Node
from host.hand.session import PendingReply
from host.hand.state import FingerUp, NodeUp
from protocol.messages.boot_program import AUTOBOOT_WINDOW_US, BootState, ImageStatus
from protocol.messages.common import Running
from protocol.topology import FINGERS

#: Longest wait for a board to run its application after its power is switched on (s):
#: the autoboot window, the application's start and a margin for a slow link.
BOOT_TIMEOUT_S: Final = AUTOBOOT_WINDOW_US / 1e6 + 3.5
#: The autoboot window (s).
AUTOBOOT_WINDOW_S: Final = AUTOBOOT_WINDOW_US / 1e6
#: How much longer than its ``timeout`` (a multiple of it, on the link's clock) a wait goes
#: on for a board whose own clock says it has not been powered ``timeout`` s yet.
BOOT_WAIT_LIMIT: Final = 3.0
#: How often a booting board is asked whether it runs its application yet (s).
POLL_S: Final = 0.25
#: Longest wait, once autopoll is on, for ``fmcb.status`` to carry the phalanges' first
#: readings (their timestamps ``pp_time`` / ``dp_time`` stop being 0), and how often it is
#: read meanwhile (s).  The fmcb polls them every 10 ms.
AUTOPOLL_CHECK_S: Final = 0.5
AUTOPOLL_READ_S: Final = 0.02
#: What to do when a board never answered, by the last route status the palm gave.
_ADVICE: Final = {
    "unpowered": "the palm's switch for this finger is off",
    "no_reply": "nothing answers: is the finger on its pogo pins, are the tendon contacts "
                "closed?",
    "link_down": "the palm's link to this finger is down: is it on its pogo pins?",
}


def _fingers(fingers: int | str | Sequence[int]) -> list[int]:
    if fingers == "all":
        return list(range(FINGERS))
    try:
        chosen = [int(fingers)] if isinstance(fingers, int | str) else [int(k) for k in fingers]
    except ValueError:
        raise UsageError(f"finger(s) {fingers!r}: give 0..{FINGERS - 1} or all") from None
    bad = [k for k in chosen if not 0 <= k < FINGERS]
    if bad or not chosen:
        raise UsageError(f"finger(s) {bad or chosen}: the hand has fingers 0..{FINGERS - 1}")
    return sorted(set(chosen))


class _Waiter:
    """Asks boards ``identify`` every :data:`POLL_S` until each runs its application or
    its time is up (see :func:`bring_up`'s ``timeout``)."""

    def __init__(self, hand: PoweredHand, start_s: float, say: Callable[[str], None]) -> None:
        self.hand = hand
        self.start_s = start_s
        self.say = say

    def wait(self, nodes: Sequence[tuple[Node, NodeUp]], timeout: float) -> None:
        session = self.hand.session
        begun = session.now()
        deadline = begun + timeout
        limit = begun + BOOT_WAIT_LIMIT * timeout
        waiting = list(nodes)
        last: dict[str, str] = {}
        uptime: dict[str, float] = {}  # s since power-up by the board's clock, last seen
        given_up: list[tuple[Node, NodeUp]] = []
        while waiting:
            asked: list[tuple[Node, NodeUp, PendingReply | HostError]] = []
            for node, up in waiting:
                try:
                    asked.append((node, up, node.start("identify", retries=0)))
                except HostError as exc:
                    asked.append((node, up, exc))
            still = []
            for node, up, pending in asked:
                try:
                    if isinstance(pending, HostError):
                        raise pending
                    reply = session.wait(pending)
                except HostError as exc:
                    last[up.where] = why_no_answer(exc)
                    uptime.pop(up.where, None)
                    still.append((node, up))
                    continue
                up.running = code_name(Running, reply["running"], "running")
                if reply["running"] == Running.APPLICATION:
                    up.up = True
                    up.after_s = session.now() - self.start_s
                    self.say(f"{up.where}: up after {up.after_s:.2f} s")
                    continue
                last[up.where] = f"still in its {up.running}"
                uptime[up.where] = reply["uptime_us"] / 1e6
                if uptime[up.where] >= timeout:  # its own clock: powered that long already
                    given_up.append((node, up))
                else:
                    still.append((node, up))
            waiting = still
            now = session.now()
            if waiting and now >= deadline:
                # A board whose own clock says it has not been powered ``timeout`` s yet is
                # booting on a robot slower than this link's clock: wait on, up to the limit.
                booting = [(n, u) for n, u in waiting if u.where in uptime and now < limit]
                given_up += [(n, u) for n, u in waiting if (n, u) not in booting]
                waiting = booting
            if waiting:
                next_check = deadline if now < deadline else limit
                session.sleep(min(POLL_S, max(0.0, next_check - now)))
        waited_s = session.now() - begun
        for node, up in given_up:
            up.problem = self._problem(node, last.get(up.where, "no reply"),
                                       uptime.get(up.where), timeout, waited_s)
            self.say(f"{up.where}: NOT UP: {up.problem}")

    def _problem(self, node: Node, last: str, uptime_s: float | None, timeout: float,
                 waited_s: float) -> str:
        """Why a board did not come up, and what to do: a board still in its bootloader
        is asked (``bl.status``, only once its autoboot window is over: the request would
        halt the countdown) why it stays there."""
        if uptime_s is None or not last.startswith("still in its bootloader"):
            advice = _ADVICE.get(last)
            return f"{last} {timeout:g} s after power-up" + (f": {advice}" if advice else "")
        if uptime_s < AUTOBOOT_WINDOW_S:
            return (f"still counting down its bootloader's {AUTOBOOT_WINDOW_S:g} s autoboot "
                    f"window, {uptime_s:.1f} s after its power-up by its own clock, when "
                    f"{waited_s:.1f} s had passed on this link: the robot runs slower than "
                    f"the link's clock (a busy machine running the emulator?); run "
                    f"`handctl up` again")
        try:
            status = node.request("bl.status", retries=0)
        except HostError:
            return (f"still in its bootloader {uptime_s:.1f} s after power-up: no valid, "
                    f"activated image? (flash it: flash-all-fingers)")
        state = code_name(BootState, status["state"], "state")
        image = code_name(ImageStatus, status["image_status"], "image_status")
        why = f"{status['text']}" if status["text"] else f"image {image}"
        if status["state"] == BootState.HALTED:
            return (f"its bootloader was halted (bl.halt: a flashing tool?) and waits, "
                    f"{uptime_s:.1f} s after power-up ({why}): finish the flashing, or "
                    f"switch the finger off and run `handctl up` again")
        if status["state"] == BootState.NO_VALID_IMAGE:
            return (f"stayed in its bootloader after its {AUTOBOOT_WINDOW_S:g} s autoboot "
                    f"window: no bootable image ({why}); flash it: flash-all-fingers")
        return f"still in its bootloader {uptime_s:.1f} s after power-up ({state}: {why})"


def bring_up(hand: PoweredHand, fingers: int | str | Sequence[int] = "all",
             timeout: float = BOOT_TIMEOUT_S,
             on_progress: Callable[[str], None] | None = None) -> list[FingerUp]:
    """Bring ``fingers`` (``"all"``, an index or indices) up from power-on, as the module
    describes: one :class:`FingerUp` each, in finger order.  ``timeout`` (s) bounds each
    wait for a board to boot after its power is switched on: on the board's own clock while
    it answers from its bootloader (up to :data:`BOOT_WAIT_LIMIT` × ``timeout`` on the
    link's clock), on the link's clock otherwise; ``on_progress`` gets one line per step as
    it happens.  Raises only when the palm itself does not run its application (nothing
    behind it can come up) or the link fails."""
    chosen = _fingers(fingers)
    if not timeout > 0:
        raise UsageError(f"bring-up timeout {timeout} s: it must be > 0")
    session = hand.session

    def say(line: str) -> None:
        if on_progress is not None:
            on_progress(line)

    waiter = _Waiter(hand, session.now(), say)
    palm = NodeUp("palm")
    waiter.wait([(hand.palm, palm)], timeout)
    if not palm.up:
        error = NodeError if palm.running is not None else ReplyTimeout
        raise error(f"the palm does not run its application: {palm.problem}")

    if len(chosen) == FINGERS:
        power = hand.power("all", "full")
    else:
        for k in chosen:
            power = hand.power(k, "full")
    say("power: " + ", ".join(f"finger {k} {power[k]}" for k in chosen)
        + f"; waiting up to {timeout:g} s for the fmcbs to boot")
    results = {k: FingerUp(k, power[k], [NodeUp(n.where) for n in hand.fingers[k].nodes])
               for k in chosen}
    waiter.wait([(hand.fingers[k].motor, results[k].nodes[0]) for k in chosen], timeout)

    powered: list[int] = []
    for k in chosen:
        fmcb, f2, f3 = results[k].nodes
        if not fmcb.up:
            for node in (f2, f3):
                node.problem = "its fmcb did not come up, so its phalanges are unpowered"
            continue
        try:
            hand.fingers[k].motor.request("fmcb.phalange_power", {"on": 1})
            powered.append(k)
        except HostError as exc:
            for node in (f2, f3):
                node.problem = f"fmcb.phalange_power failed: {exc}"
    if powered:
        say(f"phalanges: power on (finger{'s' if len(powered) > 1 else ''} "
            f"{', '.join(map(str, powered))}); waiting up to {timeout:g} s for them to boot")
        waiter.wait([(n, results[k].nodes[n.target.hop]) for k in powered
                     for n in hand.fingers[k].nodes[1:]], timeout)

    polling = []
    for k in chosen:
        if not results[k].nodes[0].up:
            continue
        try:
            hand.fingers[k].motor.request("fmcb.autopoll", {"on": 1})
            results[k].autopoll = True
            polling.append(k)
        except HostError as exc:
            results[k].autopoll_problem = f"fmcb.autopoll failed: {exc}"
            say(f"finger {k} fmcb: autopoll NOT ON: {exc}")
    if polling:
        _check_polled(hand, [results[k] for k in polling])
        say(f"autopoll: on (finger{'s' if len(polling) > 1 else ''} "
            f"{', '.join(map(str, polling))})")
    return [results[k] for k in chosen]


def _check_polled(hand: PoweredHand, fingers: Sequence[FingerUp]) -> None:
    """Wait until each finger's ``fmcb.status`` carries readings of every phalange that
    came up (so the next status has their taxels and accelerometers); a finger whose
    phalanges stay silent gets an ``autopoll_problem`` and ``autopoll`` False."""
    session = hand.session
    deadline = session.now() + AUTOPOLL_CHECK_S
    waiting = list(fingers)
    while waiting:
        still = []
        for r in waiting:
            _fmcb, f2, f3 = r.nodes
            try:
                status = hand.fingers[r.finger].motor.request("fmcb.status", retries=0)
            except HostError:
                still.append(r)
                continue
            if (f2.up and not status["pp_time"]) or (f3.up and not status["dp_time"]):
                still.append(r)
        waiting = still
        if waiting and session.now() >= deadline:
            for r in waiting:
                r.autopoll = False
                r.autopoll_problem = (f"autopoll is on but fmcb.status carried no phalange "
                                      f"readings within {AUTOPOLL_CHECK_S:g} s")
            return
        if waiting:
            session.sleep(AUTOPOLL_READ_S)


__all__ = ["AUTOBOOT_WINDOW_S", "AUTOPOLL_CHECK_S", "BOOT_TIMEOUT_S", "BOOT_WAIT_LIMIT", "POLL_S",
           "FingerUp", "NodeUp", "bring_up"]
