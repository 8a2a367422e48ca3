"""The Dynamixel Protocol 1.0 slave runtime shared by the arm nodes (stepper joints, RX-64s).

An arm node listens on its UART ``"bus"`` (RS-485, 1 Mbaud) with a
:class:`~protocol.dynamixel.DynamixelStreamDecoder` and executes the instructions addressed to
its ID or to the broadcast ID against a control-table image (:class:`ControlTable`).  The
node's application (:class:`~firmware_py.arm_stepper.StepperNodeApp`,
:class:`~firmware_py.rx64.Rx64ServoApp`) subclasses :class:`DynamixelSlave` and fills in the
hooks (:meth:`~DynamixelSlave.power_up`, :meth:`~DynamixelSlave.before_read`,
:meth:`~DynamixelSlave.validate_write`, :meth:`~DynamixelSlave.after_write`,
:meth:`~DynamixelSlave.alarm_bits`, :meth:`~DynamixelSlave.reload_registers`,
:meth:`~DynamixelSlave.host_heard`).

Speed (the emulator runs seven nodes at 1 kHz): an application may keep the registers its
control tick reads in attributes, named in :attr:`~DynamixelSlave.CACHED_REGISTERS`; the
runtime calls :meth:`~DynamixelSlave.reload_registers` whenever the image may have changed
them - at boot (before ``power_up``), after every accepted host write (before
``after_write``) and after :meth:`~DynamixelSlave.set` of a cached register - so the
attributes always equal the image.  The image itself stays the one source of truth for the
host.

Behaviour chosen here (where the e-Manual leaves room):

* Replies wait ``2 µs × return_delay_time`` (register 5) after the instruction arrived.
  Status return level 0 answers PING only, 1 PING and READ, 2 everything; a broadcast is
  never answered.  Every status error byte carries the node's latched alarms.
* A packet with a bad checksum is dropped by the decoder: no reply (the host times out);
  the CHECKSUM error bit is therefore never sent.
* A rejected write changes nothing: RANGE (outside the table, a gap, a value outside its
  limits), INSTRUCTION (read-only register, EEPROM while ``lock`` is 1, unknown instruction,
  malformed parameters, ACTION with nothing registered) or an application's own bits
  (ANGLE_LIMIT on the RX-64).
* A new ID or baud rate takes effect just after the reply to the write has been queued.
* EEPROM (addresses 0..23) persists in flash page :data:`EEPROM_PAGE`; RAM restarts from
  its defaults at power-up and after RESET.
* RESET restores the factory EEPROM **except the ID and the baud rate** (a real RX-64 also
  resets those, to 1 and 57 600 bps, which would take the node off a shared 1 Mbaud arm bus),
  then restarts the node as from power-up (latched alarms cleared), after replying.
* BULK_READ: the node listed first answers after its return delay; the others each wait
  until the status packet of the node listed just before them has passed on the bus, or -
  if that packet is never heard - until a fallback delay: the wire time of every earlier
  reply plus :data:`BULK_SLOT_US` per earlier node.
* The node assumes its transceiver does not echo its own transmissions back to it.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable, Mapping
from typing import ClassVar, Final

from mypy_extensions import mypyc_attr

from firmware_py.flash_layout import PARAM_PAGE
from firmware_py.hal import Hal, Timer
from protocol.control_tables import RAM_START, ControlTable, Register, RegisterError
from protocol.dynamixel import (
    BROADCAST_ID,
    MAX_ID,
    DynamixelStreamDecoder,
    ErrorBit,
    Instruction,
    InstructionPacket,
    StatusPacket,
    encode_packet,
    parse_bulk_read,
    parse_read,
    parse_sync_write,
    parse_write,
)
from protocol.errors import DynamixelError

#: Flash page holding the EEPROM area of the control table (the hand's parameter page).
EEPROM_PAGE = PARAM_PAGE
#: Marker of a saved EEPROM image.
EEPROM_MAGIC = b"DXL1"
_EEPROM_HEADER = struct.Struct("<4sHB")  # magic, model number, length
#: Fallback time allowed per earlier node of a BULK_READ whose reply was not heard (µs):
#: the largest return delay (254 × 2 µs) plus margin.
BULK_SLOT_US: Final = 600
#: Retry interval when the flash is busy with another write (µs).
FLASH_RETRY_US: Final = 500
#: A partial packet older than this is dropped before new bytes are decoded (µs).  Without
#: it, a false header inside a corrupted packet (``FF FF id LEN`` with a large LEN) kept the
#: node deaf until LEN more bytes had passed: every following instruction was swallowed.
PACKET_GAP_US: Final = 10_000

# Instruction codes as plain ints for the dispatch (InstructionPacket keeps unknown codes
# as int, and an enum member read off its class costs ~0.4 µs).
# Final: compiled (mypyc), a module constant that is not Final is a dict lookup per use.
_PING: Final = int(Instruction.PING)
_READ: Final = int(Instruction.READ)
_WRITE: Final = int(Instruction.WRITE)
_REG_WRITE: Final = int(Instruction.REG_WRITE)
_ACTION: Final = int(Instruction.ACTION)
_RESET: Final = int(Instruction.RESET)
_SYNC_WRITE: Final = int(Instruction.SYNC_WRITE)
_BULK_READ: Final = int(Instruction.BULK_READ)


def baud_from_register(value: int) -> int:
    """Baud-rate register -> bits per second (``2 000 000 / (value + 1)``)."""
    return 2_000_000 // (value + 1)


# The compiled core (mypyc) lets a program written in Python subclass it, as the source does.
@mypyc_attr(allow_interpreted_subclasses=True)
class DynamixelSlave:
    """One Dynamixel 1.0 node: control table, EEPROM in flash, instruction handling.

    ``factory`` overrides table defaults in the factory EEPROM (typically ``id`` and
    ``baud_rate``); it is what a blank flash starts from and what RESET restores.
    ``start()`` is the power-up; the HAL's reset calls :meth:`reboot`.
    """

    def __init__(self, hal: Hal, table: ControlTable, factory: Mapping[str, int] | None = None,
                 uart_name: str = "bus") -> None:
        self.hal = hal
        self.table = table
        self.uart = hal.uart(uart_name)
        self.factory: dict[str, int] = dict(factory or {})
        self.image = bytearray(table.size)
        self.bus_id = 1  #: the ID the node answers to (the register, once a reply is out)
        self.replies = 0  #: status packets sent since power-up
        self._decoder = DynamixelStreamDecoder("instruction", gap_timeout=PACKET_GAP_US / 1e6)
        self._pending_write: tuple[int, bytes] | None = None
        self._save_wanted = False
        self._bulk_wait: tuple[int, Callable[[], None], Timer] | None = None

    # ------------------------------------------------------------------ life cycle

    def start(self) -> None:
        """Power-up: EEPROM from flash (factory values if none), RAM defaults, listen."""
        self._boot(self._load_eeprom() or self._factory_eeprom())

    def _boot(self, eeprom: bytes) -> None:
        self._decoder = DynamixelStreamDecoder("instruction", gap_timeout=PACKET_GAP_US / 1e6)
        self._pending_write = None
        self._bulk_wait = None
        self.image = self.table.defaults()
        self.image[:RAM_START] = eeprom
        self.reload_registers()
        self._apply_bus_settings()
        self.uart.set_receiver(self._on_bytes)
        self.power_up()

    def reboot(self) -> None:
        """A reset of the microcontroller: stop everything and start again from power-up."""
        self.hal.halt(restart_clock=True)
        self.start()

    def _factory_eeprom(self) -> bytes:
        image = self.table.defaults()
        for name, value in self.factory.items():
            self.table.set_value(image, name, value)
        return bytes(image[:RAM_START])

    def _apply_bus_settings(self) -> None:
        self.bus_id = self.get("id")
        self.uart.baud = baud_from_register(self.get("baud_rate"))

    # ------------------------------------------------------------------ hooks

    #: Registers the application keeps in attributes (see :meth:`reload_registers`).
    CACHED_REGISTERS: ClassVar[frozenset[str]] = frozenset()

    def reload_registers(self) -> None:
        """Re-read the registers named in :attr:`CACHED_REGISTERS` from the image into the
        application's attributes (called whenever the image may have changed them)."""

    def power_up(self) -> None:
        """Application start (RAM registers hold their defaults; start timers here)."""

    def before_read(self) -> None:
        """Refresh the present-value registers before a READ."""

    def validate_write(self, after: bytearray, touched: list[Register]) -> int:
        """Extra checks of a write the table accepted (``after`` is the resulting image):
        return the status error bits rejecting it, or 0 to accept it."""
        return 0

    def after_write(self, touched: list[Register]) -> None:
        """React to registers a host write changed (goal, torque enable, commands)."""

    def alarm_bits(self) -> int:
        """Latched alarm bits (ErrorBit) reported in every status packet."""
        return 0

    def sync_image(self) -> None:
        """Write into the image what the application has published but left unwritten (a
        servo's present-value registers after each tick), so that the image reads as if
        everything had been written when published.  Called before the image is read or
        written (:meth:`get`, :meth:`set`, a host write); whoever reads :attr:`image`
        directly calls it first.  Nothing is left unwritten by default."""

    def host_heard(self) -> None:
        """An instruction addressed to this node arrived (its ID or broadcast; a SYNC_WRITE
        with an entry for it, a BULK_READ naming it), before it is executed: a host is
        there (the stepper node's command watchdog)."""

    # ------------------------------------------------------------------ register access

    def get(self, name: str) -> int:
        """The value of register ``name``."""
        self.sync_image()
        return self.table.value(self.image, name)

    def set(self, name: str, value: int) -> None:
        """Store ``value`` in register ``name`` (the node's own access, no limits)."""
        self.sync_image()
        self.table.set_value(self.image, name, value)
        if name in self.CACHED_REGISTERS:
            self.reload_registers()

    def sensor(self, channel: str) -> int:
        """A scalar sensor channel's value, in its own counts."""
        value = self.hal.sensors.read(channel)
        if type(value) is int:  # the common case, without the conversions
            return value
        return int(value[0]) if isinstance(value, tuple) else int(value)

    # ------------------------------------------------------------------ EEPROM in flash

    def _load_eeprom(self) -> bytes | None:
        raw = self.hal.flash.read_page(EEPROM_PAGE)
        magic, model, length = _EEPROM_HEADER.unpack_from(raw)
        end = _EEPROM_HEADER.size + length
        if magic != EEPROM_MAGIC or model != self.table.model_number or length != RAM_START:
            return None
        (crc,) = struct.unpack_from("<I", raw, end)
        if zlib.crc32(raw[:end]) != crc:
            return None
        stored = bytearray(raw[_EEPROM_HEADER.size : end])
        defaults = self.table.defaults()
        for reg in self.table:  # read-only EEPROM (model, firmware) comes from the firmware
            if reg.area == "EEPROM" and not reg.writable:
                stored[reg.address : reg.end] = defaults[reg.address : reg.end]
        return bytes(stored)

    def save_eeprom(self) -> None:
        """Write the EEPROM area to flash (now, or as soon as the flash is free)."""
        self._save_wanted = True
        flash = self.hal.flash
        if flash.busy:
            self.hal.clock.call_later(FLASH_RETRY_US, self._retry_save)
            return
        self._save_wanted = False
        body = _EEPROM_HEADER.pack(EEPROM_MAGIC, self.table.model_number, RAM_START)
        body += bytes(self.image[:RAM_START])
        record = body + struct.pack("<I", zlib.crc32(body))
        flash.write_page(EEPROM_PAGE, record + b"\xff" * (flash.page_size - len(record)),
                         lambda ok: None)

    def _retry_save(self) -> None:
        if self._save_wanted:
            self.save_eeprom()

    # ------------------------------------------------------------------ receiving

    def acts_on(self, data: bytes) -> bool:
        """Whether bytes arriving now would make this node do anything: False exactly for a
        whole packet that :meth:`_on_bytes` lets pass untouched (for another node, nothing
        half-received, and not the status packet a BULK_READ turn waits for).  A bus model
        may leave such a packet undelivered (:meth:`hil_emulator.lines.rs485_bus.Rs485Bus.attach`).
        """
        n = len(data)
        if n >= 6 and data[3] + 4 == n and data[0] == 0xFF and data[1] == 0xFF:
            target = data[2]
            if target != self.bus_id and target != BROADCAST_ID and not self._decoder.held:
                wait = self._bulk_wait
                return (wait is not None and wait[0] == target
                        and ~sum(data[2:-1]) & 0xFF == data[-1])
        return True

    def _on_bytes(self, data: bytes, t_us: int) -> None:
        # One whole packet for another node and nothing half-received: like the real
        # firmware, look at the ID byte and let the packet pass (a BULK_READ in progress
        # only needs to know, from a packet with a good checksum, whose turn has passed).
        n = len(data)
        if (n >= 6 and data[3] + 4 == n and data[0] == 0xFF and data[1] == 0xFF
                and not self._decoder.held):
            if data[2] != self.bus_id and data[2] != BROADCAST_ID:
                if self._bulk_wait is not None and ~sum(data[2:-1]) & 0xFF == data[-1]:
                    self._bulk_heard(data[2])
                return
            # One whole packet for this node: decoded once for every node it reaches.
            whole = self._decoder.take_whole(data, t_us / 1e6)
            if whole is not None:
                self._bulk_heard(whole.id)
                self.handle(whole)
                return
        for decoded in self._decoder.feed(data, t_us / 1e6):
            packet = decoded.packet
            assert isinstance(packet, InstructionPacket)
            self._bulk_heard(packet.id)
            if packet.id == self.bus_id or packet.id == BROADCAST_ID:
                self.handle(packet)

    def handle(self, packet: InstructionPacket) -> None:
        """Execute one instruction addressed to this node (or broadcast)."""
        code, params, broadcast = int(packet.instruction), packet.params, packet.is_broadcast
        if code != _SYNC_WRITE and code != _BULK_READ:
            self.host_heard()
        try:
            if code == _PING:
                self._reply(0, b"", level=0, broadcast=broadcast)
            elif code == _READ:
                address, length = parse_read(params)
                self.before_read()
                data = self.table.read(self.image, address, length)
                self._reply(0, data, level=1, broadcast=broadcast)
            elif code == _WRITE:
                address, data = parse_write(params)
                touched = self._write(address, data)
                self._reply(0, b"", level=2, broadcast=broadcast,
                            then=lambda: self._written(touched))
            elif code == _REG_WRITE:
                address, data = parse_write(params)
                self._check_write(address, data)
                self._pending_write = (address, data)
                self.set("registered", 1)
                self._reply(0, b"", level=2, broadcast=broadcast)
            elif code == _ACTION:
                self._action(broadcast)
            elif code == _RESET:
                self._reply(0, b"", level=2, broadcast=broadcast, then=self._factory_reset)
            elif code == _SYNC_WRITE:
                address, _, entries = parse_sync_write(params)
                if self.bus_id in entries:
                    self.host_heard()
                    self._written(self._write(address, entries[self.bus_id]))
            elif code == _BULK_READ:
                self._bulk_read(parse_bulk_read(params))
            else:
                self._reply(ErrorBit.INSTRUCTION, b"", level=2, broadcast=broadcast)
        except RegisterError as exc:
            self._reply(exc.error_bit, b"", level=1 if code == _READ else 2, broadcast=broadcast)
        except _Rejected as rejected:  # its own name: compiled, one name has one type
            self._reply(rejected.bits, b"", level=2, broadcast=broadcast)
        except DynamixelError:  # malformed parameters
            self._reply(ErrorBit.INSTRUCTION, b"", level=1 if code == _READ else 2,
                        broadcast=broadcast)

    def _check_write(self, address: int, data: bytes) -> tuple[bytearray, list[Register]]:
        self.sync_image()
        trial = bytearray(self.image)
        touched = self.table.write(trial, address, data)
        if "lock" in self.table and self.get("lock"):
            if any(r.area == "EEPROM" or r.name == "lock" for r in touched):
                raise _Rejected(ErrorBit.INSTRUCTION)
        bits = self.validate_write(trial, touched)
        if bits:
            raise _Rejected(bits)
        return trial, touched

    def _write(self, address: int, data: bytes) -> list[Register]:
        """Apply a host write (all or nothing); returns the registers touched."""
        trial, touched = self._check_write(address, data)
        self.image[:] = trial
        self.reload_registers()
        if any(r.area == "EEPROM" for r in touched):
            self.save_eeprom()
        self.after_write(touched)
        return touched

    def _written(self, touched: list[Register]) -> None:
        """After the reply: a new ID or baud rate takes effect."""
        if any(r.name in ("id", "baud_rate") for r in touched):
            self._apply_bus_settings()

    def _action(self, broadcast: bool) -> None:
        pending, self._pending_write = self._pending_write, None
        if pending is None:
            self._reply(ErrorBit.INSTRUCTION, b"", level=2, broadcast=broadcast)
            return
        self.set("registered", 0)
        touched = self._write(*pending)
        self._reply(0, b"", level=2, broadcast=broadcast, then=lambda: self._written(touched))

    def _factory_reset(self) -> None:
        eeprom = bytearray(self.table.defaults())
        eeprom[:RAM_START] = self._factory_eeprom()
        for name in ("id", "baud_rate"):  # kept: see the module docstring
            self.table.set_value(eeprom, name, self.get(name))
        self.hal.halt(restart_clock=False)
        self._boot(bytes(eeprom[:RAM_START]))
        self.save_eeprom()

    # ------------------------------------------------------------------ replying

    def _reply(self, error: int, params: bytes, *, level: int, broadcast: bool,
               then: Callable[[], None] | None = None) -> None:
        """Send a status packet after the return delay if the status return level allows
        (``level``: 0 ping, 1 read, 2 anything else); ``then`` runs after it is queued."""
        if broadcast or self.get("status_return_level") < level:
            if then is not None:
                then()
            return
        status = StatusPacket(self.bus_id, (int(error) | self.alarm_bits()) & 0x7F, params)
        self._send_later(2 * self.get("return_delay_time"), status.encode(), then)

    def _send_later(self, delay_us: int, raw: bytes, then: Callable[[], None] | None) -> None:
        def send() -> None:
            self.uart.send(raw)
            self.replies += 1
            if then is not None:
                then()

        self.hal.clock.call_later(delay_us, send)

    def _bulk_read(self, entries: list[tuple[int, int, int]]) -> None:
        bus_id = self.bus_id
        # This node's (first) entry: the node answers k-th, after ``earlier`` bytes of data.
        k = earlier = 0
        for entry in entries:
            if entry[1] == bus_id:
                break
            earlier += entry[0]
            k += 1
        else:
            return
        length, _, address = entry
        self.host_heard()
        self.before_read()
        try:
            data = self.table.read(self.image, address, length)
            error = 0
        except RegisterError as exc:
            data, error = b"", int(exc.error_bit)
        if not 0 <= bus_id <= MAX_ID:
            return
        # What StatusPacket(...).encode() gives (the ID is checked above, the error masked).
        raw = encode_packet(bus_id, (error | self.alarm_bits()) & 0x7F, data)
        delay = 2 * self.get("return_delay_time")
        if k == 0:
            self._send_later(delay, raw, None)
            return

        def go() -> None:
            self._bulk_wait = None
            self._send_later(delay, raw, None)

        # Bytes of the earlier replies: 6 per status packet plus its data.
        fallback = self.uart.wire_time_us(earlier + 6 * k) + k * BULK_SLOT_US
        timer = self.hal.clock.call_later(fallback, go)
        self._bulk_wait = (entries[k - 1][1], go, timer)

    def _bulk_heard(self, id_: int) -> None:
        """A packet from ``id_`` passed on the bus: the awaited one lets our reply go."""
        wait = self._bulk_wait
        if wait is not None and wait[0] == id_:
            wait[2].cancel()
            wait[1]()


class LineAudience:
    """The nodes of one line asked together which act on a frame: :meth:`picked` gives
    the ``key`` of each node whose :meth:`DynamixelSlave.acts_on` is True, in order, in
    one call per frame instead of one per node (a bus model delivers to those only).

    ``members`` are ``(node, key)`` pairs; a node whose class replaces ``acts_on`` is asked
    through it."""

    def __init__(self, members: list[tuple[DynamixelSlave, object]]) -> None:
        self._members = members
        self._all = [key for _, key in members]
        self._own_verdict = [type(node).acts_on is not DynamixelSlave.acts_on
                             for node, _ in members]
        self._plain = not any(self._own_verdict)

    def picked(self, data: bytes) -> list[object]:
        """The keys of the nodes that act on ``data`` (what each one's ``acts_on`` says)."""
        n = len(data)
        if not (self._plain and n >= 6 and data[3] + 4 == n and data[0] == 0xFF
                and data[1] == 0xFF):
            if self._plain:  # not one whole packet: every node acts on it
                return self._all
            return [key for (node, key) in self._members if node.acts_on(data)]
        # One whole packet: acts_on's test for each node, the packet read once.
        target = data[2]
        broadcast = target == BROADCAST_ID
        good: bool | None = None  # the checksum, computed only if a BULK_READ turn asks
        out = []
        for node, key in self._members:
            if broadcast or target == node.bus_id or node._decoder.held:
                out.append(key)
                continue
            wait = node._bulk_wait
            if wait is not None and wait[0] == target:
                if good is None:
                    good = ~sum(data[2:-1]) & 0xFF == data[-1]
                if good:
                    out.append(key)
        return out


class _Rejected(Exception):
    """A write refused with these status error bits."""

    def __init__(self, bits: int) -> None:
        super().__init__(f"rejected: 0x{bits:02X}")
        self.bits = bits
