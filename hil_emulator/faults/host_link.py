"""Faults of a host link (the palm's or arm's USB serial port, the loose finger's cable).

Each fault sets stages of the link's :class:`~hil_emulator.ports.link_tap.LinkTap`
(:meth:`Emulator.link_tap <hil_emulator.emulator.Emulator.link_tap>`): corruption, loss,
latency, a vanished port, a stuck transmitter, a wrong baud rate.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np

from firmware_py.scheduler import TimerHandle
from hil_emulator.faults.base import Fault
from hil_emulator.ports.host_links import PtyBacked
from hil_emulator.ports.link_tap import LinkTap, Stage

if TYPE_CHECKING:
    from hil_emulator.emulator import Emulator

Direction = Literal["down", "up", "both"]


def _install(tap: LinkTap, direction: Direction, key: int, stage: Stage) -> None:
    if direction in ("down", "both"):
        tap.down_stages[key] = stage
    if direction in ("up", "both"):
        tap.up_stages[key] = stage


def _remove(tap: LinkTap, key: int) -> None:
    tap.down_stages.pop(key, None)
    tap.up_stages.pop(key, None)


@dataclass
class LinkCorruption(Fault):
    """Each byte on host link ``link`` is replaced by a different random byte with
    ``byte_error_rate`` (in ``direction``: ``down`` host → device, ``up``, ``both``)."""

    name = "link_corruption"
    entry_point = "port"
    summary = "host serial link: bytes corrupted at a rate"
    link: str = "palm"  #: palm, arm or finger0
    byte_error_rate: float = 1e-3  #: per byte
    direction: Direction = "both"
    corrupted: int = field(default=0, init=False, repr=False)

    def __post_init__(self) -> None:
        if not 0.0 <= self.byte_error_rate <= 1.0:
            raise ValueError(f"byte_error_rate {self.byte_error_rate} is not a probability")

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        def corrupt(data: bytes) -> bytes:
            raw = np.frombuffer(data, dtype=np.uint8)
            hit = rng.random(raw.size) < self.byte_error_rate
            if not hit.any():
                return data
            self.corrupted += int(hit.sum())
            flips = rng.integers(1, 256, size=raw.size, dtype=np.uint8) * hit
            return (raw ^ flips.astype(np.uint8)).tobytes()

        _install(emulator.link_tap(self.link), self.direction, id(self), corrupt)

    def clear(self, emulator: Emulator) -> None:
        _remove(emulator.link_tap(self.link), id(self))


@dataclass
class LinkLoss(Fault):
    """Each chunk the host link ``link`` carries (what one read or one frame delivers) is
    lost with ``probability`` (in ``direction``)."""

    name = "link_loss"
    entry_point = "port"
    summary = "host serial link: chunks lost at a rate"
    link: str = "palm"  #: palm, arm or finger0
    probability: float = 0.1  #: per chunk
    direction: Direction = "both"

    def __post_init__(self) -> None:
        if not 0.0 <= self.probability <= 1.0:
            raise ValueError(f"probability {self.probability} is not in [0, 1]")

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        def lose(data: bytes) -> bytes:
            return b"" if rng.random() < self.probability else data

        _install(emulator.link_tap(self.link), self.direction, id(self), lose)

    def clear(self, emulator: Emulator) -> None:
        _remove(emulator.link_tap(self.link), id(self))


@dataclass
class LinkNoiseBurst(Fault):
    """A burst of ``length`` random bytes on host link ``link`` (both ways: the device's
    decoder and the host's both have to resynchronise)."""

    name = "link_noise_burst"
    entry_point = "port"
    summary = "host serial link: a burst of random bytes both ways"
    instantaneous = True
    link: str = "palm"  #: palm, arm or finger0
    length: int = 16  #: bytes of noise

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        noise = rng.integers(0, 256, size=self.length, dtype=np.uint8).tobytes()
        rig = emulator.rig(self.link)
        rig.send_from_host(noise)
        rig._to_host(noise, emulator.scheduler.now_us())


@dataclass
class LinkLatency(Fault):
    """Bytes toward the host on link ``link`` arrive ``latency_us`` later, plus a uniform
    jitter in [0, ``jitter_us``] (order kept): a slow USB adapter or host scheduler."""

    name = "link_latency"
    entry_point = "port"
    summary = "host serial link: added latency and jitter toward the host"
    link: str = "palm"  #: palm, arm or finger0
    latency_us: int = 2_000  #: added delay (µs)
    jitter_us: int = 0  #: up to this much more (µs), drawn per chunk

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        tap = emulator.link_tap(self.link)
        tap.latency_us = self.latency_us
        if self.jitter_us > 0:
            tap.jitter = lambda: int(rng.integers(0, self.jitter_us + 1))

    def clear(self, emulator: Emulator) -> None:
        tap = emulator.link_tap(self.link)
        tap.latency_us = 0
        tap.jitter = None


@dataclass
class PortVanish(Fault):
    """The USB serial port of link ``link`` vanishes (adapter unplugged): the pty is closed
    and its link-dir symlink removed, an in-process transport fails its sends; cleared, a new
    pty appears at the same ``--link-dir`` path."""

    name = "port_vanish"
    entry_point = "port"
    summary = "host USB serial port gone, then back at the same --link-dir path"
    link: str = "palm"  #: palm, arm or finger0

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        emulator.link_tap(self.link).vanished = True
        port = emulator.links.get(self.link)
        if isinstance(port, PtyBacked):
            port.vanish()

    def clear(self, emulator: Emulator) -> None:
        emulator.link_tap(self.link).vanished = False
        port = emulator.links.get(self.link)
        if isinstance(port, PtyBacked):
            port.reappear()


@dataclass
class SerialDriverStuck(Fault):
    """The host adapter's own transmitter on link ``link`` stuck on: the device side
    receives a continuous line condition at the link's rate — ``break`` (the line held at
    space: a NUL character with a framing error every character time) or ``noise`` (random
    characters, from the seed) — and nothing the host writes reaches the line.  The device
    cannot parse a frame of the host's meanwhile; cleared, the line idles and the link works
    again (the device's decoder resynchronises on the host's next frame).  On the arm link
    the stuck driver occupies the RS-485 line itself, so it also collides with any node
    that answers."""

    name = "serial_driver_stuck"
    entry_point = "port"
    summary = "host adapter's transmitter stuck on: break or noise at line rate, host frames lost"
    link: str = "palm"  #: palm, arm or finger0
    mode: Literal["break", "noise"] = "break"
    period_us: int = 1_000  #: the condition is fed to the device in chunks this long (µs)
    _timer: TimerHandle | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        if self.period_us <= 0:
            raise ValueError(f"period_us {self.period_us} must be positive")

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        from protocol.topology import BITS_PER_CHAR

        rig = emulator.rig(self.link)
        per_chunk = max(1, round(link_baud(emulator, self.link) / BITS_PER_CHAR
                                 * self.period_us / 1e6))

        def drive() -> None:
            if self.mode == "break":
                rig.send_from_host(bytes(per_chunk))
            else:
                rig.send_from_host(rng.integers(0, 256, size=per_chunk,
                                                dtype=np.uint8).tobytes())

        _install(emulator.link_tap(self.link), "down", id(self), lambda data: b"")
        drive()
        self._timer = emulator.scheduler.call_every(self.period_us, drive)

    def clear(self, emulator: Emulator) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        _remove(emulator.link_tap(self.link), id(self))


@dataclass
class BaudMismatch(Fault):
    """One side of host link ``link`` runs at ``baud`` (bit/s) instead of the link's rate:
    every character is sampled at the wrong instants (:func:`hil_emulator.lines.uart_sampling.misread`:
    deterministic bit-level re-sampling; characters with a framing error left out), both
    ways — the ``side`` at the wrong rate misreads what the other sends and is misread in
    turn.  Frames fail their checksum, so nothing reaches a motor; cleared, both sides agree
    again."""

    name = "baud_mismatch"
    entry_point = "port"
    summary = "host serial link: one side at a wrong baud rate, every character mis-sampled"
    link: str = "palm"  #: palm, arm or finger0
    baud: int = 1_000_000  #: the wrong side's rate (bit/s)
    side: Literal["device", "host"] = "device"
    resampled_bytes: int = field(default=0, init=False, repr=False)  #: bytes re-sampled

    def __post_init__(self) -> None:
        if self.baud <= 0:
            raise ValueError(f"baud {self.baud} must be positive")

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        from hil_emulator.lines.uart_sampling import misread

        nominal = link_baud(emulator, self.link)
        host, device = (nominal, self.baud) if self.side == "device" else (self.baud, nominal)

        def stage(sent: int, read: int) -> Stage:
            def resample(data: bytes) -> bytes:
                out = misread(data, sent, read)
                self.resampled_bytes += len(data)
                return out

            return resample

        tap = emulator.link_tap(self.link)
        tap.down_stages[id(self)] = stage(host, device)
        tap.up_stages[id(self)] = stage(device, host)

    def clear(self, emulator: Emulator) -> None:
        _remove(emulator.link_tap(self.link), id(self))


def link_baud(emulator: Emulator, link: str) -> int:
    """The baud rate (bit/s) host link ``link`` runs at (its device-side UART's)."""
    return int(emulator.rig(link).host_uart.baud)
