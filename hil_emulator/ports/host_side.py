"""What every rig shows its host: bytes toward the host, and the simulation clock."""

from __future__ import annotations

from collections.abc import Callable

from firmware_py.scheduler import Scheduler
from hil_emulator.ports.link_tap import LinkTap


class HostSide:
    """Bytes a rig sends toward the host go to ``on_host_bytes`` (bytes, arrival time in
    µs) when it is set — the emulator's ports — and otherwise collect in ``host_received``
    for :meth:`take_host_bytes` (tests, in-process use)."""

    def __init__(self, scheduler: Scheduler) -> None:
        self.scheduler = scheduler
        self.host_received: list[tuple[bytes, int]] = []
        self.on_host_bytes: Callable[[bytes, int], None] | None = None
        #: The host link's fault stages (:mod:`hil_emulator.ports.link_tap`), or None.
        self.link_tap: LinkTap | None = None

    def _to_host(self, data: bytes, t_us: int) -> None:
        if self.link_tap is not None:
            self.link_tap.up(data, t_us, self._reach_host)
        else:
            self._reach_host(data, t_us)

    def _reach_host(self, data: bytes, t_us: int) -> None:
        if self.on_host_bytes is not None:
            self.on_host_bytes(data, t_us)
        else:
            self.host_received.append((data, t_us))

    def take_host_bytes(self) -> bytes:
        """Everything sent toward the host since the last call (without ``on_host_bytes``)."""
        out = b"".join(d for d, _ in self.host_received)
        self.host_received.clear()
        return out

    def run_for(self, duration_us: int) -> None:
        """Advance simulation time (µs)."""
        self.scheduler.run_for(duration_us)
