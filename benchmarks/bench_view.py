"""What the live browser view costs the robot's loop: cycles per CPU second, view on and off.

The host loop is :meth:`host.arm.facade.Arm.cycle` on ``emu://arm/arm`` (the emulator in this
process, MuJoCo plant on).  One arm runs blocks of cycles without and with a view attached
(:class:`host.view.live.RobotView` on free ports, its server a child process, nobody watching;
by default 10 states a second by the simulation clock through a bounded queue to one
drawing thread, which sends them half a second of the robot's time at a time), in pairs of
adjacent blocks (off-on, on-off, …, so a drift of the machine
falls on both sides); a block ends when the view has drawn and sent all it was given.
Each block is measured as process CPU time (``time.process_time``: every thread of this
process, the drawing thread and rerun's included), never wall time, so the figures hold on
a busy machine; the ``ratio`` is the median over the pairs of (cycles per CPU s, on) /
(cycles per CPU s, off).  Target: ratio ≥ 0.95.

Beside it, measured directly: the CPU the view's threads in this process spent per state
drawn (process CPU − the loop thread's CPU, in the blocks with the view), and the CPU of
the server child (rerun's, which is not this process's and not in the ratio: reported so
that the whole cost is in view).  The same with every state offered (no rate limit, the
queue dropping what the thread cannot draw) shows what the rate limit protects.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass, field

from benchmarks.harness import Result
from hil_emulator.inprocess import forget_shared_emulators
from host.arm.facade import Arm
from host.view.live import SEND_INTERVAL_S, RobotView

HOLD = [0.0, 0.3, 0.0, 0.6, 0.0, 0.3, 0.0]
#: The target: cycles per CPU second with the view ≥ this × without.
TARGET_RATIO = 0.95


@dataclass
class Run:
    """What one view's blocks measured."""

    rates: dict[bool, list[float]] = field(default_factory=lambda: {False: [], True: []})
    #: CPU s spent in this process outside the loop's thread, in blocks with the view.
    side_cpu_s: float = 0.0
    #: CPU s of the server child over the blocks with the view and without.
    child_cpu_s: dict[bool, float] = field(default_factory=lambda: {False: 0.0, True: 0.0})
    #: Loop CPU s (process) in blocks with the view.
    on_cpu_s: float = 0.0
    drawn: int = 0
    dropped: int = 0
    sim_s: float = 0.0

    @property
    def pairs(self) -> list[float]:
        """Each pair's (cycles per CPU s, on) / (cycles per CPU s, off), sorted."""
        return sorted(on / off for on, off in zip(self.rates[True], self.rates[False],
                                                  strict=True))

    @property
    def ratio(self) -> float:
        """Median of the pairs' ratios."""
        return statistics.median(self.pairs)

    @property
    def spread(self) -> str:
        """The middle half of the pairs' ratios (how noisy the machine was)."""
        q = statistics.quantiles(self.pairs, n=4) if len(self.pairs) > 1 else self.pairs * 3
        return f"{q[0]:.2f}–{q[2]:.2f}"

    @property
    def side_share(self) -> float:
        """The view's threads' share of the process's CPU in the blocks with the view (%)."""
        return 100 * self.side_cpu_s / self.on_cpu_s

    @property
    def off(self) -> float:
        return statistics.median(self.rates[False])


def measure(view: RobotView, pairs: int, cycles: int, name: str) -> Run:
    """Blocks of ``cycles`` arm cycles, ``pairs`` pairs of them, with ``view`` off and on."""
    arm = Arm.open(f"emu://arm/arm?name={name}")
    arm.torque(True)
    commands = arm.make_positions(HOLD)
    view.attach_arm(arm)
    tap = arm.state_taps[-1]
    for _ in range(20):  # warm up the view's first drawings and the emulator
        arm.cycle(commands)
    view.drain()
    run = Run()
    drawn, dropped = view.drawn, view.dropped
    for block in range(2 * pairs):
        on = block % 4 in (1, 2)  # off on, on off, off on, …
        if on and tap not in arm.state_taps:
            arm.state_taps.append(tap)
        elif not on and tap in arm.state_taps:
            arm.state_taps.remove(tap)
        t0, child0 = arm.transport.now(), view.server_cpu_s() or 0.0
        c0, loop0 = time.process_time(), time.thread_time()
        for _ in range(cycles):
            arm.cycle(commands)
        view.drain()
        view.rec.flush()
        cpu, loop = time.process_time() - c0, time.thread_time() - loop0
        run.rates[on].append(cycles / cpu)
        run.child_cpu_s[on] += (view.server_cpu_s() or 0.0) - child0
        if on:
            run.side_cpu_s += cpu - loop
            run.on_cpu_s += cpu
        run.sim_s = arm.transport.now() - t0
    run.drawn, run.dropped = view.drawn - drawn, view.dropped - dropped
    arm.close()
    view.close()
    forget_shared_emulators()
    return run


def run(quick: bool) -> list[Result]:
    pairs, cycles = (4, 150) if quick else (12, 600)
    group = "live view"
    rated = measure(RobotView(web_port=0), pairs, cycles, "bench_view")
    flood = measure(RobotView(web_port=0, max_rate_hz=1e6, queue_size=256),
                    max(2, pairs // 2), cycles, "bench_view_all")
    states = max(1, rated.drawn)
    side_us = 1e6 * rated.side_cpu_s / states
    child_us = 1e6 * rated.child_cpu_s[True] / states
    child_share = 100 * rated.child_cpu_s[True] / rated.on_cpu_s
    return [
        Result(group, "arm cycles, view off", rated.off, "cyc",
               note=f"per CPU s (process CPU time), emu:// in process; median of {pairs} "
                    f"blocks of {cycles} cycles ({rated.sim_s:.2f} simulated s each)"),
        Result(group, "arm cycles, view on (10 Hz)", rated.off * rated.ratio, "cyc",
               baseline="arm cycles, view off", target=TARGET_RATIO * rated.off,
               note=f"ratio {rated.ratio:.3f} (target ≥ {TARGET_RATIO}; median of {pairs} "
                    f"adjacent on/off pairs, middle half {rated.spread}); {rated.drawn} "
                    f"states drawn, {rated.dropped} dropped"),
        Result(group, "view threads, share of CPU", rated.side_share, "%", at_most=True,
               note="measured directly: this process's CPU outside the loop's thread "
                    "(drawing, rerun's encoding and sending) in the blocks with the view; "
                    "the ratio's cost without the machine's noise, less the tap"),
        Result(group, "view threads, CPU per state", side_us, "µs", at_most=True,
               note=f"{rated.drawn} states, sent by {SEND_INTERVAL_S:g} s of the robot's "
                    "time and at each block's end"),
        Result(group, "server child, CPU per state", child_us, "µs", at_most=True,
               note=f"rerun's server process (not in the ratio): {child_share:.1f} % of the "
                    f"loop's CPU; {1e3 * rated.child_cpu_s[False]:.0f} ms idle over the "
                    "blocks without the view (/proc, 10 ms ticks)"),
        Result(group, "arm cycles, view on (every cycle)", rated.off * flood.ratio, "cyc",
               baseline="arm cycles, view off",
               note=f"ratio {flood.ratio:.2f} (middle half {flood.spread}; view threads "
                    f"{flood.side_share:.0f} % of the CPU); {flood.drawn} drawn, "
                    f"{flood.dropped} dropped by the bounded queue (the loop never waits)"),
    ]
