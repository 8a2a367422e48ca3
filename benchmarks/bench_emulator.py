"""The emulator under nominal traffic: real-time factor (fast mode) and lateness (real time).

Nominal traffic (the load the speed targets are stated for): the four fmcbs run their 1 kHz control loops in
joint mode (holding a pose) and their 100 Hz autopoll of both phalanges (fingers and
phalanges powered and booted), and the host reads the arm at 100 Hz (one BULK_READ of the
seven present positions every 10 ms).  *Heavy* traffic adds the palm polling every
finger's status at 100 Hz and a SYNC_WRITE of the four stepper goals every 10 ms.

* Fast mode, in process: the emulator's CPU time per simulated second (``time.process_time``:
  other processes on the machine do not inflate it) for the full configuration, as simulated
  seconds per CPU second and as a multiple of bare ``mj_step`` of the same model measured in
  the same process (target ≤ 5× with the default build, ≤ 8× in pure Python; each build in
  its own process, :data:`PURE_PYTHON_ENV` selecting pure Python), with simulated seconds per
  wall second beside it; and against the same configuration without the MuJoCo plant
  (firmware and buses only) measured in the same run.
* Real time, as users run it: ``hil-emulator --config full --ready --stats`` (the hand
  brought up) in its own process, this process driving the same traffic over its ptys; p99
  of how late the emulator delivered frames to the host relative to their simulated arrival
  time, with real-time scheduling (``--priority realtime``, where this process may grant
  it) and without (``--priority normal``): idle (target ≤ 1 ms), beside one CPU-bound process
  (a ``while True: pass`` interpreter this bench starts and stops; target ≤ 0.5 ms without
  real-time scheduling), and beside three (targets with real-time scheduling: p99 ≤ 0.5 ms,
  maximum ≤ 2 ms).
* Real-time CPU use: CPU seconds per wall second of the emulator process over the idle
  real-time run (``/proc/PID/stat``), against its need: the CPU seconds per simulated second
  the same configuration takes in fast mode (``time.process_time``, at most one core: the
  loop is one thread).  Real time must sleep between events, not spin, so the target is
  ≤ need + 0.1 core.  CPU time, unlike wall time, is not inflated by other processes on the
  machine, so the fast-mode rows also give simulated seconds per CPU second.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from benchmarks import wakeup_probe
from benchmarks.harness import Result
from hil_emulator.emulator import Emulator
from hil_emulator.inprocess import bring_up
from host.scheduling import request_priority
from protocol import dynamixel as dxl
from protocol.compiled_guard import PURE_PYTHON_ENV
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
    bring_up(emulator)
    if heavy:
        hand.send_from_host(CATALOGUE["palm.poll"].request_frame(ADDR_PALM, rate_hz=100))
    for k in range(FINGERS):
        hand.send_from_host(HOLD_POSE[k])
        emulator.step(30_000)
    for packet in TORQUE_ON:
        arm.send_from_host(packet)
        emulator.step(2_000)


@dataclass(frozen=True)
class FastRun:
    """A fast-mode run: simulated seconds per wall second, CPU seconds (this process,
    ``time.process_time``) per simulated second: the cores real time needs, which other
    processes on the machine do not inflate; and with the plant, the CPU seconds bare
    ``mj_step`` of the same model takes per simulated second in the same process."""

    rtf: float
    cpu_per_sim_s: float
    mj_step_cpu_per_sim_s: float = math.nan

    @property
    def times_mj_step(self) -> float:
        """The emulator's CPU per simulated second as a multiple of bare ``mj_step``'s."""
        return self.cpu_per_sim_s / self.mj_step_cpu_per_sim_s


def bare_mj_step_cpu(emulator: Emulator, sim_s: float) -> float:
    """CPU seconds per simulated second of ``mj_step`` alone on the emulator's model, from a
    copy of its present state (``time.process_time``; best of three)."""
    import mujoco

    plant = emulator.plant
    assert plant is not None
    model = plant.model
    steps = max(200, int(sim_s / model.opt.timestep))
    best = math.inf
    for _ in range(3):
        data = mujoco.MjData(model)
        mujoco.mj_copyData(data, model, plant.data)
        cpu = time.process_time()
        for _ in range(steps):
            mujoco.mj_step(model, data)
        best = min(best, (time.process_time() - cpu) / (steps * model.opt.timestep))
    return best


def fast_rtf(physics: bool, sim_s: float, heavy: bool = False) -> FastRun:
    """Simulated seconds per wall second (and CPU per simulated second, and bare
    ``mj_step``'s with the plant) of the booted full configuration under traffic."""
    emulator = Emulator("full", seed=1, physics=physics, can="none")
    boot_full(emulator, heavy)
    arm = emulator.arm
    assert arm is not None
    hand_bytes: list[int] = []
    emulator.hand.on_host_bytes = lambda data, t: hand_bytes.append(len(data))  # type: ignore[union-attr]
    arm.on_host_bytes = lambda data, t: None
    periods = int(sim_s * 100)
    start, cpu = time.perf_counter(), time.process_time()
    for k in range(periods):
        arm.send_from_host(ARM_READ)
        if heavy:
            arm.send_from_host(_arm_write(k))
        emulator.step(10_000)
    simulated = periods / 100
    rtf = simulated / (time.perf_counter() - start)
    cpu_per_sim_s = (time.process_time() - cpu) / simulated
    bare = bare_mj_step_cpu(emulator, sim_s) if physics else math.nan
    return FastRun(rtf, cpu_per_sim_s, bare)


def fast_run_of_build(pure_python: bool, sim_s: float) -> tuple[FastRun, int]:
    """:func:`fast_rtf` of the full configuration with its plant in a process of its own,
    on the default build or (``pure_python``) forced to pure Python; with how many modules
    that process imported compiled."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), PURE_PYTHON_ENV: "1" if pure_python else "0"}
    out = subprocess.run([sys.executable, "-m", "benchmarks.bench_emulator", str(sim_s)],
                         cwd=ROOT, env=env, capture_output=True, text=True, check=True).stdout
    data = json.loads(out.strip().splitlines()[-1])
    return (FastRun(data["rtf"], data["cpu_per_sim_s"], data["mj_step_cpu_per_sim_s"]),
            int(data["compiled"]))


#: The lateness targets (ms, p99): an idle machine; one CPU-bound process beside, without
#: real-time scheduling; three beside, with it (and its maximum).
LATENESS_TARGET_MS: Final = 1.0
LATENESS_HOGGED_TARGET_MS: Final = 0.5
LATENESS_3_HOGS_RT_TARGET_MS: Final = 0.5
LATENESS_3_HOGS_RT_MAX_MS: Final = 2.0
#: The emulator's CPU per simulated second at most this multiple of bare mj_step's (full,
#: fast, nominal traffic): the default build (compiled where it could be built), pure Python.
TIMES_MJ_STEP_TARGET: Final = 5.0
TIMES_MJ_STEP_PURE_TARGET: Final = 8.0
#: Real time may use this much more CPU than fast mode needs for the same simulated time
#: (cores).
CPU_MARGIN: Final = 0.1
#: A CPU-bound process: an interpreter spinning.
HOG: Final = (sys.executable, "-c", "while True: pass")


def cpu_s(pid: int) -> float:
    """CPU time (user + system) process ``pid`` has used so far (s; ``/proc/PID/stat``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@contextmanager
def cpu_hog(count: int = 1) -> Iterator[list[subprocess.Popen[bytes]]]:
    """``count`` CPU-bound processes running for the ``with`` block (killed, and reaped,
    after)."""
    hogs = [subprocess.Popen(HOG) for _ in range(count)]
    try:
        yield hogs
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()


def machine_stalls(wall_s: float) -> dict[str, float]:
    """:mod:`benchmarks.wakeup_probe` for ``wall_s`` seconds in a process of its own: the
    machine's own wake-up delays (ms) for a real-time thread, the emulator's baseline."""
    proc = subprocess.run([sys.executable, "-m", "benchmarks.wakeup_probe", "--seconds",
                           str(wall_s)], cwd=ROOT, capture_output=True, text=True,
                          timeout=wall_s + 60, check=True)
    return dict(json.loads(proc.stdout))


def realtime_allowed() -> bool:
    """Whether a process started from this one may take real-time scheduling."""
    import threading

    got: list[bool] = []
    thread = threading.Thread(target=lambda: got.append(request_priority("realtime").realtime))
    thread.start()
    thread.join()
    return got[0]


def realtime_lateness(wall_s: float, config: str = "full",
                      priority: str = "normal") -> dict[str, float]:
    """Run ``hil-emulator --config CONFIG --stats --ready --priority PRIORITY`` and drive
    nominal traffic over its ports for ``wall_s`` seconds; return its lateness stats, plus
    ``cpu_per_wall``: the emulator's CPU seconds per wall second while the traffic ran."""
    import serial

    proc = subprocess.Popen([sys.executable, "-m", "tools.cli.serve_emulator", "--config", config,
                             "--can", "none", "--stats", "--ready", "--priority", priority],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
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
        cpu0, wall0 = cpu_s(proc.pid), time.monotonic()
        next_t = wall0
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
        cpu_per_wall = (cpu_s(proc.pid) - cpu0) / (time.monotonic() - wall0)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    line = next(x for x in err.splitlines() if x.startswith("hil-emulator stats:"))
    return {**json.loads(line.partition(":")[2]), "cpu_per_wall": cpu_per_wall}


def _lateness_result(name: str, stats: dict[str, float], target_ms: float | None,
                     what: str = "p99") -> Result:
    if stats["p99_ms"] is None:  # nothing was delivered
        stats = {**stats, "p50_ms": math.nan, "p99_ms": math.nan, "max_ms": math.nan}
    figure = stats["p99_ms"] if what == "p99" else stats["max_ms"]
    return Result(
        "emulator realtime", f"{name}: lateness {what}", figure, "ms",
        target=target_ms, at_most=True,
        note=f"p50 {stats['p50_ms']:.3f} ms, p99 {stats['p99_ms']:.3f} ms, max "
             f"{stats['max_ms']:.2f} ms over {int(stats['count'])} deliveries in "
             f"{stats['sim_s']:.1f} s, {stats['slipped_s']:.2f} s slipped; "
             f"{stats.get('scheduling')}")


def _compiled_note() -> str:
    """Whether the optional compiled core (``make compiled``) is what ran."""
    loaded = loaded_compiled()
    if not loaded:
        return "compiled: not built (pure Python)"
    return f"compiled: {len(loaded)} of {len(COMPILED_MODULES)} modules (make compiled)"


def _times_mj_step_result(name: str, run: FastRun, compiled: int, target: float) -> Result:
    build = (f"{compiled} of {len(COMPILED_MODULES)} modules compiled" if compiled
             else "pure Python")
    return Result("emulator fast", name, run.times_mj_step, "× mj_step", target=target,
                  at_most=True,
                  note=f"{run.cpu_per_sim_s * 1e3:.1f} ms CPU per sim s "
                       f"({1 / run.cpu_per_sim_s:.2f} sim-s per CPU s) vs bare mj_step "
                       f"{run.mj_step_cpu_per_sim_s * 1e3:.1f} ms; wall: {run.rtf:.2f} sim-s "
                       f"per wall s; {build}")


def run(quick: bool) -> list[Result]:
    sim_s = 0.5 if quick else 5.0
    firmware_only = fast_rtf(physics=False, sim_s=sim_s)
    full = fast_rtf(physics=True, sim_s=sim_s)
    heavy = fast_rtf(physics=True, sim_s=sim_s, heavy=True)
    default, compiled = fast_run_of_build(False, sim_s)
    pure, _ = fast_run_of_build(True, sim_s)
    results = [
        Result("emulator fast", "full, firmware + buses only", firmware_only.rtf, "sim-s",
               note=f"booted, nominal traffic, no plant; "
                    f"{1 / firmware_only.cpu_per_sim_s:.2f} sim-s per CPU s"),
        Result("emulator fast", "full, with MuJoCo plant", full.rtf, "sim-s",
               baseline="full, firmware + buses only", target=4.0,
               note=f"real-time factor: simulated s per wall s; "
                    f"{1 / full.cpu_per_sim_s:.2f} sim-s per CPU s; "
                    f"{full.times_mj_step:.1f}× bare mj_step; {_compiled_note()}"),
        Result("emulator fast", "full, plant, heavy traffic", heavy.rtf, "sim-s",
               baseline="full, with MuJoCo plant",
               note=f"+ palm polls fingers at 100 Hz, arm SYNC_WRITE at 100 Hz; "
                    f"{1 / heavy.cpu_per_sim_s:.2f} sim-s per CPU s"),
        _times_mj_step_result("full, default build: CPU per sim s", default, compiled,
                              TIMES_MJ_STEP_TARGET),
        _times_mj_step_result("full, pure Python: CPU per sim s", pure, 0,
                              TIMES_MJ_STEP_PURE_TARGET),
    ]
    wall_s = 1.0 if quick else 8.0
    rt = "realtime" if realtime_allowed() else None
    idle = realtime_lateness(wall_s, "full")
    with cpu_hog():
        hogged = realtime_lateness(wall_s, "full")
    need = full.cpu_per_sim_s
    results += [
        _lateness_result("full, hand up", idle, LATENESS_TARGET_MS),
        _lateness_result("full, hand up, 1 CPU hog", hogged, LATENESS_HOGGED_TARGET_MS),
    ]
    if rt is None:
        results.append(Result("emulator realtime",
                              "full, hand up, 3 CPU hogs, real-time scheduling: not allowed here",
                              math.nan, "ms", target=LATENESS_3_HOGS_RT_TARGET_MS,
                              at_most=True,
                              note="run the bench as root or with CAP_SYS_NICE or an rtprio "
                                   "limit (docs/EMULATOR.md) for the rows with it"))
    else:
        idle_rt = realtime_lateness(wall_s, "full", rt)
        with cpu_hog():
            hogged_rt = realtime_lateness(wall_s, "full", rt)
        with cpu_hog(3):
            machine = machine_stalls(wall_s)
            three_rt = realtime_lateness(wall_s, "full", rt)
        results += [
            _lateness_result("full, hand up, real-time scheduling", idle_rt, LATENESS_TARGET_MS),
            _lateness_result("full, hand up, 1 CPU hog, real-time scheduling", hogged_rt, None),
            _lateness_result("full, hand up, 3 CPU hogs, real-time scheduling", three_rt,
                             LATENESS_3_HOGS_RT_TARGET_MS),
            _lateness_result("full, hand up, 3 CPU hogs, real-time scheduling", three_rt,
                             LATENESS_3_HOGS_RT_MAX_MS, what="max"),
            Result("emulator realtime", "baseline, 3 CPU hogs: a bare real-time sleeper's "
                   "longest stall", machine["max_ms"], "ms", at_most=True,
                   note=f"p99 {machine['p99_ms']:.3f} ms over {int(machine['count'])} "
                        f"wake-ups of {wakeup_probe.SLEEP_S * 1e3:.1f} ms sleeps, "
                        f"{machine['scheduling']}, beside the same hogs just before: the "
                        "machine's own, which no program here can beat"),
        ]
    results += [
        _lateness_result("arm", realtime_lateness(wall_s, "arm"), LATENESS_TARGET_MS),
        Result("emulator realtime", "full, hand up: CPU per wall s", idle["cpu_per_wall"],
               "cores", target=min(need, 1.0) + CPU_MARGIN, at_most=True,
               note=f"need {need:.2f} CPU s per sim s (fast mode, at most 1 core) "
                    f"+ {CPU_MARGIN}; {hogged['cpu_per_wall']:.2f} cores beside the hog"),
    ]
    return results


def main(argv: list[str] | None = None) -> int:
    """``python -m benchmarks.bench_emulator SIM_S``: one fast-mode run of the full
    configuration with its plant (:func:`fast_rtf`) in this process, as a JSON line."""
    sim_s = float((argv if argv is not None else sys.argv[1:])[0])
    run_ = fast_rtf(physics=True, sim_s=sim_s)
    print(json.dumps({"rtf": run_.rtf, "cpu_per_sim_s": run_.cpu_per_sim_s,
                      "mj_step_cpu_per_sim_s": run_.mj_step_cpu_per_sim_s,
                      "compiled": len(loaded_compiled())}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
