"""The palm application: the hub of the hand.

The palm (address 10) talks to the host over its USB serial UART ``host`` and over CAN
(hand frames cut into CAN frames by :mod:`protocol.canlink`: requests on 0x100 + node,
replies on 0x180 + node); a reply always goes back on the link its request came from.  It
reaches each finger's fmcb over that finger's pogo UART ``finger0`` … ``finger3`` (every
fmcb is address 10; fingers are told apart by the UART only).

What it does, besides the common messages of :class:`~firmware_py.hand_node.HandNode`:

- ``palm.tactile``: 32 taxels scanned one per ms (a full scan every 32 ms), values in place;
- ``palm.state``: the 100-byte state (µs time, accel/gyro/mag, 7 temperatures, taxels),
  rebuilt every 10 ms (100 Hz);
- ``palm.route``: deliver a hand frame to a finger's fmcb (hop 0, written as is) or to its
  f2/f3 (hops 1/2, through an ``fmcb.tunnel``) and return the reply, one transaction in
  flight per finger with a short queue (:mod:`firmware_py.palm_router`);
- ``palm.finger_power``: switch one finger or all (0xFF, ``stagger_ms`` apart); the reply
  gives the states at once, and ``palm.finger_event`` (powered / unpowered) reports each
  switch as it happens;
- ``palm.poll``: poll every powered finger's ``fmcb.status`` at ``rate_hz`` (off at boot);
  a finger that answered and then misses :data:`~firmware_py.palm_router.LOST_AFTER_MISSES`
  polls in a row is reported lost (3/rate s: 30 ms at 100 Hz), and returned when it answers;
- ``palm.hand_status``: the per-finger summaries, the effort cap, the poll rate, the supply;
- ``palm.current_limit``: the :class:`~firmware_py.current_governor.CurrentGovernor` runs
  every 10 ms on the summed finger currents and sends ``fmcb.effort_cap`` to every powered
  finger when the cap changes (and to a finger that comes back with a stale cap).

Unsolicited ``palm.finger_event`` frames go to the host (address 0) on the host UART only.
"""

from __future__ import annotations

from functools import partial
from typing import Any, Final

from mypy_extensions import mypyc_attr

from firmware_py.current_governor import FULL_CAP, GOVERNOR_PERIOD_US, CurrentGovernor
from firmware_py.errors import HalError
from firmware_py.hal import CanController, Hal, Timer, Uart
from firmware_py.hand_node import DEFERRED, HandNode, Request
from firmware_py.mcu import Mcu
from firmware_py.palm_router import FingerLink, Transaction, route_transaction
from protocol.canlink import DEFAULT_PALM_NODE, CanReassembler, can_id, segment
from protocol.errors import ProtocolError
from protocol.framing import Frame, parse_frame
from protocol.messages import CATALOGUE
from protocol.messages.palm import (
    ALL_FINGERS,
    PALM_TAXELS,
    ROUTE_MAX_FRAME,
    FingerEvent,
    FingerPower,
    RouteStatus,
)
from protocol.topology import ADDR_FMCB, FINGERS, HOP_NODE

#: Taxel scan period (µs): one taxel per millisecond.
TAXEL_PERIOD_US: Final = 1_000
#: palm.state rebuild period (µs): 100 Hz.
STATE_PERIOD_US: Final = 10_000
#: Highest finger polling rate (Hz).
MAX_POLL_HZ: Final = 200
#: Longest wait for a poll's fmcb.status reply (µs); never more than 80 % of the period.
POLL_TIMEOUT_US: Final = 4_000
#: Temperature channels of the palm.
PALM_TEMPERATURES: Final = 7

_STATUS = CATALOGUE.by_name("fmcb.status")
_EFFORT_CAP = CATALOGUE.by_name("fmcb.effort_cap")
_EVENT = CATALOGUE.by_name("palm.finger_event")


def _clamp(value: int, lo: int, hi: int) -> int:
    v = int(value)
    return lo if v < lo else hi if v > hi else v


#: The taxel channels, named once (one is read every millisecond).
_TAXEL_CHANNELS: Final = tuple(f"taxel{i}" for i in range(PALM_TAXELS))


class CanLink(Uart):
    """The CAN controller seen as a reply path: a hand frame sent here goes out segmented
    on identifier 0x180 + node.  (Receiving is done by :class:`PalmApp` itself.)"""

    def __init__(self, can: CanController, node: int = DEFAULT_PALM_NODE) -> None:
        self.can = can
        self.node = node
        self.tx_id = can_id(node, to_host=True)

    def wire_time_us(self, n_bytes: int) -> int:  # pragma: no cover - never used
        raise HalError("the CAN link has no character timing; its controller paces frames")

    def send(self, data: bytes) -> None:
        for chunk in segment(data):
            self.can.send(self.tx_id, chunk)

    def set_receiver(self, callback: Any) -> None:  # pragma: no cover - never used
        raise HalError("the CAN link is read by the palm application directly")

    @property
    def tx_busy(self) -> bool:
        return False


@mypyc_attr(allow_interpreted_subclasses=True)
class PalmApp(HandNode):
    """The palm's application program (``firmware_py.palm:PalmApp``)."""

    node_kind = "palm"
    FW_VERSION = (1, 0, 0)

    def __init__(self, hal: Hal, mcu: Mcu | None = None,
                 can_node: int = DEFAULT_PALM_NODE) -> None:
        super().__init__(hal)
        self.mcu = mcu
        self.host_uart = hal.uart("host")
        self.links = [FingerLink(k, hal.uart(f"finger{k}"), hal.clock) for k in range(FINGERS)]
        for link in self.links:
            link.on_route_heard = partial(self._route_heard, link)
        for k, link in enumerate(self.links):
            link.power = hal.power(f"finger{k}").state  # a jump from the bootloader keeps power
        self.can_node = can_node
        self.can_link: CanLink | None = None
        self._can: CanController | None = None
        try:
            self._can = hal.can()
            self.can_link = CanLink(self._can, can_node)
        except HalError:
            pass
        self._can_rx = CanReassembler()
        self.governor = CurrentGovernor()
        self.taxels = [0] * PALM_TAXELS
        self._taxel_next = 0
        self.state: dict[str, Any] = {}
        self.poll_hz = 0
        self._poll_timer: Timer | None = None
        self._stagger: dict[int, Timer] = {}
        self.events_sent: list[tuple[int, int]] = []
        self.handle("palm.tactile", lambda req: {"taxels": list(self.taxels)})
        self.handle("palm.state", lambda req: self.state)
        self.handle("palm.route", self._route)
        self.handle("palm.finger_power", self._finger_power)
        self.handle("palm.hand_status", lambda req: self.hand_status())
        self.handle("palm.poll", self._poll_cmd)
        self.handle("palm.current_limit", self._current_limit)

    # --- program ---------------------------------------------------------------------------
    def start(self) -> None:
        """Listen on the host UART, the CAN bus and the finger UARTs; start the timers."""
        self.listen(self.host_uart)
        if self._can is not None:
            self._can.set_receiver(self._on_can)
        for link in self.links:
            link.start()
        clock = self.hal.clock
        self._rebuild_state()
        clock.call_every(TAXEL_PERIOD_US, self._scan_taxel)
        clock.call_every(STATE_PERIOD_US, self._rebuild_state)
        clock.call_every(GOVERNOR_PERIOD_US, self._govern)

    def _on_can(self, arbitration_id: int, data: bytes, t_us: int) -> None:
        if arbitration_id != can_id(self.can_node, to_host=False) or self.can_link is None:
            return
        try:
            frames = self._can_rx.feed(arbitration_id, data, t_us / 1e6)
        except ProtocolError:
            return
        for frame in frames:
            self.on_frame(frame, self.can_link)

    # --- own sensors -----------------------------------------------------------------------
    def _read(self, channel: str, default: int | tuple[int, ...]) -> int | tuple[int, ...]:
        try:
            return self.hal.sensors.read(channel)
        except HalError:
            return default

    def _vector(self, channel: str) -> list[int]:
        value = self._read(channel, (0, 0, 0))
        values = list(value) if isinstance(value, tuple) else [value, 0, 0]
        return [_clamp(v, -0x8000, 0x7FFF) for v in (values + [0, 0, 0])[:3]]

    def _scalar(self, channel: str, lo: int = 0, hi: int = 0xFFFF) -> int:
        value = self._read(channel, 0)
        return _clamp(value[0] if isinstance(value, tuple) else value, lo, hi)

    def _scan_taxel(self) -> None:
        i = self._taxel_next
        # self._scalar(_TAXEL_CHANNELS[i]), written out: it runs every millisecond.
        try:
            value = self.hal.sensors.read(_TAXEL_CHANNELS[i])
        except HalError:
            value = 0
        v = int(value[0] if isinstance(value, tuple) else value)
        self.taxels[i] = 0 if v < 0 else 0xFFFF if v > 0xFFFF else v
        self._taxel_next = (i + 1) % PALM_TAXELS

    def _rebuild_state(self) -> None:
        self.state = {
            "time": self.hal.clock.now_us() & 0xFFFFFFFF,
            "accel": self._vector("accel"),
            "gyro": self._vector("gyro"),
            "mag": self._vector("mag"),
            "temps": [self._scalar(f"temperature{i}") for i in range(PALM_TEMPERATURES)],
            "tactile": list(self.taxels),
        }

    # --- events ----------------------------------------------------------------------------
    def _event(self, finger: int, event: int) -> None:
        """Send an unsolicited palm.finger_event to the host on the host UART."""
        self.events_sent.append((finger, event))
        payload = _EVENT.build_reply(finger=finger, event=event,
                                     time=self.hal.clock.now_us() & 0xFFFFFFFF)
        self.send_reply(self.host_uart, _EVENT.type_id, payload)

    # --- routing ---------------------------------------------------------------------------
    def _route(self, req: Request) -> Any:
        finger, hop = req.fields["finger"], req.fields["hop"]
        timeout_ms, raw = req.fields["timeout_ms"], bytes(req.fields["frame"])

        def respond(status: int, frame: bytes = b"") -> None:
            req.respond({"finger": finger, "hop": hop, "status": status, "frame": frame})

        inner = self._valid_frame(raw)
        if finger >= FINGERS or hop not in HOP_NODE or inner is None:
            return {"finger": finger, "hop": hop, "status": RouteStatus.BAD_DESTINATION, "frame": b""}
        link = self.links[finger]
        if link.power == FingerPower.OFF:
            return {"finger": finger, "hop": hop, "status": RouteStatus.UNPOWERED, "frame": b""}
        if link.lost:
            return {"finger": finger, "hop": hop, "status": RouteStatus.LINK_DOWN, "frame": b""}
        txn = route_transaction(hop, inner, raw, timeout_ms, link.uart.baud, respond)
        if txn is None:
            return {"finger": finger, "hop": hop, "status": RouteStatus.BAD_DESTINATION, "frame": b""}
        if not link.submit(txn):
            return {"finger": finger, "hop": hop, "status": RouteStatus.BUSY, "frame": b""}
        return DEFERRED

    @staticmethod
    def _valid_frame(raw: bytes) -> Frame | None:
        """``raw`` as exactly one complete, CRC-valid hand frame, or None."""
        if len(raw) > ROUTE_MAX_FRAME:
            return None
        try:
            return parse_frame(raw)
        except ProtocolError:
            return None

    # --- finger power ----------------------------------------------------------------------
    def _finger_power(self, req: Request) -> dict[str, Any]:
        finger, state = req.fields["finger"], req.fields["state"]
        stagger_us = req.fields["stagger_ms"] * 1000
        if state <= FingerPower.FULL:
            if finger == ALL_FINGERS:
                for k in range(FINGERS):
                    self._schedule_power(k, state, k * stagger_us)
            elif finger < FINGERS:
                self._schedule_power(finger, state, 0)
        return {"states": self.power_states()}

    def _schedule_power(self, finger: int, state: int, delay_us: int) -> None:
        pending = self._stagger.pop(finger, None)
        if pending is not None:
            pending.cancel()
        if delay_us <= 0:
            self.set_finger_power(finger, state)
            return

        def fire() -> None:
            self._stagger.pop(finger, None)
            self.set_finger_power(finger, state)

        self._stagger[finger] = self.hal.clock.call_later(delay_us, fire)

    def set_finger_power(self, finger: int, state: int) -> None:
        """Switch finger ``finger`` to ``state`` (a FingerPower code) now, with events."""
        link = self.links[finger]
        old = link.power
        self.hal.power(f"finger{finger}").set(state)
        link.power = state
        if old == FingerPower.OFF and state != FingerPower.OFF:
            link.powered_up()
            self._event(finger, FingerEvent.POWERED)
        elif old != FingerPower.OFF and state == FingerPower.OFF:
            link.powered_down()
            self._event(finger, FingerEvent.UNPOWERED)

    def power_states(self) -> list[int]:
        """The power state (FingerPower code) of every finger."""
        return [link.power for link in self.links]

    # --- polling and breakaway -------------------------------------------------------------
    def _poll_cmd(self, req: Request) -> dict[str, Any]:
        self.set_poll_rate(req.fields["rate_hz"])
        return {}

    def set_poll_rate(self, rate_hz: int) -> None:
        """Poll every powered finger at ``rate_hz`` (0 stops polling; at most 200 Hz)."""
        self.poll_hz = _clamp(rate_hz, 0, MAX_POLL_HZ)
        if self._poll_timer is not None:
            self._poll_timer.cancel()
            self._poll_timer = None
        if self.poll_hz:
            self._poll_timer = self.hal.clock.call_every(1_000_000 // self.poll_hz, self._poll)

    def _poll(self) -> None:
        period_us = 1_000_000 // max(1, self.poll_hz)
        timeout_us = min(POLL_TIMEOUT_US, period_us * 4 // 5)
        request = _STATUS.request_frame(ADDR_FMCB)
        for link in self.links:
            if link.power == FingerPower.OFF or not link.idle:
                continue  # a routed transaction owns the link: skip, not a miss

            def done(frame: Frame | None, status: int, link: FingerLink = link) -> None:
                self._poll_done(link, frame, status)

            link.submit(Transaction(request, _STATUS.type_id, timeout_us, done, kind="poll"))

    def _route_heard(self, link: FingerLink, answered: bool) -> None:
        """A routed transaction's outcome, taken as a poll's: the only evidence while routes
        keep the link busy and the polls skip it.  Only while the palm polls: a finger
        marked lost refuses routes until a poll hears it again, so with polling stopped (a
        host that owns the links, as a flash run does) a timeout stays the host's to judge."""
        if not self.poll_hz:
            return
        if not answered:
            if link.missed():
                self._event(link.index, FingerEvent.LOST)
        elif link.answered():
            link.cap_sent = FULL_CAP
            self._event(link.index, FingerEvent.RETURNED)

    def _poll_done(self, link: FingerLink, frame: Frame | None, status: int) -> None:
        if frame is None:
            if status == RouteStatus.NO_REPLY and link.missed():
                self._event(link.index, FingerEvent.LOST)
            return
        try:
            fields = _STATUS.parse_reply(frame.payload)
            link.hall_pos = list(fields["hall_pos"])
            link.effort = list(fields["effort"])
        except ProtocolError:
            pass  # it answered, so it is there; its status is not usable
        if link.answered():
            link.cap_sent = FULL_CAP  # a finger that broke away may have rebooted
            self._event(link.index, FingerEvent.RETURNED)
        if link.cap_sent != self.governor.cap:
            self._send_cap(link)

    def hand_status(self) -> dict[str, Any]:
        """The palm.hand_status reply fields."""
        fingers = []
        for k, link in enumerate(self.links):
            try:
                current = self.hal.power(f"finger{k}").current_ma()
            except HalError:
                current = 0
            fingers.append({
                "present": int(link.present),
                "power": link.power,
                "current": _clamp(current, 0, 0xFFFF),
                "last_seen_ms": link.last_seen_ms(),
                "hall_pos": list(link.hall_pos),
                "effort": [_clamp(e, -0x8000, 0x7FFF) for e in link.effort],
            })
        return {
            "time": self.hal.clock.now_us() & 0xFFFFFFFF,
            "effort_cap": self.governor.cap,
            "poll_hz": self.poll_hz,
            "bus_voltage": self._scalar("supply_mv"),
            "fingers": fingers,
        }

    # --- current governor ------------------------------------------------------------------
    def _current_limit(self, req: Request) -> dict[str, Any]:
        self.governor.set_limit(req.fields["limit_ma"])
        return {}

    def total_current_ma(self) -> int:
        """Sum of the finger supply currents (mA)."""
        total = 0
        for k in range(FINGERS):
            try:
                total += max(0, self.hal.power(f"finger{k}").current_ma())
            except HalError:
                pass
        return total

    def _govern(self) -> None:
        before = self.governor.cap
        cap = self.governor.update(self.total_current_ma())
        if cap == before:
            return
        for link in self.links:
            if link.power:
                self._send_cap(link)

    def _send_cap(self, link: FingerLink) -> None:
        cap = self.governor.cap
        frame = _EFFORT_CAP.request_frame(ADDR_FMCB, cap=cap)
        link.post(frame, key=_EFFORT_CAP.type_id)
        link.cap_sent = cap


__all__ = ["PalmApp", "CanLink"]
