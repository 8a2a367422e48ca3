"""Backpressure on the arm port: a host blasting input as fast as a pty takes it.

``hil-emulator --config arm --no-physics`` in its own process, as users run it; this process
writes junk to the arm port for :data:`FLOOD_S` seconds (wall), far more than the 1 Mbaud
wire carries, then a valid ping to servo 1
(:func:`tests.hil_emulator.emulator_process.flood_arm_port`, the procedure
``test_a_flood_on_the_arm_port_is_an_overrun_and_the_next_ping_is_answered`` asserts on).

* **Ping after the flood**: how long the reply took (ms, wall clock; target ≤ 50 ms).
* **Resident memory growth** of the emulator over the flood (MB; target ≤ 10 MB: flat, the
  port keeps what its wire carries soon and counts the rest as overrun).
"""

from __future__ import annotations

from typing import Final

from benchmarks.harness import Result
from tests.hil_emulator.emulator_process import flood_arm_port

GROUP: Final = "arm port flood"
#: How long the flood lasts (s, wall clock; ``--quick``: :data:`QUICK_FLOOD_S`).
FLOOD_S: Final = 3.0
QUICK_FLOOD_S: Final = 1.0
#: The ping's reply must come within this after the flood (ms).
PING_TARGET_MS: Final = 50.0
#: The emulator's memory may grow by at most this over the flood (MB).
RSS_TARGET_MB: Final = 10.0
#: The ping's reply from servo 1: id 1, no error.
PONG: Final = bytes([0xFF, 0xFF, 1, 2, 0, 0xFC])


def run(quick: bool = False) -> list[Result]:
    flood = flood_arm_port(QUICK_FLOOD_S if quick else FLOOD_S)
    arm = flood.stats["ports"]["arm"]
    answered = flood.reply[:6] == PONG
    ping_ms = flood.answered_s * 1e3 if answered else float("nan")
    flood_note = (f"{flood.written / 1e6:.1f} MB written, {arm['overrun'] / 1e6:.1f} MB "
                  f"overrun, queue peak {arm['queue_peak_us'] / 1e3:.1f} ms")
    return [
        Result(GROUP, "ping answered after the flood", ping_ms, "ms", target=PING_TARGET_MS,
               at_most=True, note=("" if answered else f"no valid reply ({flood.reply!r}); ")
               + flood_note),
        Result(GROUP, "emulator memory growth", flood.rss_growth_kb / 1e3, "MB",
               target=RSS_TARGET_MB, at_most=True, note="resident (VmRSS) after − before"),
    ]
