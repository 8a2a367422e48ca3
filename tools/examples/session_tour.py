"""The conversation under :class:`~host.hand.facade.Hand`: :class:`~host.hand.session.HandSession`
requests by catalogue name, routed through the palm, several in flight at once.

    python -m tools.examples.session_tour [URL]
"""

from __future__ import annotations

import sys
from typing import Any, TypedDict

from host import open_transport
from host.errors import RouteError
from host.hand.session import HandSession, SessionCounters, Target
from protocol.messages.palm import FingerPower


class Seen(TypedDict):
    """What the tour saw: two ``identify`` replies (fields by name), the fmcbs' hall
    positions (counts), finger 0's refusal while off, the session's counters."""

    palm: dict[str, Any]
    f3: dict[str, Any]
    halls: list[int]
    refused: str
    counters: SessionCounters


def main(url: str = "emu://hand/palm") -> Seen:
    """Run the tour on ``url``; returns what it saw."""
    with HandSession(open_transport(url)) as session:
        # The palm itself: every request travels in a txn envelope, matched by sequence.
        palm = session.request("identify")
        # A node behind the palm: finger 2's distal board (hop 2), routed by palm.route
        # and, past the fmcb, through its tendon tunnel.  Timeouts add up along the hops.
        f3 = session.request("identify", to=Target(finger=2, hop=2))
        # Pipelining: start requests to all four fmcbs, then wait for each reply.
        pending = [session.start("fmcb.status", to=Target(finger=k)) for k in range(4)]
        halls = [session.wait(p)["hall_pos"] for p in pending]
        # A finger that is switched off answers with a route error saying what to do.
        session.request("palm.finger_power", {"finger": 0, "state": FingerPower.OFF,
                                                     "stagger_ms": 0})
        try:
            session.request("identify", to=Target(finger=0), retries=0)
            refused = ""
        except RouteError as exc:
            refused = str(exc)
            print(exc)
        session.request("palm.finger_power", {"finger": 0, "state": FingerPower.FULL,
                                                     "stagger_ms": 0})
        session.sleep(3.5)  # the finger boots (link clock: simulated seconds on emu://)
        print(palm, f3, sep="\n")
        return {"palm": palm, "f3": f3, "halls": halls, "refused": refused,
                "counters": session.counters}


if __name__ == "__main__":
    main(*sys.argv[1:2])
