"""A trial of the fit on a robot it is not told: a profile of perturbed arm parameters and
two different excitations recorded against it (what the walk-through in docs/HIL_BENCH.md
does from the command line, the tests and the benchmark do in process).

The robot (:data:`PERTURBED`, multiples of the nominal values): the shoulder's (J2) element
30 % stiffer and the elbow's (J4) 30 % softer, J2's bearings twice as stiff in friction, and
J4's stepper 20 % weaker (its torque constant, so its holding torque).  The first excitation
(:data:`FIRST`, the one fitted) chirps J2 and J4, ramps J2 slowly through zero speed, holds
two poses and probes J4's holding torque; the second (:data:`SECOND`, the one checked) is
another motion: J4 chirped alone, another hold, J2 not ramped, J4 probed for a shorter time.
"""

from __future__ import annotations

from pathlib import Path
from typing import Final

from hil_emulator.inprocess import forget_shared_emulators
from hil_emulator.profile import PARAMETERS, RobotProfile
from host.arm.excite import Excitation, excite
from host.arm.facade import Arm
from host.arm.recording import ArmRecorder

#: The perturbed robot: multiples of each parameter's nominal value.
PERTURBED: Final = {"arm.J2.stiffness": 1.3, "arm.J4.stiffness": 0.7,
                    "arm.J2.bearing_friction": 2.0, "arm.J4.torque_constant": 0.8}
#: The excitation fitted, and the different one the refit robot is checked against.
FIRST: Final = Excitation(joints=(1, 3), chirp_s=1.5, hold_s=0.3,
                          holds=((0.3, 0.0), (0.3, 0.4)), ramps=(1,), ramp_rad=0.06,
                          probes=(3,), probe_s=2.0)
SECOND: Final = Excitation(joints=(3,), chirp_s=1.0, hold_s=0.3, holds=((0.2, 0.3),),
                           probes=(3,), probe_s=1.5)
#: The emulator's seed of the recordings.
SEED: Final = 3


def truth() -> dict[str, float]:
    """The perturbed robot's values, in their units."""
    return {n: PARAMETERS[n].nominal * f for n, f in PERTURBED.items()}


def write_profile(path: Path) -> Path:
    """Write the perturbed robot's profile to ``path``; ``path``."""
    RobotProfile(truth()).write(path)
    return path


def record(path: Path, profile: Path, plan: Excitation, seed: int = SEED) -> None:
    """Record ``plan`` to ``path`` on an in-process arm emulator with ``profile``."""
    forget_shared_emulators()
    try:
        with Arm.open(f"emu://arm/arm?seed={seed}&name=fit-trial&profile={profile}") as arm:
            arm.torque(True)
            with ArmRecorder(arm, path):
                excite(arm, plan)
    finally:
        forget_shared_emulators()
