"""Figure 4.4 on the emulated arm: end-effector error before and after calibration.

The dissertation (§4.4, figure 4.4) calibrated its low-cost arm by touching a board's
corners and a table, and drove the mean end-effector error on held-out points from 11 mm
(the CAD model) to 2 mm.  Here, per seed, with the realistic (as-built) arm:

1. **training touches**: the board (a 4×3 grid of dimples at :data:`DIMPLE_PITCH_M`) in
   :data:`TRAINING_BOARDS` seeded placements and :data:`TABLE_TOUCHES` table contacts, each
   reached by the *built* arm's kinematics (the emulator's compiled model, the planted index
   marks and horns), its joint readings those the homed host would read (the planted reading
   offsets, the encoders' and pots' quantisation).  These touches are synthesised from the
   emulator's ground truth, not made by guarded moves (the solver's figures; ``--physical``
   makes them);
2. :func:`host.arm.calibration.calibrate` from the CAD model;
3. **held-out error, synthetic**: touches of :data:`HELD_OUT_BOARDS` other placements, the
   flange's position from the host's kinematics (CAD, then calibrated) against the true one,
   each model given the true gauge (J1's zero and the base's position, which no touch can
   see: :meth:`~host.arm.calibration.ArmGeometry.with_gauge_of`);
4. **held-out error, on the emulator** (``--emulator``): the arm homed over the wire and
   moved to :data:`EMULATOR_POSES` seeded poses, the host's readings through both models
   against the plant's flange (the optical tracker), with the true gauge likewise.

5. **the physical procedure** (``--physical``): ``armctl calibrate``'s touches
   (:func:`host.arm.touches.gather`) on the emulator's ``calibration`` scene, its fit
   (:func:`host.arm.touches.fit`), then :data:`PHYSICAL_POSES` held-out poses, the host's
   readings through the CAD model and the calibration against the plant's probe tip (no
   gauge given), and the CPU time the seed took.  Slow: 2-3 CPU minutes per seed.

    python -m tools.experiments.arm_calibration [--seeds 0 1 2] [--emulator] [--physical] [--json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Final

import numpy as np
from scipy.optimize import least_squares

from hil_emulator.arm.model import MOUNT_HEIGHT_M
from hil_emulator.emulator import Emulator
from host.arm.calibration import (
    ArmGeometry,
    BoardTouches,
    CalibrationData,
    calibrate,
)
from host.arm.kinematics import LOWER, UPPER, rpy_to_matrix
from protocol.robot import ARM_ENCODER_COUNTS_PER_REV, RX64_UNITS_PER_RAD

#: The dissertation's figure 4.4: mean held-out end-effector error (mm), CAD → calibrated.
DISSERTATION_MM: Final = (11.0, 2.0)
#: The board's dimples: a 4×3 grid at this pitch (m).
DIMPLE_PITCH_M: Final = 0.05
DIMPLES: Final = np.array([(DIMPLE_PITCH_M * i, DIMPLE_PITCH_M * j, 0.0)
                           for i in range(4) for j in range(3)])
TRAINING_BOARDS: Final = 6
HELD_OUT_BOARDS: Final = 3
TABLE_TOUCHES: Final = 60
#: The table's top in the base frame (m): 0.40 m below the base plate.
TABLE_Z_M: Final = -0.40
EMULATOR_POSES: Final = 12
#: Anchor dimples on the arm's mounting bracket, drawn in the base frame (m), each touched
#: :data:`ANCHOR_TOUCHES` times in different configurations; as built each is off its drawing
#: by :data:`ANCHOR_SIGMA_M` per axis.
ANCHOR_POINTS_M: Final = np.array([(0.35, 0.12, -0.15), (0.35, -0.12, -0.15)])
ANCHOR_TOUCHES: Final = 3
ANCHOR_SIGMA_M: Final = 0.0003
#: The arm's body names in the emulator's model, J1..J7 then the flange.
ARM_BODIES: Final = ("arm/link1", "arm/shoulder", "arm/upper_arm", "arm/forearm",
                     "arm/forearm_roll", "arm/wrist", "arm/wrist_yaw", "arm/flange")


def built_geometry(emulator: Emulator) -> tuple[ArmGeometry, np.ndarray]:
    """The built arm's true geometry (zero offsets 0: true angles) from the emulator's
    compiled model, and what the homed host reads less the true angles (rad, 7)."""
    assert emulator.plant is not None and emulator.planted is not None
    model = emulator.plant.model
    pos = np.array([model.body(name).pos for name in ARM_BODIES], dtype=float)
    return (ArmGeometry(np.zeros(7), pos[:7].copy(), pos[7].copy()),
            emulator.planted.arm_reading_offsets_rad())


def _quantised(q: np.ndarray) -> np.ndarray:
    """What the encoders (J1..J4) and pots (J5..J7) resolve of ``q`` (rad)."""
    enc = 2.0 * math.pi / ARM_ENCODER_COUNTS_PER_REV
    out = q.copy()
    out[..., :4] = np.round(q[..., :4] / enc) * enc
    out[..., 4:] = np.round(q[..., 4:] * RX64_UNITS_PER_RAD) / RX64_UNITS_PER_RAD
    return out


def reach(truth: ArmGeometry, target: np.ndarray, rng: np.random.Generator) -> np.ndarray | None:
    """True joint angles (rad) putting the built arm's flange on ``target`` (m, base frame),
    from a random start (so the wrist's orientation varies), or None if out of reach."""
    q0 = rng.uniform(LOWER * 0.5, UPPER * 0.5)
    q0[1] = rng.uniform(0.6, 1.6)
    q0[3] = rng.uniform(0.3, 1.6)
    fit = least_squares(lambda q: np.concatenate((truth.tips(q)[0] - target,
                                                  1e-3 * (q - q0))),
                        q0, bounds=(LOWER + 0.05, UPPER - 0.05))
    q: np.ndarray = fit.x
    if np.linalg.norm(truth.tips(q)[0] - target) > 1e-5:
        return None
    return q


def _board_pose(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A board placement in front of the arm: rotation (3×3) and origin (m, base frame)."""
    rot = rpy_to_matrix(rng.uniform(-0.5, 0.5, 3) + np.array([0.0, 0.0, rng.uniform(-0.6, 0.6)]))
    origin = np.array([rng.uniform(0.3, 0.45), rng.uniform(-0.25, 0.1), rng.uniform(-0.45, -0.2)])
    return rot, origin


def touches(truth: ArmGeometry, offsets: np.ndarray, rng: np.random.Generator, boards: int,
            table: int) -> tuple[CalibrationData, list[np.ndarray]]:
    """``boards`` placements' touches and ``table`` table touches of the built arm
    (``truth``), as the host reads them; and each placement's true flange positions."""
    placements: list[BoardTouches] = []
    true_tips: list[np.ndarray] = []
    while len(placements) < boards:
        rot, origin = _board_pose(rng)
        qs = []
        for p in DIMPLES:
            q1 = reach(truth, origin + rot @ p, rng)
            if q1 is None:
                break
            qs.append(q1)
        if len(qs) < len(DIMPLES):
            continue
        q = np.array(qs)
        placements.append(BoardTouches(_quantised(q + offsets), DIMPLES.copy()))
        true_tips.append(truth.tips(q))
    table_q: list[np.ndarray] = []
    while len(table_q) < table:
        target = np.array([rng.uniform(0.2, 0.45), rng.uniform(-0.25, 0.25), TABLE_Z_M])
        q1 = reach(truth, target, rng)
        if q1 is not None:
            table_q.append(q1)
    table_readings = (_quantised(np.array(table_q) + offsets) if table_q
                      else np.zeros((0, len(offsets))))
    return CalibrationData(tuple(placements), table_readings), true_tips


def anchored(data: CalibrationData, truth: ArmGeometry, offsets: np.ndarray,
             rng: np.random.Generator) -> CalibrationData:
    """``data`` with the anchor dimples' touches (:data:`ANCHOR_POINTS_M`, each where the
    built bracket has it)."""
    joints: list[np.ndarray] = []
    points: list[np.ndarray] = []
    for drawn in ANCHOR_POINTS_M:
        built = drawn + rng.normal(0.0, ANCHOR_SIGMA_M, 3)
        touched = 0
        while touched < ANCHOR_TOUCHES:
            q = reach(truth, built, rng)
            if q is not None:
                joints.append(_quantised(q + offsets))
                points.append(drawn)
                touched += 1
    return CalibrationData(data.boards, data.table_joints, np.array(joints), np.array(points))


@dataclass
class SeedResult:
    """One seed's figures (mm): held-out mean and max before and after, synthetic and (with
    ``--emulator``) on the emulator; the solver's evaluations."""

    seed: int
    before_mean_mm: float
    before_max_mm: float
    after_mean_mm: float
    after_max_mm: float
    emulator_before_mean_mm: float | None = None
    emulator_after_mean_mm: float | None = None
    emulator_after_max_mm: float | None = None
    #: The same without the true gauge: the base frame's absolute error, J1's index in it.
    emulator_raw_before_mean_mm: float | None = None
    emulator_raw_after_mean_mm: float | None = None
    #: Calibrated with the anchor touches too, no gauge given: synthetic, on the emulator.
    raw_before_mean_mm: float = 0.0
    anchored_mean_mm: float = 0.0
    anchored_max_mm: float = 0.0
    emulator_anchored_mean_mm: float | None = None
    emulator_anchored_max_mm: float | None = None
    evaluations: int = 0


def held_out_errors(geometry: ArmGeometry, truth: ArmGeometry, data: CalibrationData,
                    true_tips: Sequence[np.ndarray]) -> np.ndarray:
    """End-effector errors (m) of ``geometry`` on the held-out touches, with the gauge of
    ``truth`` (the host's view of the true geometry, readings' offsets included)."""
    gauged = geometry.with_gauge_of(truth)
    est = np.concatenate([gauged.tips(b.joints) for b in data.boards])
    out: np.ndarray = np.linalg.norm(est - np.concatenate(true_tips), axis=1)
    return out


def on_emulator(seed: int, geometries: Sequence[ArmGeometry], truth: ArmGeometry
                ) -> list[np.ndarray]:
    """Each geometry's flange errors (m) over :data:`EMULATOR_POSES` poses of the homed
    emulated arm (host readings over the wire; the plant's flange as truth): first with
    ``truth``'s gauge, then as they are (J1's index error and the base's position in them)."""
    from hil_emulator.inprocess import EmulatorTransport
    from host.arm.facade import Arm
    emulator = Emulator("arm", seed=seed)
    rng = np.random.default_rng(1000 + seed)
    readings, tracked = [], []
    with Arm.on(EmulatorTransport(emulator, "arm")) as arm:
        arm.torque(True, hold=True)
        arm.home()
        plant = emulator.arm_plant
        assert plant is not None
        base = np.array([0.0, 0.0, -MOUNT_HEIGHT_M])  # world → the arm's base frame
        for _ in range(EMULATOR_POSES):
            pose = [rng.uniform(-0.8, 0.8), rng.uniform(0.3, 1.8), rng.uniform(-0.8, 0.8),
                    rng.uniform(0.2, 2.0), rng.uniform(-1, 1), rng.uniform(-0.8, 0.8),
                    rng.uniform(-0.8, 0.8)]
            arm.move(pose)
            readings.append(arm.state().joints)
            tracked.append(plant.flange_position() + base)
    q, t = np.array(readings), np.array(tracked)
    gauged = [np.linalg.norm(g.with_gauge_of(truth).tips(q) - t, axis=1) for g in geometries]
    raw = [np.linalg.norm(g.tips(q) - t, axis=1) for g in geometries]
    return gauged + raw


def run_seed(seed: int, emulator: bool = False) -> SeedResult:
    """Calibrate seed ``seed``'s built arm and measure it (see the module docs)."""
    built = Emulator("arm", seed=seed)
    truth, offsets = built_geometry(built)
    rng = np.random.default_rng(seed)
    train, _ = touches(truth, offsets, rng, TRAINING_BOARDS, TABLE_TOUCHES)
    test, test_tips = touches(truth, offsets, rng, HELD_OUT_BOARDS, 0)
    result = calibrate(train)
    with_anchors = calibrate(anchored(train, truth, offsets, rng)).geometry
    seen = ArmGeometry(-offsets, truth.joint_offsets_m, truth.flange_offset_m)
    before = held_out_errors(ArmGeometry.nominal(), seen, test, test_tips) * 1000
    after = held_out_errors(result.geometry, seen, test, test_tips) * 1000
    est = np.concatenate([with_anchors.tips(b.joints) for b in test.boards])
    raw = np.linalg.norm(est - np.concatenate(test_tips), axis=1) * 1000
    cad = np.concatenate([ArmGeometry.nominal().tips(b.joints) for b in test.boards])
    raw_before = np.linalg.norm(cad - np.concatenate(test_tips), axis=1) * 1000
    out = SeedResult(seed, float(before.mean()), float(before.max()), float(after.mean()),
                     float(after.max()), evaluations=result.evaluations,
                     anchored_mean_mm=float(raw.mean()), anchored_max_mm=float(raw.max()),
                     raw_before_mean_mm=float(raw_before.mean()))
    if emulator:
        nominal, calibrated, _, nominal_raw, calibrated_raw, anchors_raw = on_emulator(
            seed, (ArmGeometry.nominal(), result.geometry, with_anchors), seen)
        out.emulator_anchored_mean_mm = float(anchors_raw.mean() * 1000)
        out.emulator_anchored_max_mm = float(anchors_raw.max() * 1000)
        out.emulator_before_mean_mm = float(nominal.mean() * 1000)
        out.emulator_after_mean_mm = float(calibrated.mean() * 1000)
        out.emulator_after_max_mm = float(calibrated.max() * 1000)
        out.emulator_raw_before_mean_mm = float(nominal_raw.mean() * 1000)
        out.emulator_raw_after_mean_mm = float(calibrated_raw.mean() * 1000)
    return out


#: Held-out poses of the physical procedure's measurement.
PHYSICAL_POSES: Final = 8


@dataclass
class PhysicalResult:
    """One seed's physical procedure (mm, probe tip, no gauge given): held-out mean and max
    before (CAD) and after; touches made and missed."""

    seed: int
    before_mean_mm: float
    before_max_mm: float
    after_mean_mm: float
    after_max_mm: float
    touches: dict[str, int]
    missed: int
    #: The process's CPU time for the seed (s): the emulator, the host, the fit.
    cpu_s: float = 0.0


def run_physical(seed: int, poses: int) -> PhysicalResult:
    """The touches made by guarded moves on the ``calibration`` scene, the fit, and held-out
    poses (see the module docs)."""
    from hil_emulator.inprocess import EmulatorTransport
    from host.arm import touches as arm_touches
    from host.arm.facade import Arm
    from protocol.robot import ARM_PROBE_TIP_M
    cpu = time.process_time()
    emulator = Emulator("arm", seed=seed, scene="calibration")
    truth = emulator.scene_parts[0]
    rng = np.random.default_rng(100 + seed)
    with Arm.on(EmulatorTransport(emulator, "arm")) as arm:
        arm.torque(True, hold=True)
        arm.home()
        arm.hand = False
        gathered = arm_touches.gather(arm, poses)
        fitted = arm_touches.fit(gathered.data)
        result = fitted.result
        aim = arm_touches.probe_geometry(arm)
        readings, tips = [], []
        for k in range(PHYSICAL_POSES):
            target = [rng.uniform(0.3, 0.55), rng.uniform(-0.2, 0.2), rng.uniform(-0.40, -0.25)]
            rpy = arm_touches.ORIENTATIONS[k % len(arm_touches.ORIENTATIONS)]
            arm.moveto(target, list(rpy), speed=0.4, geometry=aim, hand=False)
            readings.append(np.mean([arm.state().joints for _ in range(10)], axis=0))
            tips.append(truth.tip_m)  # type: ignore[attr-defined]
    q, t = np.array(readings), np.array(tips)
    before = np.linalg.norm(aim.tips(q) - t, axis=1) * 1000
    after = np.linalg.norm(result.geometry.with_tool(ARM_PROBE_TIP_M).tips(q) - t, axis=1) * 1000
    touches = {**gathered.counts, "board": gathered.counts["board"] - fitted.dropped}
    return PhysicalResult(seed, float(before.mean()), float(before.max()), float(after.mean()),
                          float(after.max()), touches, gathered.missed + fitted.dropped,
                          time.process_time() - cpu)


def main(argv: Sequence[str] | None = None) -> int:
    """Print figure 4.4's before/after beside the dissertation's, per seed."""
    parser = argparse.ArgumentParser(prog="python -m tools.experiments.arm_calibration",
                                     description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--emulator", action="store_true",
                        help="also measure held-out poses on the emulated arm (slow)")
    parser.add_argument("--physical", action="store_true",
                        help="the touches made by guarded moves on the calibration scene "
                             "instead (slow: minutes per seed)")
    parser.add_argument("--poses", type=int, default=24,
                        help="board touches of --physical (default 24)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if args.physical:
        physical = [run_physical(seed, args.poses) for seed in args.seeds]
        if args.json:
            print(json.dumps([asdict(r) for r in physical], indent=2))
            return 0
        print(f"end-effector (probe tip) error on held-out poses after the physical "
              f"procedure (mm; dissertation fig. 4.4: mean {DISSERTATION_MM[0]:g} → "
              f"{DISSERTATION_MM[1]:g})")
        for p in physical:
            print(f"seed {p.seed}: CAD mean {p.before_mean_mm:.1f} max {p.before_max_mm:.1f}  →  "
                  f"calibrated mean {p.after_mean_mm:.1f} max {p.after_max_mm:.1f}  "
                  f"(touches {p.touches}, {p.missed} missed; {p.cpu_s:.0f} s CPU)")
        return 0
    results = [run_seed(seed, args.emulator) for seed in args.seeds]
    if args.json:
        print(json.dumps([asdict(r) for r in results], indent=2))
        return 0
    d0, d1 = DISSERTATION_MM
    print(f"end-effector error on held-out touches (mm; dissertation fig. 4.4: mean {d0:g} → "
          f"{d1:g})")
    for r in results:
        line = (f"seed {r.seed}: CAD mean {r.before_mean_mm:.1f} max {r.before_max_mm:.1f}"
                f"  →  calibrated mean {r.after_mean_mm:.2f} max {r.after_max_mm:.2f}"
                f"; no gauge given: CAD {r.raw_before_mean_mm:.1f} → anchored "
                f"{r.anchored_mean_mm:.2f} max {r.anchored_max_mm:.2f}")
        if r.emulator_before_mean_mm is not None:
            line += (f"  | on the emulator: {r.emulator_before_mean_mm:.1f} → "
                     f"{r.emulator_after_mean_mm:.2f} (max {r.emulator_after_max_mm:.2f}); "
                     f"with J1's index error: {r.emulator_raw_before_mean_mm:.1f} → "
                     f"{r.emulator_raw_after_mean_mm:.1f}, anchored "
                     f"{r.emulator_anchored_mean_mm:.2f} (max {r.emulator_anchored_max_mm:.2f})")
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
