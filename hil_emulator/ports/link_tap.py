"""The fault stages of one host link, both directions, and what passed them.

A :class:`LinkTap` sits on one host link (the palm's or arm's USB serial port, the loose
finger's cable): bytes from the host pass :meth:`LinkTap.down` before they enter the
simulation (in process: the :class:`~hil_emulator.inprocess.EmulatorTransport`; through a pty:
the :class:`~hil_emulator.ports.host_links.SerialLink`), bytes toward the host pass
:meth:`LinkTap.up` (the rig's ``_to_host``).  The emulator makes one tap per link on demand
(:meth:`Emulator.link_tap <hil_emulator.emulator.Emulator.link_tap>`); the link faults
(:mod:`hil_emulator.faults.host_link`) set its stages.  The tap also keeps the frames the
host sent and what the device side received when ``record`` is on, so a run can check that
nothing the host never sent was accepted.  A tap with no stages passes bytes unchanged.
"""

from __future__ import annotations

from collections.abc import Callable

from firmware_py.scheduler import Scheduler

#: One fault stage: what is left of a chunk of bytes after it (``b""``: all lost).
Stage = Callable[[bytes], bytes]


class LinkTap:
    """The fault stages of one host link, both directions, and what passed them."""

    def __init__(self, name: str, scheduler: Scheduler) -> None:
        self.name = name
        self.scheduler = scheduler
        self.down_stages: dict[int, Stage] = {}
        self.up_stages: dict[int, Stage] = {}
        #: Added delay of bytes toward the host (µs), and its jitter draw (µs).
        self.latency_us = 0
        self.jitter: Callable[[], int] | None = None
        #: True while the port is gone (a USB adapter unplugged).
        self.vanished = False
        self.record = False
        self.sent: bytearray = bytearray()  #: what the host sent (record on)
        self.received: bytearray = bytearray()  #: what entered the simulation (record on)
        self._last_up_us = 0

    def down(self, data: bytes) -> bytes:
        """Host → device: what enters the simulation of ``data`` the host wrote."""
        if self.record:
            self.sent += data
        if self.vanished:
            return b""
        for stage in list(self.down_stages.values()):
            data = stage(data)
        if self.record:
            self.received += data
        return data

    def up(self, data: bytes, t_us: int, deliver: Callable[[bytes, int], None]) -> None:
        """Device → host: ``deliver`` what reaches the host of ``data`` (complete at
        ``t_us``), later by the added latency (order kept)."""
        if self.vanished:
            return
        for stage in list(self.up_stages.values()):
            data = stage(data)
        if not data:
            return
        delay = self.latency_us + (self.jitter() if self.jitter is not None else 0)
        if delay <= 0 and self._last_up_us <= t_us:
            deliver(data, t_us)
            return
        at = max(t_us + delay, self._last_up_us)
        self._last_up_us = at
        self.scheduler.call_at(at, lambda: deliver(data, at))
