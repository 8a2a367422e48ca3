"""The machine's own wake-up stalls: the baseline for the emulator's real-time lateness.

A thread that does nothing but sleep :data:`SLEEP_S` at a time, with the real-time
scheduling the emulator asks for, for ``--seconds``; it prints one JSON object: how many
wake-ups there were and how much later than asked for they came (``p99_ms``, ``max_ms``:
the time between two wake-ups beyond the sleep).  Whatever stalls it (a virtual machine's
vCPU held by its host, a kernel thread that does not yield) stalls the emulator's pacing
thread too: no user program on that machine can be on time by more than this.

    python -m benchmarks.wakeup_probe --seconds 8
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Final

from host.scheduling import priority_for

#: The probe's sleep (s): about the emulator's gap between events.
SLEEP_S: Final = 0.0002


def probe(seconds: float) -> dict[str, float | int | str]:
    """Sleep :data:`SLEEP_S` at a time for ``seconds`` (s); wake-up delays in ms.  The
    calling thread gets its own scheduling back at the end."""
    delays: list[float] = []
    with priority_for("realtime") as got:
        end = time.monotonic() + seconds
        before = time.monotonic()
        while before < end:
            time.sleep(SLEEP_S)
            now = time.monotonic()
            delays.append(max(0.0, now - before - SLEEP_S))
            before = now
    delays.sort()
    return {"count": len(delays), "p99_ms": delays[int(0.99 * (len(delays) - 1))] * 1e3,
            "max_ms": delays[-1] * 1e3, "scheduling": got.policy}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="wakeup_probe", description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=8.0, help="how long to probe (s)")
    args = parser.parse_args(argv)
    print(json.dumps(probe(args.seconds)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
