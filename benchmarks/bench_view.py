"""What the live browser view costs the robot's loop: cycles per CPU second, view on and off.

The host loop is :meth:`host.arm.Arm.cycle` on ``emu://arm/arm`` (the emulator in this
process, MuJoCo plant on).  One arm runs blocks of cycles alternately without and with a
view attached (:class:`host.view.RobotView` serving its page and data on free ports, nobody
watching; by default 10 states a second by the simulation clock through a bounded queue to
one logging thread); a block with the view ends when the view has drawn all it was given.
Each block is measured as process CPU time (``time.process_time``: the logging thread's
work counts), never wall time, and the median block of each kind is compared, so the
ratio holds on a busy machine.  Target: the view on keeps ≥ 95 % of the loop's cycles per
CPU second.  The same with every state offered (no rate limit, the queue dropping what the
thread cannot draw) shows what the bound protects, and the view's own cost per state drawn
(µs CPU, rerun's logging calls included) is printed beside it.
"""

from __future__ import annotations

import statistics
import time

from benchmarks.harness import Result
from hil_emulator.inprocess import forget_shared_emulators
from host.arm import Arm
from host.view import RobotView

HOLD = [0.0, 0.3, 0.0, 0.6, 0.0, 0.3, 0.0]


def alternate(view: RobotView, blocks: int, cycles: int, name: str
              ) -> tuple[float, float, float]:
    """(median cycles per CPU second without the view, with it; simulated s per block)."""
    arm = Arm.open(f"emu://arm/arm?name={name}")
    arm.torque(True)
    commands = arm.make_positions(HOLD)
    view.attach_arm(arm)
    tap = arm.state_taps[-1]
    for _ in range(20):  # warm up the view's first drawings and the emulator
        arm.cycle(commands)
    view.drain()
    rates: dict[bool, list[float]] = {False: [], True: []}
    sim = 0.0
    for block in range(2 * blocks):
        on = block % 2 == 1
        if on:
            arm.state_taps.append(tap)
        elif tap in arm.state_taps:
            arm.state_taps.remove(tap)
        t0, c0 = arm.transport.now(), time.process_time()
        for _ in range(cycles):
            arm.cycle(commands)
        view.drain()
        rates[on].append(cycles / (time.process_time() - c0))
        sim = arm.transport.now() - t0
    arm.close()
    view.close()
    forget_shared_emulators()
    return statistics.median(rates[False]), statistics.median(rates[True]), sim


def run(quick: bool) -> list[Result]:
    blocks, cycles = (3, 150) if quick else (7, 400)
    group = "live view"
    view = RobotView(web_port=0)
    off, on, sim = alternate(view, blocks, cycles, "bench_view")
    every = RobotView(web_port=0, max_rate_hz=1e6, queue_size=256)
    off_all, flood, _ = alternate(every, blocks, cycles, "bench_view_all")
    cost_us = 1e6 * max(0.0, 1 / on - 1 / off) * cycles / max(1.0, view.drawn / blocks)
    return [
        Result(group, "arm cycles, view off", off, "cyc",
               note=f"per CPU s (process CPU time), emu:// in process; median of {blocks} "
                    f"blocks of {cycles} cycles ({sim:.2f} simulated s each)"),
        Result(group, "arm cycles, view on (10 Hz)", on, "cyc",
               baseline="arm cycles, view off", target=0.95 * off,
               note=f"{view.drawn} states drawn, {view.dropped} dropped; about "
                    f"{cost_us:.0f} µs CPU per state drawn"),
        Result(group, "arm cycles, view on (every cycle)", flood * off / off_all, "cyc",
               baseline="arm cycles, view off",
               note=f"{every.drawn} drawn, {every.dropped} dropped by the bounded queue "
                    "(the loop never waits for the view); scaled to the first run's off"),
    ]
