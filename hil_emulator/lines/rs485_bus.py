"""A multidrop half-duplex RS-485 line on the simulation :class:`~firmware_py.scheduler.Scheduler`.

Every node is a :class:`~firmware_py.sim.virtual_ports.VirtualUart` handed to :meth:`Rs485Bus.attach`.
A frame a node sends occupies the line for its wire time (``bits_per_char`` x bytes / ``baud``;
twice that with the Manchester line code) and reaches every *other* node, in one
:meth:`~firmware_py.sim.virtual_ports.VirtualUart.deliver` call per frame, ``turnaround_us`` after
its last bit.  Frames that overlap in time collide: every receiver gets garbage for both.

Faults (all drawn from one seeded :class:`numpy.random.Generator`, so a run is repeatable):

* ``bit_error_rate``: each data bit of a frame flips with this probability;
* :meth:`Rs485Bus.drop`: each frame is lost with this probability;
* :meth:`Rs485Bus.set_line_cut`: nothing is delivered while the line is cut;
* ``fault_filter``: a function given what the receivers would get and returning what they
  do get (``b""``: nothing), set by the fault registry (:mod:`hil_emulator.faults`) for
  burst loss and jammed lines;
* ``line_code="manchester"``: the frame is sent as Manchester chips
  (:func:`protocol.manchester.encode_packed`), each chip flips with ``chip_error_rate``, and
  the receivers get what :func:`protocol.manchester.decode_report_packed` recovers: characters
  with an invalid chip pair or a framing error are left out (a real USART flags them) and
  counted in ``manchester_bad_characters``.  With ``chip_error_rate`` 0 nothing can
  corrupt a chip, the round trip is the identity (a property the protocol's tests check), and
  the chips are not computed: the frame's wire time is still that of its chips.

The line is one wire, so a frame's corruption is drawn once and every receiver sees the same
bytes.  ``baud`` is always the *data* bit rate; on a Manchester line the chip rate is twice it.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Final, Literal

import numpy as np
import numpy.typing as npt

from firmware_py.scheduler import Scheduler
from firmware_py.sim.virtual_ports import VirtualUart, line_delivers
from protocol import manchester
from protocol.topology import BITS_PER_CHAR, wire_time_us

__all__ = ["LineCode", "Rs485Bus", "Transmission"]

LineCode = Literal["nrz", "manchester"]

#: Transmissions kept in :attr:`Rs485Bus.log`.
LOG_LENGTH: Final = 4096
#: Default time from a frame's last bit to the receivers having it (µs).
DEFAULT_TURNAROUND_US: Final = 2


@dataclass(slots=True)
class Transmission:
    """One frame on the line: who sent it, when it occupied the line (µs), and its fate.

    ``collided`` is set when another frame overlaps it (possibly after it was logged).
    ``received`` is what the receivers got: ``None`` until delivery time, and ``b""`` when
    nothing arrived (line cut, dropped, or every Manchester character bad).
    """

    name: str
    start_us: int
    end_us: int
    data: bytes
    collided: bool = False
    received: bytes | None = None

    # Written out: the __init__ a dataclass generates stays interpreted Python in the
    # compiled core (mypyc), and the buses make one Transmission per frame.
    def __init__(self, name: str, start_us: int, end_us: int, data: bytes,
                 collided: bool = False, received: bytes | None = None) -> None:
        self.name = name
        self.start_us = start_us
        self.end_us = end_us
        self.data = data
        self.collided = collided
        self.received = received


#: Run from source (not the compiled core): a frame's :class:`Transmission` is made with
#: ``__new__`` and six stores, a third cheaper than through ``__init__`` (compiled, the
#: constructor is the cheaper).
_FROM_SOURCE: Final = __file__.endswith(".py")
_new_transmission: Final = Transmission.__new__

#: Whether a receiver acts on a frame (see :meth:`Rs485Bus.attach`).
Hears = Callable[[bytes], bool]


#: Which of a set of receivers act on a frame, in one call (see :meth:`Rs485Bus.set_audience`).
Audience = Callable[[bytes], Sequence[object]]
_NOBODY: Final[Sequence[object]] = ()


class _Node:
    __slots__ = ("by_audience", "free_us", "hears", "name", "uart")

    def __init__(self, uart: VirtualUart, name: str, hears: Hears | None) -> None:
        self.uart = uart
        self.name = name
        self.hears = hears
        #: The bus's audience says whether it acts on a frame (not ``hears``).
        self.by_audience = False
        self.free_us = 0  # when this node's transmitter is done with the line


class Rs485Bus:
    """A shared half-duplex line: frames from one node reach all the others.

    ``baud`` is the data bit rate (bit/s) that sets the wire time; ``bits_per_char`` the bits
    per UART character (start + 8 data + stop).  ``collisions`` counts frames that started
    while another was on the line (two overlapping frames count 1); ``log`` lists every
    :class:`Transmission`.
    """

    def __init__(
        self,
        scheduler: Scheduler,
        baud: int = 2_000_000,
        turnaround_us: int = DEFAULT_TURNAROUND_US,
        seed: int = 0,
        bits_per_char: int = BITS_PER_CHAR,
        line_code: LineCode = "nrz",
        bit_error_rate: float = 0.0,
        chip_error_rate: float = 0.0,
    ) -> None:
        if baud <= 0:
            raise ValueError("baud must be positive")
        if line_code not in ("nrz", "manchester"):
            raise ValueError(f"unknown line code {line_code!r}")
        self.scheduler = scheduler
        self.baud = int(baud)
        self.turnaround_us = int(turnaround_us)
        self.bits_per_char = int(bits_per_char)
        self.line_code: LineCode = line_code
        self.bit_error_rate = float(bit_error_rate)
        self.chip_error_rate = float(chip_error_rate)
        self.drop_probability = 0.0
        self.line_cut = False
        #: What the receivers get instead of a frame's bytes (None: no filter).
        self.fault_filter: Callable[[bytes], bytes] | None = None
        self.collisions = 0
        self.manchester_bad_characters = 0
        #: The most recent transmissions (at most :data:`LOG_LENGTH`).
        self.log: deque[Transmission] = deque(maxlen=LOG_LENGTH)
        self._rng = np.random.default_rng(seed)
        self._nodes: list[_Node] = []
        self._audience: Audience | None = None
        self._on_air: list[Transmission] = []  # frames not yet past their end time
        self._on_air_until = 0  # the latest end of the frames in _on_air (µs)

    # ---------------------------------------------------------------------------- set-up

    def attach(self, uart: VirtualUart, name: str, hears: Hears | None = None) -> None:
        """Put ``uart`` on the line: its output goes to the bus, and it hears the others.

        ``hears``, if given, tells from a frame's bytes whether the node behind ``uart``
        would act on it; a frame it would let pass untouched (a whole packet for another
        node, say) is then not delivered to it at all, which saves the emulator the call.
        It must answer exactly as the node would, from the node's present state.
        """
        if any(n.uart is uart for n in self._nodes):
            raise ValueError(f"UART {name!r} is already on this bus")
        node = _Node(uart, name, hears)
        self._nodes.append(node)
        uart.peer = None
        uart.sink = line_delivers  # the bus delivers the frame, not the UART
        # The bus must know a frame from its first bit to find collisions.  (partial, not
        # a lambda: no Python frame of its own per frame.)
        uart.on_transmit = partial(self._transmit, node)

    def set_audience(self, uarts: list[VirtualUart], audience: Audience) -> None:
        """Ask ``audience`` once per frame, instead of each node's ``hears``, which of the
        attached ``uarts`` (given in the order they were attached) act on it: it returns
        those of them that would, in that order (the frame's bytes as ``hears`` gets
        them), and only those get it.  It must answer exactly as the nodes' ``hears``
        would.  Detaching one of them ends it: each node's ``hears`` decides again."""
        order = [id(n.uart) for n in self._nodes]
        at = [order.index(id(uart)) if id(uart) in order else -1 for uart in uarts]
        if -1 in at:
            raise ValueError(f"UART {uarts[at.index(-1)].name!r} is not on this bus")
        if at != sorted(at):
            raise ValueError("the audience's UARTs must be given in the order attached")
        for i in at:
            self._nodes[i].by_audience = True
        self._audience = audience

    def detach(self, uart: VirtualUart) -> None:
        """Take ``uart`` off the line (a node unplugged): it neither sends nor hears from
        now on; frames it already put on the line still arrive."""
        node = next((n for n in self._nodes if n.uart is uart), None)
        if node is None:
            raise ValueError(f"UART {uart.name!r} is not on this bus")
        self._nodes.remove(node)
        if node.by_audience:
            self._audience = None
            for other in self._nodes:
                other.by_audience = False
        uart.on_transmit = None
        uart.sink = None

    @property
    def names(self) -> list[str]:
        """The attached nodes' names, in attach order."""
        return [n.name for n in self._nodes]

    # ------------------------------------------------------------------------------ faults

    def drop(self, probability: float) -> None:
        """Lose each frame (for all receivers) with ``probability`` from now on."""
        if not 0.0 <= probability <= 1.0:
            raise ValueError("probability must be in [0, 1]")
        self.drop_probability = float(probability)

    def set_line_cut(self, cut: bool) -> None:
        """Cut (True) or repair (False) the line; a cut line delivers nothing."""
        self.line_cut = bool(cut)

    # ------------------------------------------------------------------------------ timing

    def wire_time_us(self, n_bytes: int) -> int:
        """Time ``n_bytes`` occupy the line (µs, rounded up); doubled on a Manchester line."""
        return wire_time_us(n_bytes, self.baud, manchester=self.line_code == "manchester",
                            bits_per_char=self.bits_per_char)

    @property
    def busy(self) -> bool:
        """True while some frame is on the line."""
        now = self.scheduler.now_us()
        return any(t.start_us <= now < t.end_us for t in self._on_air)

    # ----------------------------------------------------------------------------- internals

    def _transmit(self, node: _Node, data: bytes, start_us: int) -> None:
        free = node.free_us
        start = start_us if start_us > free else free
        # self.wire_time_us(), one call less per frame.
        end = start + wire_time_us(len(data), self.baud,
                                   manchester=self.line_code == "manchester",
                                   bits_per_char=self.bits_per_char)
        node.free_us = end
        if type(data) is not bytes:
            data = bytes(data)
        if _FROM_SOURCE:  # Transmission(node.name, start, end, data), a third cheaper
            tx = _new_transmission(Transmission)
            tx.name = node.name
            tx.start_us = start
            tx.end_us = end
            tx.data = data
            tx.collided = False
            tx.received = None
        else:
            tx = Transmission(node.name, start, end, data)
        on_air = self._on_air
        if on_air:
            now = self.scheduler.now
            if self._on_air_until <= (start if start < now else now):
                # Every frame on the line ended before this one starts: nothing overlaps
                # (the common case, without scanning the list).
                on_air = self._on_air = []
            else:
                on_air = self._on_air = [t for t in on_air if t.end_us > now]
                overlapping = [t for t in on_air if t.start_us < end and start < t.end_us]
                if overlapping:
                    self.collisions += 1
                    tx.collided = True
                    for t in overlapping:
                        t.collided = True
        on_air.append(tx)
        if end > self._on_air_until:
            self._on_air_until = end
        self.log.append(tx)
        self.scheduler.call_at(end + self.turnaround_us, partial(self._deliver, node, tx))

    def _deliver(self, sender: _Node, tx: Transmission) -> None:
        if self.line_cut or (
            self.drop_probability > 0.0 and self._rng.random() < self.drop_probability
        ):
            tx.received = b""
            return
        if not tx.collided and self.bit_error_rate <= 0.0 and not (
            self.line_code == "manchester" and self.chip_error_rate > 0.0
        ):
            # Nothing can corrupt the frame: the receivers get the bytes sent.
            self._hand_over(sender, tx, tx.data)
            return
        data = np.frombuffer(tx.data, dtype=np.uint8)
        if tx.collided:
            # Two drivers fighting: every character is garbage (never equal to what was sent).
            data = data ^ self._rng.integers(1, 256, size=data.size, dtype=np.uint8)
        if self.bit_error_rate > 0.0:
            data = data ^ self._error_mask(data.size * 8, self.bit_error_rate)
        if self.line_code == "manchester" and self.chip_error_rate > 0.0:
            # Only chip errors can make the chips decode to anything but the bytes sent
            # (a collision's garbage is still valid Manchester): run the chips only then.
            received = self._through_manchester(data)
        else:
            received = data.tobytes()
        self._hand_over(sender, tx, received)

    def _hand_over(self, sender: _Node, tx: Transmission, received: bytes) -> None:
        """Record what arrived and give it to every node but the sender."""
        if self.fault_filter is not None and received:
            received = self.fault_filter(received)
        tx.received = received
        if not received:
            return
        audience = self._audience
        picked = audience(received) if audience is not None else _NOBODY
        # The audience's picks come in attach order: the next one is the only candidate
        # (compared by identity: a membership test would call __eq__).
        k, n_picked = 0, len(picked)
        for node in self._nodes:
            if node.by_audience:
                if k < n_picked and picked[k] is node.uart:
                    k += 1
                    if node is not sender:
                        node.uart.deliver(received)
            elif node is not sender and (node.hears is None or node.hears(received)):
                node.uart.deliver(received)

    def _error_mask(self, n_bits: int, rate: float) -> npt.NDArray[np.uint8]:
        """Packed (little bit order) mask with each of ``n_bits`` set with ``rate``."""
        flips = self._rng.random(n_bits) < rate
        return np.packbits(flips, bitorder="little")

    def _through_manchester(self, data: npt.NDArray[np.uint8]) -> bytes:
        packed = np.frombuffer(manchester.encode_packed(data), dtype=np.uint8)
        n_chips = data.size * manchester.chips_per_character()
        if self.chip_error_rate > 0.0:
            packed = packed ^ self._error_mask(n_chips, self.chip_error_rate)
        report = manchester.decode_report_packed(packed, n_chips=n_chips)
        self.manchester_bad_characters += len(report.bad_characters)
        return report.data
