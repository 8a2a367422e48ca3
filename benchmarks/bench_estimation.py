"""Inertial joint estimation on the emulated hand: errors against the plant, as in the
dissertation's section 4.6.1 table, and homing.

On ``Emulator("hand")`` (palm up; the thumb, finger 3, has every joint axis observable for
|J0| < 70°), in process on the simulation clock:

* **static**: N random poses of the thumb (moved unhomed, then idled and left to rest); the
  closed form (:mod:`host.inertial_closed_form`, 6 status samples averaged) against the
  plant's MuJoCo joint angles: RMS and max error per joint (deg).  Targets: ≤ 0.5° RMS on
  J2 (distal), ≤ 1° on J0/J1.
* **moving**: the thumb driven through random targets while its status is read at 50 Hz;
  the joint EKF (:mod:`host.joint_ekf`, accelerometers only) and the per-sample closed form
  against the plant at each read (the readings lag by up to one IMU period).
* **homing**: at each static pose, :func:`host.hand_homing.home_finger`; a success is a
  homed finger whose hall-derived joints then read within 1° of the plant; time in
  simulated seconds.

``python -m benchmarks.bench_estimation [--poses 50] [--seed 1]``
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Sequence

import numpy as np

from hil_emulator.emulator import Emulator
from host.errors import HostError
from host.hand import Hand
from host.hand_homing import accels_from_status, home_finger, inertial_estimate
from host.inertial_closed_form import estimate
from host.joint_ekf import JointEkf, accel_counts_to_g

THUMB = 3
JOINTS = ("J0 (abduction)", "J1 (proximal)", "J2 (distal)")


def _pose(rng: np.random.Generator) -> tuple[float, float, float]:
    return (float(rng.uniform(-0.9, 0.9)), float(rng.uniform(-0.3, 1.3)),
            float(rng.uniform(-0.3, 1.3)))


def _row(name: str, errors: Sequence[Sequence[float]]) -> str:
    e = np.degrees(np.asarray(errors, dtype=float))
    cells = [f"{math.sqrt(float(np.nanmean(e[:, j] ** 2))):6.3f} / {np.nanmax(np.abs(e[:, j])):6.3f}"
             for j in range(3)]
    return f"{name:28} " + "  ".join(f"{c:>17}" for c in cells) + f"   n={len(e)}"


def run(poses: int, seed: int) -> None:
    wall = time.perf_counter()
    emulator = Emulator("hand", seed=seed, can="none")
    emulator.bring_up()
    plant = emulator.finger_plants[THUMB]
    hand = Hand.open(emulator.transport("palm"))
    thumb = hand.fingers[THUMB]
    rng = np.random.default_rng(seed)

    static, homed_err = [], []
    successes, home_times = 0, []
    for _ in range(poses):
        thumb.move(_pose(rng), effort=200, timeout=2.0, unhomed=True)
        thumb.idle()
        hand.session.sleep(0.2)
        truth = plant.joint_angles()
        found = inertial_estimate(thumb)
        static.append([np.nan if q is None else q - t for q, t in zip(found.q, truth,
                                                                      strict=True)])
        t0 = hand.session.now()
        try:
            home_finger(thumb)
        except HostError:
            continue
        home_times.append(hand.session.now() - t0)
        err = np.asarray(thumb.status().joints) - plant.joint_angles()
        homed_err.append(err)
        successes += bool(np.all(np.abs(np.degrees(err)) < 1.0))

    ekf = JointEkf(q0=plant.joint_angles(), q0_sigma=0.05)
    moving_ekf, moving_cf = [], []
    for _ in range(4):
        thumb.command(_pose(rng), effort=120)
        end = hand.session.now() + 0.8
        while hand.session.now() < end:
            hand.session.sleep(0.02)
            status = thumb.motor.request("fmcb.status")
            t, truth = hand.session.now(), plant.joint_angles()
            accels = accels_from_status(status)
            g = {b: accel_counts_to_g(v) for b, v in accels.items()}
            ekf.predict(t)
            ekf.update_accels(g["fmcb"], g["f2"], g["f3"], t)
            moving_ekf.append(ekf.q - truth)
            cf = estimate(accels, previous=ekf.q)
            moving_cf.append([np.nan if q is None else q - tr for q, tr in zip(cf.q, truth,
                                                                               strict=True)])
    thumb.idle()

    header = f"{'error (deg): RMS / max':28} " + "  ".join(f"{j:>17}" for j in JOINTS)
    print(header)
    print("-" * len(header))
    print(_row("static, closed form", static))
    print(_row("after homing, hall counts", homed_err or [[np.nan] * 3]))
    print(_row("moving, EKF (accels only)", moving_ekf))
    print(_row("moving, closed form", moving_cf))
    mean_t = float(np.mean(home_times)) if home_times else float("nan")
    print(f"homing: {successes}/{poses} poses homed within 1° "
          f"({100.0 * successes / max(1, poses):.0f} %), {mean_t:.3f} s each (simulated); "
          f"wall {time.perf_counter() - wall:.0f} s")
    hand.close()
    emulator.close()


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_estimation")
    parser.add_argument("--poses", type=int, default=50)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    run(args.poses, args.seed)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
