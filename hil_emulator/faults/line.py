"""Faults of the line models: the arm's RS-485 line and each finger's tendon bus.

They act through :class:`~hil_emulator.lines.rs485_bus.Rs485Bus` (its error rates, frame loss, line
cut, and its ``fault_filter`` hook on what the receivers get) and the tendon contact
(:func:`~hil_emulator.hand.rig.tendon_glitch`); ``burst_dropout`` on a tendon bus may follow
the finger's tendon load from the physics.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

import hil_emulator.faults.targets as targets
from hil_emulator.faults.base import Fault

if TYPE_CHECKING:
    from hil_emulator.emulator import Emulator

#: A finger's tendon bus name; group 1 the finger's index.
_TENDON_BUS = re.compile(r"tendon(\d)")


@dataclass
class BusBitErrors(Fault):
    """Each data bit of every frame on ``bus`` flips with probability ``rate``."""

    name = "bus_bit_errors"
    entry_point = "line model"
    summary = "bit flips on a bus (arm or tendon<k>) at a rate"
    bus: str = "arm"  #: ``arm`` or ``tendon<k>``
    rate: float = 1e-3  #: probability per data bit
    _before: float = field(default=0.0, init=False, repr=False)

    def __post_init__(self) -> None:
        if not 0.0 <= self.rate <= 1.0:
            raise ValueError(f"rate {self.rate} is not a probability")

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        line = targets.bus(emulator, self.bus)
        self._before = line.bit_error_rate
        line.bit_error_rate = self.rate

    def clear(self, emulator: Emulator) -> None:
        targets.bus(emulator, self.bus).bit_error_rate = self._before


@dataclass
class TendonChipErrors(Fault):
    """Each Manchester chip on finger ``finger``'s tendon bus flips with ``rate``; characters
    with an invalid chip pair are dropped as the USART flags them."""

    name = "tendon_chip_errors"
    entry_point = "line model"
    summary = "Manchester chip flips on a finger's tendon bus at a rate"
    finger: int = 0  #: finger module 0..3
    rate: float = 1e-3  #: probability per chip
    _before: float = field(default=0.0, init=False, repr=False)

    def __post_init__(self) -> None:
        if not 0.0 <= self.rate <= 1.0:
            raise ValueError(f"rate {self.rate} is not a probability")

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        line = targets.bus(emulator, f"tendon{self.finger}")
        self._before = line.chip_error_rate
        line.chip_error_rate = self.rate

    def clear(self, emulator: Emulator) -> None:
        targets.bus(emulator, f"tendon{self.finger}").chip_error_rate = self._before


@dataclass
class BusFrameLoss(Fault):
    """Each frame on ``bus`` is lost for every receiver with ``probability``."""

    name = "bus_frame_loss"
    entry_point = "line model"
    summary = "independent frame loss on a bus"
    bus: str = "arm"  #: ``arm`` or ``tendon<k>``
    probability: float = 0.1  #: per frame
    _before: float = field(default=0.0, init=False, repr=False)

    def __post_init__(self) -> None:
        if not 0.0 <= self.probability <= 1.0:
            raise ValueError(f"probability {self.probability} is not in [0, 1]")

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        line = targets.bus(emulator, self.bus)
        self._before = line.drop_probability
        line.drop(self.probability)

    def clear(self, emulator: Emulator) -> None:
        targets.bus(emulator, self.bus).drop(self._before)


@dataclass
class BurstDropout(Fault):
    """Frames on ``bus`` lost in bursts: a two-state Gilbert model drawn once per frame.
    In the good state a frame is lost with ``loss_good``, in the bad state with
    ``loss_bad``; the line goes bad with ``p_enter`` and good again with ``p_leave`` per
    frame (mean burst length ``1 / p_leave`` frames).

    With ``tendon_torque_nm`` (a ``tendon<k>`` bus, physics on) the steel tendons' contact
    worsens under load, as the tendons carrying the phalanges' power and data strain and
    flex: each frame's good → bad probability is ``p_enter · load / tendon_torque_nm``,
    clipped to 1, where ``load`` is the finger's most loaded tendon at that moment
    (:meth:`~hil_emulator.hand.finger_plant.FingerPlant.tendon_load_nm`: the largest motor
    torque times its gear ratio, N·m at the capstan, i.e. tension × capstan radius; the
    model has tendons as motor-to-joint couplings without a capstan radius, so the load is
    given as that torque, not in newtons).  A slack finger (motors coasting) never enters
    bursts; one driven against a stop or an object does most.  ``frames`` counts the frames
    seen, ``lost`` those lost."""

    name = "burst_dropout"
    entry_point = "line model"
    summary = "burst frame loss (two-state Gilbert model) on a bus, optionally tendon-load driven"
    bus: str = "arm"  #: ``arm`` or ``tendon<k>``
    p_enter: float = 0.05  #: per frame, good → bad
    p_leave: float = 0.3  #: per frame, bad → good
    loss_good: float = 0.0  #: loss probability in the good state
    loss_bad: float = 1.0  #: loss probability in the bad state
    #: N·m at the capstan (tension × capstan radius) at which ``p_enter`` applies in full
    #: (``tendon<k>`` buses, physics on); None: ``p_enter`` whatever the load
    tendon_torque_nm: float | None = None
    lost: int = field(default=0, init=False, repr=False)
    frames: int = field(default=0, init=False, repr=False)
    _bad: bool = field(default=False, init=False, repr=False)

    def __post_init__(self) -> None:
        for key in ("p_enter", "p_leave", "loss_good", "loss_bad"):
            if not 0.0 <= getattr(self, key) <= 1.0:
                raise ValueError(f"{key} {getattr(self, key)} is not a probability")
        if self.tendon_torque_nm is not None:
            if not self.tendon_torque_nm > 0.0:
                raise ValueError(f"tendon_torque_nm {self.tendon_torque_nm} must be positive")
            if _TENDON_BUS.fullmatch(self.bus) is None:
                raise ValueError(f"tendon_torque_nm needs a tendon<k> bus, not {self.bus!r}")

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        self._bad = False
        line = targets.bus(emulator, self.bus)
        full = self.tendon_torque_nm
        load = None
        if full is not None:
            m = _TENDON_BUS.fullmatch(self.bus)
            assert m is not None  # checked in __post_init__
            load = targets.finger_plant(emulator, int(m.group(1))).tendon_load_nm

        def gilbert(data: bytes) -> bytes:
            self.frames += 1
            if self._bad:
                self._bad = rng.random() >= self.p_leave
            else:
                p_enter = self.p_enter
                if load is not None and full is not None:
                    p_enter = min(1.0, p_enter * load() / full)
                self._bad = rng.random() < p_enter
            if rng.random() < (self.loss_bad if self._bad else self.loss_good):
                self.lost += 1
                return b""
            return data

        line.fault_filter = gilbert

    def clear(self, emulator: Emulator) -> None:
        targets.bus(emulator, self.bus).fault_filter = None


@dataclass
class LineCut(Fault):
    """The line of ``bus`` is cut: nothing is delivered until cleared."""

    name = "line_cut"
    entry_point = "line model"
    summary = "a cut bus line (arm or tendon<k>)"
    bus: str = "arm"  #: ``arm`` or ``tendon<k>``

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        targets.bus(emulator, self.bus).set_line_cut(True)

    def clear(self, emulator: Emulator) -> None:
        targets.bus(emulator, self.bus).set_line_cut(False)


@dataclass
class StuckDriver(Fault):
    """A transceiver on ``bus`` stuck transmitting: every frame reaches the receivers as
    garbage (no character equal to what was sent) until cleared."""

    name = "stuck_driver"
    entry_point = "line model"
    summary = "a bus driver stuck transmitting: every frame garbled"
    bus: str = "arm"  #: ``arm`` or ``tendon<k>``

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        def jam(data: bytes) -> bytes:
            raw = np.frombuffer(data, dtype=np.uint8)
            return (raw ^ rng.integers(1, 256, size=raw.size, dtype=np.uint8)).tobytes()

        targets.bus(emulator, self.bus).fault_filter = jam

    def clear(self, emulator: Emulator) -> None:
        targets.bus(emulator, self.bus).fault_filter = None


@dataclass
class TendonGlitch(Fault):
    """Finger ``finger``'s tendon contact opens for ``duration_us``: the bus carries nothing
    meanwhile; the phalanges ride through on their hold-up (≤ 2 ms) or brown out and reboot
    (a power glitch shorter or longer than the hold-up)."""

    name = "tendon_glitch"
    entry_point = "node power"
    summary = "tendon contact open: power glitch shorter/longer than the phalanges' hold-up"
    instantaneous = True
    finger: int = 0  #: finger module 0..3
    duration_us: int = 1_000  #: µs the contact stays open

    def __post_init__(self) -> None:
        if self.duration_us <= 0:
            raise ValueError(f"duration_us {self.duration_us} must be positive")

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        from hil_emulator.hand.rig import tendon_glitch

        tendon_glitch(targets.finger(emulator, self.finger), emulator.scheduler,
                      self.duration_us)
