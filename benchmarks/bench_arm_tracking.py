"""Tracking a Cartesian line with the arm's joint PID, at 100 Hz and as fast as the wire allows.

In process on ``emu://arm/arm`` (simulation clock, fast mode: return delay 0), homed.  The
flange follows a straight line of :data:`LINE_M` at :data:`SPEED_M_S`: the line is sampled
every centimetre, each sample solved by IK from the previous one (so the joint path is
continuous), and the joint-space waypoints timed along the line; the controller
(:class:`host.arm.joint_loop.JointController`, coupling feed-forward on) runs it at 100 Hz and
with ``rate_hz=None`` (back-to-back cycles, the wire's bound).  The error is the MuJoCo flange
body's distance from where the line says it should be at that cycle (mm: RMS and maximum over
the move and 0.5 s after), and the rate is the cycles per simulated second achieved.

``python -m benchmarks bench_arm_tracking`` (or ``python -m benchmarks.bench_arm_tracking``
for JSON).
"""

from __future__ import annotations

import json
from typing import Any, Final

import mujoco
import numpy as np

from benchmarks.harness import Result
from hil_emulator.inprocess import forget_shared_emulators
from host.arm import kinematics as arm_kinematics
from host.arm.facade import Arm
from host.arm.joint_loop import JointController
from host.arm.trajectory import Trajectory, Waypoint

#: The line (m, base frame) and the flange's speed along it (m/s).
LINE_M: Final = ((0.10, -0.15, -0.60), (0.30, 0.15, -0.48))
SPEED_M_S: Final = 0.1
SETTLE_S: Final = 0.5


def line_trajectory(q0: np.ndarray, a: np.ndarray, b: np.ndarray, speed: float
                    ) -> tuple[Trajectory, float]:
    """Joint waypoints along the line a→b (IK every cm, chained from ``q0``), timed at
    ``speed`` (m/s); and the line's duration (s)."""
    length = float(np.linalg.norm(b - a))
    n = max(int(length / 0.01), 1)
    q = q0
    points = []
    for k in range(n + 1):
        ik = arm_kinematics.solve_ik(a + (b - a) * k / n, q0=q)
        if not ik.converged:
            raise RuntimeError(f"IK failed on the line at {k}/{n}")
        q = ik.q
        points.append(Waypoint(length * k / n / speed, tuple(float(v) for v in q)))
    return Trajectory(points), length / speed


def track(arm: Arm, rate_hz: float | None) -> dict[str, float]:
    """Run the line once at ``rate_hz``; errors (mm) and cycles per simulated second."""
    a, b = (np.array(p) for p in LINE_M)
    arm.moveto(a)
    control = JointController(arm, rate_hz=rate_hz)
    state = control.start()
    trajectory, duration = line_trajectory(np.array(state.joints), a, b, SPEED_M_S)
    plant = arm.transport.emulator.arm_plant  # type: ignore[attr-defined]
    model, data = plant.model, plant.data
    flange = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "arm/flange")
    base = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "arm/base")
    clock = arm.transport
    t0 = clock.now()
    errors: list[float] = []
    cycles = 0

    def follow(t: float) -> tuple[np.ndarray, np.ndarray]:
        nonlocal cycles
        where = data.xmat[base].reshape(3, 3).T @ (data.xpos[flange] - data.xpos[base])
        wanted = a + (b - a) * min(max(t, 0.0) / duration, 1.0)
        errors.append(float(np.linalg.norm(where - wanted)))
        cycles += 1
        return trajectory(t)

    control.run(follow, duration + SETTLE_S)
    elapsed = clock.now() - t0
    e = np.array(errors) * 1000.0
    return {"rms_mm": float(np.sqrt(np.mean(e ** 2))), "max_mm": float(e.max()),
            "final_mm": float(e[-1]), "cycles_per_s": cycles / elapsed}


def measure() -> dict[str, dict[str, float]]:
    """Both rates on one homed in-process arm."""
    arm = Arm.open("emu://arm/arm?name=bench_arm_tracking")
    try:
        arm.home()
        return {"100 Hz": track(arm, 100.0), "wire bound": track(arm, None)}
    finally:
        arm.close()
        forget_shared_emulators()


def run(quick: bool) -> list[Result]:
    """Per rate: the cycles per simulated second (the wire bound's against 100 Hz's), and
    the flange's RMS error (mm) with its maximum and final error in the note."""
    group = "arm line tracking"
    out = []
    for name, r in measure().items():
        baseline = None if name == "100 Hz" else "100 Hz"
        out.append(Result(group, f"{name}: cycle rate", r["cycles_per_s"], "cyc",
                          baseline=None if baseline is None else f"{baseline}: cycle rate",
                          note="per simulated s"))
        out.append(Result(group, f"{name}: flange error RMS", r["rms_mm"], "mm",
                          baseline=None if baseline is None else f"{baseline}: flange error RMS",
                          at_most=True, note=f"max {r['max_mm']:.1f} mm, final "
                                             f"{r['final_mm']:.1f} mm; line "
                                             f"{SPEED_M_S * 1e3:.0f} mm/s"))
    return out


def main() -> None:
    results: dict[str, Any] = measure()
    print(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
