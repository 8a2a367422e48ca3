"""A Dynamixel Protocol 1.0 bus client over a :class:`~host.transports.base.Transport`.

One request at a time (the bus is half duplex): :meth:`DynamixelBus.exchange` sends one or
more instruction packets in one go and collects the status packets they call for, matched
by ID and in the order the nodes answer, each checked (checksum by the decoder; ID, length,
error byte here).  Nothing else is ever on the wire while a request waits.

Timeouts come from the wire, not a fixed guess: the time the request and every expected
reply take at the bus's bit rate (10 bits per byte: start, 8 data, stop), plus each node's
return delay (register 5, 2 µs units, remembered per ID once :meth:`set_return_delay` wrote
it; the factory 250 = 500 µs until then), plus :attr:`DynamixelBus.latency_s` for the
adapter and the operating system (a USB adapter buffers for up to a millisecond or more; the
in-process emulator has none).  Deadlines are on :meth:`Transport.now`'s clock, so on the
emulator they are simulation time.

Errors (all in :mod:`host.errors`' tree):

* :class:`~host.errors.ReplyTimeout` - a node did not answer (after ``retries`` repeats of an
  idempotent request: PING, READ, WRITE, BULK_READ);
* :class:`DynamixelNodeError` (a :class:`~host.errors.NodeError`) - a node answered but
  refused the request: the error byte holds one of :data:`REQUEST_ERRORS` (instruction,
  range, angle limit, checksum).  The other bits (input voltage, overheating, overload) are
  *alarms*: the node reports them in every status packet until the cause is cleared, so
  they are returned in the :class:`~protocol.dynamixel.StatusPacket` (``errors``), never
  raised - a host must be able to read an overheating servo;
* :class:`~host.errors.NodeError` - a reply that does not fit the request (wrong data
  length) and no fitting one by the deadline, after the retries.  A misfit is first taken
  for a late reply to an earlier request, or another program's, and skipped.

Another program on the bus (a second master on its own adapter): this client hears its
instruction packets and the nodes' replies to it, and their frames collide with its own.
What it cannot tell from its own replies it skips: another ID, another length (a reply to
the other program, or its instruction packet read as a status); a refusal (an error byte
with :data:`REQUEST_ERRORS` bits, which another program's instruction code also looks like)
is held until the deadline, in case the node's own answer follows, and only then raised.  A
garbled or lost reply is retried as any missing one (idempotent requests only; a goal's
SYNC_WRITE expects no reply and the next cycle sends the next goal); a BULK_READ's repeat
asks only the nodes whose replies are still missing (see :meth:`DynamixelBus.exchange`).  A reply to the other
program of the very length expected from that ID is taken for this one's: the same
registers a moment apart, when both read the same block.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Final

from host.errors import HostError, NodeError, ReplyTimeout, UsageError
from host.recording.prologue import Prologue
from host.transports.base import Transport, url_scheme
from protocol.dynamixel import (
    MIN_PACKET_SIZE,
    DynamixelStreamDecoder,
    ErrorBit,
    Instruction,
    InstructionPacket,
    StatusPacket,
    make_bulk_read,
    make_ping,
    make_read,
    make_sync_write,
    make_write,
    parse_bulk_read,
)

#: Bits on the wire per byte (8N1: start, 8 data, stop).
BITS_PER_BYTE: Final = 10
#: The arm bus's bit rate (bit/s).
ARM_BUS_BAUD: Final = 1_000_000
#: Return delay of a node whose register 5 this client has not written (µs): the factory
#: value 250 × 2 µs.
FACTORY_RETURN_DELAY_US: Final = 500
#: Transceiver turnaround allowed per reply (µs): line settling between two packets.
TURNAROUND_US: Final = 2
#: Within an exchange's replies, a silence this long (s) after some arrived ends them: the
#: nodes answer back to back, and the adapter passes them on within its latency.
REPLY_GAP_S: Final = 0.005
#: Another program's frames heard before a request: the line must have been this quiet (s)
#: before this client sends (a polling program's next READ follows its reply within about a
#: pty's or a USB adapter's turnaround), waiting at most :data:`LISTEN_MAX_S`.
LINE_QUIET_S: Final = 0.004
LISTEN_MAX_S: Final = 0.02
#: Repeats of an idempotent request that got no valid reply.  Another program on the bus
#: (a monitor READing the seven joints every 20 ms on its own adapter) collides with some
#: exchanges even with :data:`LINE_QUIET_S` (counted through the emulator's ptys: 27 of 200
#: BULK_READs of the cycle lost; 300 cycles needed 114 repeats); five repeats left none of
#: the 300 cycles failing, two left 3 (each repeat then asked every node again; now a
#: repeat asks only the missing and one that brings replies is not counted: see
#: :meth:`DynamixelBus.exchange`).  A node that is gone costs six deadlines.
DEFAULT_RETRIES: Final = 5
#: Writes of a setting read back and made again (:meth:`DynamixelBus.sync_write_confirmed`),
#: each repeat after a random pause of up to CONFIRM_BACKOFF_S (s): a poller on its own
#: adapter sends its next READ as soon as it has taken one of the read-back's replies for
#: its own, and a write sent at once would meet it every time.
CONFIRM_ATTEMPTS: Final = 5
CONFIRM_BACKOFF_S: Final = 0.02
#: Error bits meaning "the request was refused"; the rest are alarms (see the module docs).
REQUEST_ERRORS: Final = (ErrorBit.INSTRUCTION | ErrorBit.RANGE | ErrorBit.ANGLE_LIMIT
                         | ErrorBit.CHECKSUM)
#: Extra wait for replies by transport scheme (s): adapter and OS latency.
DEFAULT_LATENCY_S: Final = {"emu": 0.0002}
#: Extra wait for replies on any other link (s): USB adapters (a 16 ms latency timer) and
#: ptys to an emulator on a busy machine; only a missing reply waits it out.
SERIAL_LATENCY_S: Final = 0.1


def error_names(error: int) -> tuple[str, ...]:
    """Names of the :class:`~protocol.dynamixel.ErrorBit` bits set in ``error``, lowest bit
    first, e.g. ``("OVERHEATING", "OVERLOAD")``."""
    return tuple(bit.name or hex(bit.value) for bit in ErrorBit if error & bit.value)


class DynamixelNodeError(NodeError):
    """Node ``dxl_id`` refused a request: ``error`` is its status error byte (an
    :class:`~protocol.dynamixel.ErrorBit`), ``names`` the names of the bits set."""

    def __init__(self, message: str, *, dxl_id: int, error: int) -> None:
        super().__init__(message)
        self.dxl_id = dxl_id
        self.error = ErrorBit(error)
        self.names = error_names(error)


@dataclass(frozen=True)
class Expect:
    """A status packet an exchange waits for: from ``dxl_id`` with ``length`` data bytes."""

    dxl_id: int
    length: int = 0


@dataclass
class BusStats:
    """Counters of one :class:`DynamixelBus` (for logs and benchmarks)."""

    requests: int = 0
    retries: int = 0
    timeouts: int = 0
    bytes_sent: int = 0
    bytes_received: int = 0


def resend_for(packets: Sequence[InstructionPacket], ids: Collection[int]
               ) -> list[InstructionPacket]:
    """What to send again for the replies of ``ids`` still missing from the exchange of
    ``packets``: the same, but a BULK_READ last asks only the nodes in ``ids`` (the writes
    before it go again: goals, idempotent)."""
    last = packets[-1] if packets else None
    if last is None or last.instruction != Instruction.BULK_READ:
        return list(packets)
    entries = [e for e in parse_bulk_read(last.params) if e[1] in ids]
    return [*packets[:-1], make_bulk_read(entries)] if entries else list(packets)


class DynamixelBus:
    """Protocol 1.0 client of the nodes on ``transport`` at ``baud`` bit/s.

    ``retries``: repeats of an idempotent request that got no (valid) reply.  ``latency_s``:
    extra wait for replies (s; default by transport scheme: 0.2 ms in process, 100 ms on a
    serial link).  ``on_bytes(direction, data, t)``, if given, sees every chunk sent
    (``"tx"``) and received (``"rx"``) with the transport's time (s) - for recording.
    """

    def __init__(self, transport: Transport, baud: int = ARM_BUS_BAUD, *,
                 retries: int = DEFAULT_RETRIES,
                 latency_s: float | None = None) -> None:
        if baud <= 0:
            raise UsageError(f"bus baud rate {baud} must be positive")
        self.transport = transport
        self.baud = int(baud)
        self.retries = int(retries)
        if latency_s is None:
            latency_s = DEFAULT_LATENCY_S.get(url_scheme(transport.url), SERIAL_LATENCY_S)
        self.latency_s = float(latency_s)
        #: Return delay per ID (µs) as this client last set it.
        self.return_delay_us: dict[int, int] = {}
        self.stats = BusStats()
        self.on_bytes: Callable[[str, bytes, float], None] | None = None
        #: The first chunks each way since the bus opened, for a recorder attaching later.
        self.prologue = Prologue()
        self._decoder = DynamixelStreamDecoder("status")
        #: When (s, the transport's clock) what this client last sent has left the wire: a
        #: write that expects no reply returns at once, and the next request queues behind it.
        self._line_free_at = 0.0
        #: The replies still due of an exchange cut short while its nodes answered (Ctrl-C:
        #: a KeyboardInterrupt out of the wait): their deadline (s, the transport's clock)
        #: and how many; None when no exchange was cut short (see :meth:`wait_out_replies`).
        self._due: tuple[float, int] | None = None
        #: The last reply of the wrong length an exchange heard, and the length expected.
        self._misfit: tuple[StatusPacket, int] | None = None
        #: The pauses before a confirmed write's repeats (:data:`CONFIRM_BACKOFF_S`).
        self._backoff = random.Random()

    # ------------------------------------------------------------------ timing

    def wire_time(self, n_bytes: int) -> float:
        """Seconds ``n_bytes`` take on the wire at :attr:`baud`."""
        return n_bytes * BITS_PER_BYTE / self.baud

    def reply_time(self, expected: Sequence[Expect]) -> float:
        """Seconds from the end of a request to the end of its ``expected`` replies if every
        node answers as late as it may: wire time, return delays and turnarounds."""
        total = 0.0
        for e in expected:
            delay_us = self.return_delay_us.get(e.dxl_id, FACTORY_RETURN_DELAY_US)
            total += self.wire_time(MIN_PACKET_SIZE + e.length)
            total += (delay_us + TURNAROUND_US) / 1e6
        return total

    # ------------------------------------------------------------------ the one exchange

    def _emit(self, direction: str, data: bytes) -> None:
        hook = self.on_bytes
        if hook is not None:
            hook(direction, data, self.transport.now())
            self.prologue.complete = False  # what a listener takes is not kept
        elif self.prologue.complete:
            self.prologue.add(direction, self.transport.now(), data)

    def exchange(self, packets: Sequence[InstructionPacket], expected: Sequence[Expect] = (),
                 *, retries: int | None = None) -> list[StatusPacket]:
        """Send ``packets`` back to back and return the status packets ``expected``, in that
        order (each from its ID, with its data length).

        Raises :class:`ReplyTimeout` if some did not arrive by the wire's deadline (after
        ``retries`` repeats; default :attr:`retries`, 0 when nothing is expected),
        :class:`DynamixelNodeError` if one carries a :data:`REQUEST_ERRORS` bit and
        :class:`NodeError` if one has the wrong data length.

        The replies are taken as they come, each by its ID, and kept across the repeats: a
        repeat of a BULK_READ some of whose replies came asks only the nodes still missing
        (:func:`resend_for`), and a repeat that brought some does not count against
        ``retries``.  Another program polling the nodes on its own adapter takes one of these
        replies for the answer to its own READ of that node and sends its next READ at
        once, into the replies still coming: repeated whole, every repeat met the same fate
        (six of six, the host's cycle failing), repeated for the missing, each gets more.
        """
        attempts = 1 + (self.retries if retries is None else retries) if expected else 1
        self._misfit = None
        got: dict[int, StatusPacket] = {}
        sending = packets
        attempt = 0
        while True:
            if sending is not packets:
                self.stats.retries += 1
            before = len(got)
            missing = [i for i in range(len(expected)) if i not in got]
            self._send_and_collect(b"".join(p.encode() for p in sending), expected, missing,
                                   got)
            if len(got) == len(expected):
                return [got[i] for i in range(len(expected))]
            if len(got) == before:
                attempt += 1
                if attempt >= attempts:
                    break
            sending = resend_for(packets, [expected[i].dxl_id for i in range(len(expected))
                                           if i not in got])
        self.stats.timeouts += 1
        if self._misfit is not None:
            misfit, length = self._misfit
            raise NodeError(f"node {misfit.id} answered {len(misfit.params)} data bytes, "
                            f"{length} expected")
        waiting = ", ".join(str(expected[i].dxl_id) for i in range(len(expected))
                            if i not in got)
        raise ReplyTimeout(f"{self.transport.url}: no reply from node(s) {waiting} after "
                           f"{attempts} attempt(s); check power, wiring, IDs and baud "
                           f"({self.baud} bit/s), and that no other program has the port "
                           f"open (one without a lock, such as the Dynamixel SDK's "
                           f"PortHandler, takes replies meant for this one)")

    def _send_and_collect(self, raw: bytes, expected: Sequence[Expect], missing: Sequence[int],
                          got: dict[int, StatusPacket]) -> None:
        """Send ``raw`` and collect into ``got`` (index in ``expected`` -> reply) the replies
        of ``missing`` (indices) that arrive by the deadline."""
        transport = self.transport
        stale = transport.recv(0.0)  # a late reply to an earlier request: drop it
        if stale:
            self._emit("rx", stale)
            self._listen_for_quiet()
        self._decoder.reset()
        self.stats.requests += 1
        self.stats.bytes_sent += len(raw)
        self._emit("tx", raw)
        start = max(transport.now(), self._line_free_at)  # behind what is still going out
        self._line_free_at = start + self.wire_time(len(raw))
        waited = [expected[i] for i in missing]
        deadline = self._line_free_at + self.reply_time(waited) + self.latency_s
        # due until collected: an exception other than the bus's own (Ctrl-C) leaves it set
        self._due = (deadline, len(waited)) if waited else None
        transport.send(raw)
        if not waited:
            return
        try:
            self._collect(expected, missing, got, deadline, deadline - self.latency_s)
        except HostError:
            self._due = None
            raise
        self._due = None

    def _listen_for_quiet(self) -> None:
        """Bytes were on the line before a request (another program on the bus, or a late
        reply): receive and drop until it has been quiet for :data:`LINE_QUIET_S`, for at
        most :data:`LISTEN_MAX_S`, so the request does not collide with the rest of it."""
        transport = self.transport
        until = transport.now() + LISTEN_MAX_S
        while transport.now() < until:
            data = transport.recv(LINE_QUIET_S)
            if not data:
                return
            self._emit("rx", data)

    def _collect(self, expected: Sequence[Expect], missing: Sequence[int],
                 got: dict[int, StatusPacket], deadline: float, wire_end: float) -> None:
        """Collect into ``got`` the replies of ``missing`` (indices in ``expected``) arriving
        by ``deadline`` (see :meth:`exchange`), each taken by its ID, whatever the order.
        ``wire_end`` is when they are due at the latest without the adapter's latency: once
        bytes have been heard (a collision's garbage, another program's frames, some of the
        replies), :data:`REPLY_GAP_S` past it and past the last reply taken without the
        next one ends the wait early (the rest were lost: retried at once, not after the
        latency)."""
        transport = self.transport
        pending = list(missing)
        refused: StatusPacket | None = None
        heard = False
        progress = wire_end  # no reply is due later than this without the latency
        while True:
            end = min(deadline, progress + REPLY_GAP_S) if heard else deadline
            remaining = end - transport.now()
            if remaining <= 0:
                if refused is not None and any(expected[i].dxl_id == refused.id
                                               for i in pending):
                    self._check(refused)
                return
            data = transport.recv(remaining)
            if not data:
                continue
            heard = True
            self.stats.bytes_received += len(data)
            self._emit("rx", data)
            for decoded in self._decoder.feed(data):
                status = decoded.packet
                assert isinstance(status, StatusPacket)
                turn = next((i for i in pending if expected[i].dxl_id == status.id), None)
                if turn is None:
                    continue  # not a node still to answer: noise, a late reply, another's
                if len(status.params) != expected[turn].length:
                    # a late reply to an earlier request, another program's, or a wrong node
                    self._misfit = (status, expected[turn].length)
                    continue
                if status.error & REQUEST_ERRORS:
                    refused = status  # or another program's instruction: raised at the deadline
                    continue
                got[turn] = status
                pending.remove(turn)
                progress = max(progress, transport.now())
                self._due = (deadline, len(pending))
                if not pending:
                    return

    def wait_out_replies(self) -> bool:
        """Let the replies of an exchange that was cut short pass: a Ctrl-C while the
        nodes answered leaves their status packets on the half-duplex line for a few more
        wire times, and whatever is written meanwhile collides with them and is lost (a
        hold written at once did not arrive, and the nodes drove on).  Receives until the
        packets still due have arrived, or bytes came and then none for
        :data:`REPLY_GAP_S` (what the interruption took of them is lost with it), or their
        deadline has passed (the exchange's own: wire time, return delays and
        :attr:`latency_s`), and drops them.  True when they all came, or none was due."""
        due, self._due = self._due, None
        if due is None:
            return True
        deadline, left = due
        transport = self.transport
        heard = False
        while left > 0:
            remaining = deadline - transport.now()
            if remaining <= 0:
                return False
            data = transport.recv(min(remaining, REPLY_GAP_S) if heard else remaining)
            if not data:
                if heard:
                    return False
                continue
            heard = True
            self.stats.bytes_received += len(data)
            self._emit("rx", data)
            left -= sum(isinstance(d.packet, StatusPacket) for d in self._decoder.feed(data))
        return True

    def _check(self, status: StatusPacket) -> None:
        refused = status.error & REQUEST_ERRORS
        if refused:
            names = ", ".join(error_names(status.error))
            raise DynamixelNodeError(f"node {status.id} refused the request ({names})",
                                     dxl_id=status.id, error=status.error)

    # ------------------------------------------------------------------ instructions

    def ping(self, dxl_id: int, retries: int | None = None) -> StatusPacket:
        """PING ``dxl_id``; its (empty) status packet, with its alarm bits."""
        return self.exchange([make_ping(dxl_id)], [Expect(dxl_id)], retries=retries)[0]

    def scan(self, ids: Iterable[int]) -> list[int]:
        """The IDs among ``ids`` that answer a PING (one try each)."""
        found = []
        for dxl_id in ids:
            try:
                self.ping(dxl_id, retries=0)
            except ReplyTimeout:
                continue
            found.append(dxl_id)
        return found

    def read(self, dxl_id: int, address: int, length: int) -> bytes:
        """READ ``length`` bytes at ``address`` of node ``dxl_id``."""
        packet = make_read(dxl_id, address, length)
        return self.exchange([packet], [Expect(dxl_id, length)])[0].params

    def write(self, dxl_id: int, address: int, data: bytes) -> StatusPacket:
        """WRITE ``data`` at ``address`` of node ``dxl_id`` and wait for its status."""
        return self.exchange([make_write(dxl_id, address, data)], [Expect(dxl_id)])[0]

    def sync_write(self, address: int, length: int, data: Mapping[int, bytes]) -> None:
        """SYNC_WRITE ``length`` bytes at ``address`` of every node in ``data`` (no reply)."""
        self.exchange([make_sync_write(address, length, data)])

    def sync_write_confirmed(self, address: int, length: int, data: Mapping[int, bytes],
                             attempts: int = CONFIRM_ATTEMPTS) -> None:
        """SYNC_WRITE ``data`` as :meth:`sync_write`, then read it back from every node (one
        BULK_READ) and write again to those that do not hold it, up to ``attempts`` times:
        for a setting that must not be lost (a SYNC_WRITE has no reply, and another
        program's frame colliding with it loses it without a word).  Raises
        :class:`~host.errors.NodeError` naming the nodes that still do not hold it."""
        pending = dict(data)
        for attempt in range(max(attempts, 1)):
            if attempt:  # out of step with a poller that answers the read-back's replies
                self.transport.sleep(self._backoff.uniform(0.0, CONFIRM_BACKOFF_S))
            self.sync_write(address, length, pending)
            held = self.bulk_read([(length, i, address) for i in pending])
            pending = {i: v for i, v in pending.items() if held[i].params != v}
            if not pending:
                return
        raise NodeError(f"node(s) {', '.join(map(str, sorted(pending)))} did not take the "
                        f"write at address {address} after {attempts} attempts (another "
                        f"program on the bus colliding with it?)")

    def bulk_read(self, entries: Sequence[tuple[int, int, int]]) -> dict[int, StatusPacket]:
        """BULK_READ ``(length, id, address)`` entries; the status packets by ID."""
        expected = [Expect(dxl_id, length) for length, dxl_id, _ in entries]
        replies = self.exchange([make_bulk_read(entries)], expected)
        return {s.id: s for s in replies}

    def set_return_delay(self, dxl_id: int, units: int, address: int = 5) -> None:
        """Write node ``dxl_id``'s return delay (register 5, 2 µs units) and remember it
        for the timeouts.  The node answers this write after its old delay."""
        self.write(dxl_id, address, bytes([units]))
        self.return_delay_us[dxl_id] = 2 * units
