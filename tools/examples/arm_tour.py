"""A tour of :class:`host.arm.facade.Arm`: discover, torque, the cycle API, move, home, moveto.

    python -m tools.examples.arm_tour [URL]

URL defaults to the emulator in process (``emu://arm/arm``); a real arm's RS-485 adapter is
a serial path (1 Mbaud unless ``?baud=N``).
"""

from __future__ import annotations

import sys
from typing import TypedDict

from host import Arm


class Seen(TypedDict):
    """What the tour saw: the joints' names, homed, the move settled, the steppers' angles
    after it (rad), the moveto's position error (m) and whether it reached."""

    joints: list[str]
    homed: bool
    settled: bool
    angles: list[float]
    moveto_error_m: float
    reached: bool


def main(url: str = "emu://arm/arm") -> Seen:
    """Run the tour on ``url``; returns what it saw."""
    with Arm.open(url) as arm:
        # Seven joints: J1-J4 series-elastic steppers, J5-J7 RX-64 servos.
        for joint in arm.joints:
            print(joint.name, joint.dxl_id, joint.kind, joint.model_number)

        # The cycle: commands as data, sent with one read of all seven joints.
        state = arm.cycle([arm.make_torque(j, True) for j in range(7)])
        print("J2 at", round(state.steppers[1].angle, 3), "rad")
        state = arm.cycle([arm.make_position("J6", state.servos[1].angle + 0.1, speed=0.5)])

        # Find every stepper's index mark: angles become absolute.
        calibration = arm.home()
        print("homed; offsets (rad):", [round(o, 3) for o in calibration.offsets[:4]])

        # Cartesian: the flange to x y z (m, base frame), orientation kept free.
        reached = arm.moveto([0.25, -0.08, -0.52])
        print("moveto:", reached.reached, round(reached.position_error * 1000, 1), "mm")

        # Joint-space move: all joints arrive together after `duration` s (the steppers
        # about 0.6 s later: their speed limits ramp up over the first 0.6 s and down over
        # the last, so the elastic joints do not ring).
        goal = [0.0, 0.3, 0.0, 0.4, 0.0, 0.2, 0.0]
        state, settled = arm.move(goal, duration=1.0, timeout=6.0)
        print("move settled:", settled)

        arm.torque(False)  # the arm hangs again
        return {"joints": [j.name for j in arm.joints], "homed": arm.homed,
                "settled": settled, "angles": [s.angle for s in state.steppers],
                "moveto_error_m": reached.position_error, "reached": reached.reached}


if __name__ == "__main__":
    main(*sys.argv[1:2])
