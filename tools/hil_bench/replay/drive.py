"""Feed an emulator a recording's host bytes at their recorded times, as fast as it goes.

Each host message goes onto its link (the rig's :meth:`send_from_host`, the way the
in-process transport sends, without ptys) at its recorded time on the simulated clock: the
emulator runs every event due up to that time first, exactly as it did while the host waited
for a reply or slept.  What the emulated robot sends back is taken with the simulated time
it arrived.  An ``emu://`` recording's times are the emulator's own clock and are kept; any
other recording's (a serial port's monotonic clock) are shifted so its first message goes
out when the emulator is ready.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Final

from hil_emulator.emulator import Emulator
from tools.hil_bench.replay.source import Timed

#: How long the emulator runs past the last host message, for the last replies (s).
TAIL_S: Final = 0.05


def answers(emulator: Emulator, sent: Mapping[str, Sequence[Timed]], *,
            shift_s: float = 0.0) -> dict[str, list[Timed]]:
    """Send each link's messages in ``sent`` (by emulator link name) at ``t + shift_s`` and
    return what each link answered, at ``t`` on the recording's clock (the shift taken off)."""
    scheduler = emulator.scheduler
    out: dict[str, list[Timed]] = {link: [] for link in sent}
    rigs = {link: emulator.rig(link) for link in sent}
    displaced = {link: rig.on_host_bytes for link, rig in rigs.items()}

    def taker(link: str) -> Callable[[bytes, int], None]:
        inbox = out[link]

        def take(data: bytes, t_us: int) -> None:
            inbox.append(Timed(t_us / 1e6 - shift_s, bytes(data)))
        return take

    for link, rig in rigs.items():
        rig.on_host_bytes = taker(link)
    try:
        merged = sorted((m.t, n, link, m.data) for link, messages in sent.items()
                        for n, m in enumerate(messages))
        last_us = scheduler.now_us()
        for t, _n, link, data in merged:
            due_us = int(round((t + shift_s) * 1e6))
            now = scheduler.now_us()
            if due_us > now:
                emulator.step(due_us - now)
            rigs[link].send_from_host(data)
            last_us = max(last_us, due_us)
        emulator.step(max(0, last_us + int(TAIL_S * 1e6) - scheduler.now_us()))
    finally:
        for link, rig in rigs.items():
            rig.on_host_bytes = displaced[link]
    return out
