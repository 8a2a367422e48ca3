"""A tour of the live browser view: one view of the arm with the hand on its flange.

    python -m tools.examples.view_tour [ARM_URL HAND_URL]

The URLs default to the ``full`` emulator in process (the hand on the arm's wrist).  It
prints the page's address; open it in a browser while the tour runs (a few seconds).
"""

from __future__ import annotations

import sys

from host import Arm, Hand
from host.view import RobotView

FULL = "emu://full/{}?name=view-tour"


def main(arm_url: str = FULL.format("arm"), hand_url: str = FULL.format("palm"),
         web_port: int = 9090) -> dict[str, object]:
    """Run the tour; returns what it saw."""
    with RobotView(web_port=web_port) as view:
        print("open", view.address)
        arm = Arm.open(arm_url, view=view)                  # view=True: a view of its own
        hand = Hand.open(hand_url, view=view)               # the same view: the hand on the flange
        with arm, hand:
            arm.torque(True, hold=True)
            for k in range(200):  # the wrist turns while the hand is read now and then
                arm.cycle([arm.make_position("J6", 0.002 * k)])
                if k % 20 == 0:
                    hand.status()
        view.drain()
        return {"address": view.address, "drawn": view.drawn, "dropped": view.dropped}


if __name__ == "__main__":
    print(main(sys.argv[1], sys.argv[2]) if len(sys.argv) > 2 else main())
