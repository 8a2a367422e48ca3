"""A link whose clock runs faster than the robot's: what a host sees of an emulator that a
busy machine slows below real time, made exact on the simulation clock for the tests."""

from __future__ import annotations

from host.transports.base import Transport


class FastLinkClock(Transport):
    """``inner`` with a clock running ``factor`` times faster than the simulation's: what a
    host sees of an emulator that keeps up with only 1/``factor`` of real time."""

    def __init__(self, inner: Transport, factor: float) -> None:
        super().__init__(inner.url)
        self.inner = inner
        self.factor = factor

    def now(self) -> float:
        return self.inner.now() * self.factor

    def _send(self, data: bytes) -> None:
        self.inner.send(data)

    def _recv(self, timeout: float | None) -> bytes:
        return self.inner.recv(None if timeout is None else timeout / self.factor)

    def _close(self) -> None:
        self.inner.close()
