"""A tour of :class:`host.hand.facade.Hand`: discover, status, power, move, parameters, limits,
events, a short state stream and an MCAP recording.

    python -m tools.examples.hand_tour [URL] [OUT.mcap]

URL defaults to the emulator in process (``emu://hand/palm``); give ``/dev/ttyACM0`` or
``./robot/palm`` for a real hand or the emulator's pty.
"""

from __future__ import annotations

import sys
from typing import TypedDict

from host import Hand
from host.hand.params import Value
from host.hand.recording import HandRecorder
from host.hand.session import FingerEvent


class Seen(TypedDict):
    """What the tour saw: nodes found and answering, ``(finger, event)`` pairs, finger 0's
    deadband (hall counts), finger 1's move (settled, joints in rad), the stream's times (s
    on the link's clock), frames and states recorded."""

    nodes: int
    answered: int
    events: list[tuple[int, str]]
    deadband: Value
    settled: bool
    joints: list[float]
    stream: list[float]
    frames: int
    states: int


def main(url: str = "emu://hand/palm", mcap_path: str = "hand_tour.mcap") -> Seen:
    """Run the tour on ``url``; returns what it saw (the test checks it)."""
    with Hand.open(url) as hand:
        # Who answers: the palm, then each finger's fmcb, f2, f3 (13 nodes).
        nodes = hand.discover()
        for node in nodes:
            print(node.where, node.running if node.answered else node.problem)

        # One snapshot: joints (rad), taxels, currents of every finger.
        state = hand.status()
        print("finger 0 joints (rad):", state.fingers[0].joints)

        # Events (lost, returned, breaker trip, powered, unpowered) arrive whatever the
        # session is waiting for.
        events: list[FingerEvent] = []
        unsubscribe = hand.subscribe(events.append)

        # Power finger 3 off and on again (it boots for about 3 s before it answers).
        print("power:", hand.power(3, "off"))
        print("power:", hand.power(3, "full"))
        hand.session.sleep(3.5)

        # Parameters of finger 0's motor board, by name.
        deadband = hand.fingers[0].params.get("deadband")
        print("finger 0 deadband (hall counts):", deadband)

        # Joint limits: refuse (default) or clamp targets beyond them.
        hand.limits = hand.limits.with_action("clamp")

        # Move finger 1 and wait until it settles.  A finger whose hall offsets were never
        # set is refused (NotHomedError) unless homed first (hand.home()) or unhomed=True.
        result = hand.fingers[1].move([0.0, 0.4, 0.3], effort=200, timeout=3.0,
                                      unhomed=True)
        print("settled:", result.settled, "after", round(result.elapsed_s, 2), "s")

        # Five states at 20 Hz on the link's clock.
        stream = [s.t for s in hand.states(20.0, seconds=0.2)]

        # Frames both ways, states and events to an MCAP file (`handbus decode FILE`).
        with HandRecorder(hand, mcap_path) as recorder:
            recorder.record(0.2, rate_hz=25.0)
        unsubscribe()
        return {"nodes": len(nodes), "answered": sum(n.answered for n in nodes),
                "events": [(e.finger, e.event) for e in events], "deadband": deadband,
                "settled": result.settled, "joints": list(result.states[1].joints),
                "stream": stream, "frames": recorder.frames, "states": recorder.states}


if __name__ == "__main__":
    main(*sys.argv[1:3])
