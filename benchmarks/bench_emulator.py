"""The emulator under nominal traffic: real-time factor (fast mode) and lateness (real time).

Nominal traffic (the load the speed targets are stated for): the four fmcbs run their 1 kHz control loops in
joint mode (holding a pose) and their 100 Hz autopoll of both phalanges (fingers and
phalanges powered and booted), and the host reads the arm at 100 Hz (one BULK_READ of the
seven present positions every 10 ms).  *Heavy* traffic adds the palm polling every
finger's status at 100 Hz and a SYNC_WRITE of the four stepper goals every 10 ms.

* Fast mode, in process: simulated seconds per wall second for the full configuration
  (target ≥ 3), against the same configuration without the MuJoCo plant (firmware and buses
  only) measured in the same run.
* Real time, as users run it: ``hil-emulator --config full --stats`` in its own process, this
  process driving the same traffic over its ptys; p99 of how late the emulator delivered
  frames to the host relative to their simulated arrival time (target ≤ 1 ms).
"""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import time
from pathlib import Path

from benchmarks.harness import Result
from hil_emulator.emulator import Emulator
from protocol import dynamixel as dxl
from protocol.control_tables import RX64_TABLE, STEPPER_TABLE, TABLES_BY_MODEL
from protocol.messages import CATALOGUE
from protocol.messages.fmcb import ControlMode
from protocol.topology import (
    ADDR_PALM,
    ARM_BUS_BAUD,
    ARM_JOINTS,
    FINGERS,
    HOP_ADDRESS,
    HOST_LINK_BAUD,
    SERVO_IDS,
    STEPPER_IDS,
    Hop,
)
from tools.build_compiled import COMPILED_MODULES, loaded_compiled

S = 1_000_000
ROOT = Path(__file__).resolve().parents[1]
TORQUE_ON = [dxl.make_write(j.dxl_id, TABLES_BY_MODEL[j.model_number]["torque_enable"].address,
                            b"\x01").encode() for j in ARM_JOINTS]
ARM_READ = dxl.make_bulk_read(
    [(4, i, STEPPER_TABLE["present_position"].address) for i in STEPPER_IDS]
    + [(2, i, RX64_TABLE["present_position"].address) for i in SERVO_IDS]).encode()


def _sync_write(goal_counts: int) -> bytes:
    goals = {i: goal_counts.to_bytes(4, "little", signed=True) for i in STEPPER_IDS}
    return dxl.make_sync_write(STEPPER_TABLE["goal_position"].address, 4, goals).encode()


#: The host's goal pattern, built once (the host's own packet building is not measured).
ARM_WRITES = [_sync_write(50 * k) for k in range(20)]


def _arm_write(k: int) -> bytes:
    return ARM_WRITES[k % 20]


def _hold_pose(finger: int) -> bytes:
    """fmcb.control joint mode, targets 0 rad (the pose the fingers start in), routed."""
    inner = CATALOGUE["fmcb.control"].request_frame(HOP_ADDRESS[Hop.FMCB], mode=ControlMode.JOINT,
                                                    args={"target": [0.0] * 3})
    return CATALOGUE["palm.route"].request_frame(ADDR_PALM, finger=finger, hop=Hop.FMCB,
                                                 timeout_ms=0, frame=inner)


HOLD_POSE = [_hold_pose(k) for k in range(FINGERS)]


def boot_full(emulator: Emulator, heavy: bool = True) -> None:
    """Bring the full configuration up as a host would (palm, fingers, phalanges, autopoll:
    :meth:`Emulator.bring_up`), fingers holding their pose in joint mode, arm torque on
    (and, ``heavy``, the palm polling every finger)."""
    hand, arm = emulator.hand, emulator.arm
    assert hand is not None and arm is not None
    emulator.bring_up()
    if heavy:
        hand.send_from_host(CATALOGUE["palm.poll"].request_frame(ADDR_PALM, rate_hz=100))
    for k in range(FINGERS):
        hand.send_from_host(HOLD_POSE[k])
        emulator.step(30_000)
    for packet in TORQUE_ON:
        arm.send_from_host(packet)
        emulator.step(2_000)


def fast_rtf(physics: bool, sim_s: float, heavy: bool = False) -> float:
    """Simulated seconds per wall second of the booted full configuration under traffic."""
    emulator = Emulator("full", seed=1, physics=physics, can="none")
    boot_full(emulator, heavy)
    arm = emulator.arm
    assert arm is not None
    hand_bytes: list[int] = []
    emulator.hand.on_host_bytes = lambda data, t: hand_bytes.append(len(data))  # type: ignore[union-attr]
    arm.on_host_bytes = lambda data, t: None
    periods = int(sim_s * 100)
    start = time.perf_counter()
    for k in range(periods):
        arm.send_from_host(ARM_READ)
        if heavy:
            arm.send_from_host(_arm_write(k))
        emulator.step(10_000)
    return periods / 100 / (time.perf_counter() - start)


def realtime_lateness(wall_s: float, config: str = "full") -> dict[str, float]:
    """Run ``hil-emulator --config CONFIG --stats --ready`` and drive nominal traffic over
    its ports for ``wall_s`` seconds; return its lateness stats."""
    import serial

    proc = subprocess.Popen([sys.executable, "-m", "tools.hil_emulator", "--config", config,
                             "--can", "none", "--stats", "--ready"], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        info = json.loads(proc.stdout.readline())
        palm = serial.Serial(info["palm"], HOST_LINK_BAUD, timeout=0) if info["palm"] else None
        arm = serial.Serial(info["arm"], ARM_BUS_BAUD, timeout=0) if info["arm"] else None
        if palm is not None:  # --ready: the hand is up; hold the fingers' pose
            for k in range(FINGERS):
                palm.write(HOLD_POSE[k])
                time.sleep(0.03)
        if arm is not None:
            for packet in TORQUE_ON:
                arm.write(packet)
                time.sleep(0.002)
        next_t = time.monotonic()
        end = next_t + wall_s
        k = 0
        while next_t < end:
            if arm is not None:
                arm.write(ARM_READ)
                arm.read(65536)
            if palm is not None:
                palm.read(65536)
            k += 1
            next_t += 0.010
            time.sleep(max(0.0, next_t - time.monotonic()))
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    line = next(x for x in err.splitlines() if x.startswith("hil-emulator stats:"))
    return dict(json.loads(line.partition(":")[2]))


def _lateness_result(config: str, stats: dict[str, float]) -> Result:
    if stats["p99_ms"] is None:  # nothing was delivered
        stats = {**stats, "p50_ms": math.nan, "p99_ms": math.nan, "max_ms": math.nan}
    p99_ms = stats["p99_ms"]
    return Result(
        "emulator realtime", f"{config}: lateness p99 (1/ms)", 1.0 / max(p99_ms, 1e-6), "1/ms",
        target=1.0,
        note=f"p99 {p99_ms:.3f} ms, p50 {stats['p50_ms']:.3f} ms, max {stats['max_ms']:.2f} ms "
             f"over {int(stats['count'])} deliveries in {stats['sim_s']:.1f} s")


def _compiled_note() -> str:
    """Whether the optional compiled core (``make compiled``) is what ran."""
    loaded = loaded_compiled()
    if not loaded:
        return "compiled: not built (pure Python)"
    return f"compiled: {len(loaded)} of {len(COMPILED_MODULES)} modules (make compiled)"


def run(quick: bool) -> list[Result]:
    sim_s = 2.0 if quick else 5.0
    firmware_only = fast_rtf(physics=False, sim_s=sim_s)
    full = fast_rtf(physics=True, sim_s=sim_s)
    heavy = fast_rtf(physics=True, sim_s=sim_s, heavy=True)
    results = [
        Result("emulator fast", "full, firmware + buses only", firmware_only, "sim-s",
               note="booted, nominal traffic, no plant"),
        Result("emulator fast", "full, with MuJoCo plant", full, "sim-s",
               baseline="full, firmware + buses only", target=3.0,
               note=f"real-time factor: simulated s per wall s; {_compiled_note()}"),
        Result("emulator fast", "full, plant, heavy traffic", heavy, "sim-s",
               baseline="full, with MuJoCo plant",
               note="+ palm polls fingers at 100 Hz, arm SYNC_WRITE at 100 Hz"),
    ]
    wall_s = 3.0 if quick else 8.0
    results.append(_lateness_result("full", realtime_lateness(wall_s, "full")))
    results.append(_lateness_result("arm", realtime_lateness(wall_s, "arm")))
    return results
