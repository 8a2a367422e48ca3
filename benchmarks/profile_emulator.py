"""Where the emulator's time goes under nominal traffic (fast mode, full configuration).

``python -m benchmarks.profile_emulator [--sim-s 3] [--no-physics] [--cprofile] [--sample]``

Boots the full configuration as :mod:`benchmarks.bench_emulator` does (fingers holding
their pose in joint mode with autopoll, arm torque on, the host reading the arm at 100 Hz),
then runs ``--sim-s`` simulated seconds and prints

* the real-time factor (simulated s per wall s, and per CPU s: the latter is steadier on a
  shared machine),
* wall time per simulated second spent in each kind of scheduler callback (a firmware
  tick, a bus delivery, the plant tick …), with its rate and cost per call,
* the plant tick split into ``mj_step`` and each part's ``before_step`` / ``after_step``,
* with ``--cprofile``, the top of a cProfile run sorted by own time and by cumulative
  time (the profiler inflates Python calls several-fold: use it for ranking only),
* with ``--sample``, a sampling profile: the Python stack is looked at every 0.5 ms of CPU
  time (``SIGPROF``), so small functions are not inflated; each function's share of the
  samples where it was running (own) and where it was on the stack (cumulative).  A C call
  (``mj_step``) counts as its Python caller's own time.

It is not a ``bench_*`` module, so ``python -m benchmarks`` does not run it.
"""

from __future__ import annotations

import argparse
import collections
import cProfile
import io
import pstats
import signal
import time
from collections.abc import Callable

import mujoco

from benchmarks.bench_emulator import ARM_READ, boot_full
from firmware_py.scheduler import Scheduler
from hil_emulator.emulator import Emulator
from tests.firmware_py.reference_scheduler import run_due


def booted(physics: bool) -> Emulator:
    """The full configuration, booted, nominal traffic set up, host output discarded."""
    emulator = Emulator("full", seed=1, physics=physics, can="none")
    boot_full(emulator, heavy=False)
    assert emulator.hand is not None and emulator.arm is not None
    emulator.hand.on_host_bytes = lambda data, t: None
    emulator.arm.on_host_bytes = lambda data, t: None
    return emulator


def drive(emulator: Emulator, sim_s: float) -> tuple[float, float]:
    """Nominal traffic for ``sim_s`` s; returns (wall s, CPU s)."""
    arm = emulator.arm
    assert arm is not None
    wall, cpu = time.perf_counter(), time.process_time()
    for _ in range(int(sim_s * 100)):
        arm.send_from_host(ARM_READ)
        emulator.step(10_000)
    return time.perf_counter() - wall, time.process_time() - cpu


def _timed_run_until(acc: collections.defaultdict[str, float], calls: collections.Counter[str]
                     ) -> Callable[[Scheduler, int], int]:
    """A :meth:`Scheduler.run_until` that times each callback (same event order)."""
    clock = time.perf_counter

    def timed(cb: Callable[[], None]) -> None:
        start = clock()
        cb()
        key = getattr(cb, "__qualname__", type(cb).__name__)
        acc[key] += clock() - start
        calls[key] += 1

    def run_until(self: Scheduler, t_us: int) -> int:
        return run_due(self, t_us, timed)

    return run_until


def _time_group_members(scheduler: Scheduler, acc: collections.defaultdict[str, float],
                        calls: collections.Counter[str]) -> None:
    """Time each member of the scheduler's tick groups (timers of one period and phase
    sharing a queue entry) as a kind of its own; the group's entry is then what the sharing
    itself costs (``_TickGroup.run``, members' time included: subtract them)."""
    clock = time.perf_counter
    for shared in list(getattr(scheduler, "_ticks", {}).values()):
        for member in getattr(shared, "members", ()):
            cb = member.callback
            if cb is None:
                continue
            key = f"{getattr(cb, '__qualname__', type(cb).__name__)} (in a tick group)"

            def timed(cb: Callable[[], None] = cb, key: str = key) -> None:
                start = clock()
                cb()
                acc[key] += clock() - start
                calls[key] += 1

            member.callback = timed


def breakdown(physics: bool, sim_s: float) -> list[str]:
    """Lines: real-time factor, callbacks by kind, the plant tick's split."""
    emulator = booted(physics)
    acc: collections.defaultdict[str, float] = collections.defaultdict(float)
    calls: collections.Counter[str] = collections.Counter()
    plant_acc: collections.defaultdict[str, float] = collections.defaultdict(float)
    scheduler = emulator.scheduler
    try:
        scheduler.run_until = _timed_run_until(acc, calls).__get__(scheduler)  # type: ignore[method-assign]
    except AttributeError:  # a compiled Scheduler (tools.build_compiled): no per-callback split
        pass
    plant = emulator.plant
    if plant is not None and plant._timer is not None:
        clock = time.perf_counter

        def tick() -> None:  # Plant.tick, each stage timed
            model, data, dt = plant.model, plant.data, plant._dt_s
            data.qfrc_applied[:] = 0.0
            for part in plant.parts:
                start = clock()
                part.before_step(dt)
                plant_acc[f"before_step {type(part).__name__}"] += clock() - start
            start = clock()
            for _ in range(plant.substeps):
                mujoco.mj_step(model, data)
            plant_acc["mj_step"] += clock() - start
            for part in plant.parts:
                start = clock()
                part.after_step(dt)
                plant_acc[f"after_step {type(part).__name__}"] += clock() - start
            plant.ticks += 1

        tick.__qualname__ = "Plant.tick"
        plant._timer.callback = tick
    _time_group_members(scheduler, acc, calls)
    wall, cpu = drive(emulator, sim_s)
    lines = [f"{'with' if physics else 'without'} plant: {sim_s / wall:.2f} sim-s per wall s, "
             f"{sim_s / cpu:.2f} per CPU s (timed: the timing itself costs some)",
             f"{'ms/sim-s':>9s} {'calls/s':>8s} {'µs/call':>8s}  callback"]
    for key, spent in sorted(acc.items(), key=lambda kv: -kv[1])[:20]:
        lines.append(f"{spent / sim_s * 1e3:9.1f} {calls[key] / sim_s:8.0f} "
                     f"{spent / calls[key] * 1e6:8.1f}  {key}")
    for key, spent in sorted(plant_acc.items(), key=lambda kv: -kv[1]):
        lines.append(f"{spent / sim_s * 1e3:9.1f} {'':8s} {'':8s}    plant: {key}")
    return lines


def profile(physics: bool, sim_s: float, top: int = 30) -> str:
    """cProfile of the driven run: top entries by own time and by cumulative time."""
    emulator = booted(physics)
    profiler = cProfile.Profile()
    profiler.enable()
    drive(emulator, sim_s)
    profiler.disable()
    out = io.StringIO()
    stats = pstats.Stats(profiler, stream=out)
    stats.sort_stats("tottime").print_stats(top)
    stats.sort_stats("cumtime").print_stats(top)
    return out.getvalue()


def sample(physics: bool, sim_s: float, top: int = 40, interval_s: float = 0.0005) -> str:
    """Sampling profile of the driven run: shares of own and cumulative samples (%)."""
    emulator = booted(physics)
    own: collections.Counter[str] = collections.Counter()
    cum: collections.Counter[str] = collections.Counter()
    total = 0

    def on_sample(signum: int, frame: object) -> None:
        nonlocal total
        total += 1
        seen: set[str] = set()
        f = frame
        first = True
        while f is not None:
            code = f.f_code  # type: ignore[attr-defined]
            key = f"{code.co_filename.rsplit('/', 1)[-1]}:{code.co_name}"
            if first:
                own[key] += 1
                first = False
            if key not in seen:
                cum[key] += 1
                seen.add(key)
            f = f.f_back  # type: ignore[attr-defined]

    previous = signal.signal(signal.SIGPROF, on_sample)
    signal.setitimer(signal.ITIMER_PROF, interval_s, interval_s)
    try:
        drive(emulator, sim_s)
    finally:
        signal.setitimer(signal.ITIMER_PROF, 0.0, 0.0)
        signal.signal(signal.SIGPROF, previous)
    lines = [f"{total} samples; own (running):"]
    lines += [f"{100 * n / total:6.1f}%  {key}" for key, n in own.most_common(top)]
    lines.append("cumulative (on the stack):")
    lines += [f"{100 * n / total:6.1f}%  {key}" for key, n in cum.most_common(top)]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.profile_emulator")
    parser.add_argument("--sim-s", type=float, default=3.0, help="simulated seconds")
    parser.add_argument("--no-physics", action="store_true", help="firmware and buses only")
    parser.add_argument("--cprofile", action="store_true", help="also a cProfile run")
    parser.add_argument("--sample", action="store_true", help="also a sampling profile")
    args = parser.parse_args(argv)
    physics = not args.no_physics
    print("\n".join(breakdown(physics, args.sim_s)))
    if args.cprofile:
        print(profile(physics, args.sim_s))
    if args.sample:
        print(sample(physics, args.sim_s))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
