"""The finger motor control board (fmcb) application.

Listens for hand frames on the ``pogo`` UART (palm or loose-finger link) at its identity's
address (10) and runs, all on ``hal.clock`` timers:

- a 1 kHz control tick: hall counting and velocities of the three motors, the phalange-bus
  breaker check, and the PD law of the current control mode (:mod:`firmware_py.fmcb_control`);
- the 148-byte status snapshot, refreshed every 5 ms (supply voltage, phalange-bus current
  and motor temperatures as raw ADC counts, as the original sent them:
  :mod:`protocol.sensor_counts`); the motor-module IMU sampled every
  40 ms; temperatures every 250 ms;
- the tendon-bus master: with autopoll on, every 10 ms it asks f2 (address 1) then f3
  (address 2) for their tactile sample, **both in sequence within the 10 ms cycle** (100 Hz
  each), each with a reply timeout (parameter ``tendon_timeout_us``, 2 ms); once a second
  the cycle also asks f2 for its strain gauge and f3 for its temperatures.  The bus is
  half-duplex: a request is only sent when no reply is awaited.  Replies (frames to
  address 0) are decoded with the tendon bus's own stream decoder and land in the status.
- the tunnel (0x1f): raw bytes out on the tendon bus, every byte heard during the
  request's wire time plus ``max_ms`` back to the host, or sooner: as soon as a complete
  frame to the host (a phalange's reply) has been heard; autopoll pauses meanwhile.  A tunnel
  request arriving while another is on the bus waits its turn (:data:`TUNNEL_QUEUE` deep)
  and is answered after it, in order, as the original fmcb's receive ring did.

Parameters live in flash page 1020 (:mod:`firmware_py.fmcb_params`).  Hall positions are
reported and controlled relative to the homing offsets (``fmcb.set_home``); ``hall_counts``
with ``raw=1`` gives the raw counts.  Efforts are clamped by the smallest of: the
``max_effort`` parameter, the hand-wide cap from the palm (``fmcb.effort_cap``), and in
modes 4/5 the per-joint cap of joint i applied to motor i.

Joint limits a host widens in RAM hold only while the host keeps sending requests
(:mod:`firmware_py.limit_lease`): a host killed while it pushed a finger onto its stops
leaves the limits it found, :data:`~protocol.robot.FINGER_LIMIT_LEASE_MS` later.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Final

from mypy_extensions import mypyc_attr

from firmware_py.flash_layout import PARAM_PAGE
from firmware_py.fmcb_control import (
    EFFORT_FULL,
    HallCounter,
    clamp_effort,
    clamp_joints,
    min_cap,
    pd_effort,
)
from firmware_py.fmcb_params import ParamTable
from firmware_py.hal import Hal, Timer, Uart
from firmware_py.hand_node import (
    DEFERRED,
    FRAME_GAP_US,
    HandNode,
    Request,
)
from firmware_py.limit_lease import LIMIT_NAMES, LimitLease
from protocol.catalogue import Message
from protocol.errors import ProtocolError
from protocol.framing import Frame
from protocol.messages import CATALOGUE
from protocol.messages.common import TxnStatus
from protocol.messages.fmcb import TUNNEL_MAX, ControlMode
from protocol.robot import joint_to_motor, motor_to_joint
from protocol.sensor_counts import pb_current_counts, supply_counts, temperature_counts
from protocol.stream import StreamDecoder
from protocol.topology import ADDR_HOST, NODE_ADDRESS, NodeKind, wire_time_us

CONTROL_PERIOD_US: Final = 1_000
STATUS_PERIOD_US: Final = 5_000
IMU_PERIOD_US: Final = 40_000
TEMPERATURE_PERIOD_US: Final = 250_000
AUTOPOLL_PERIOD_US: Final = 10_000
#: Autopoll cycles between two slow polls (f2 strain, f3 temperatures): once a second.
SLOW_POLL_CYCLES: Final = 100
#: Control ticks over which velocities are measured (10 ms).
VELOCITY_WINDOW: Final = 10
#: Tick counts kept for the velocity window (a full history).
_HISTORY_FULL: Final = VELOCITY_WINDOW + 1
#: Velocity span (s) over a history of n tick counts, by n (n - 1 control periods).
_VELOCITY_SPAN_S: Final = tuple((n - 1) * CONTROL_PERIOD_US / 1e6
                                for n in range(VELOCITY_WINDOW + 2))
#: Tunnel requests (0x1f) the fmcb holds while one is on the tendon bus: each is answered in
#: turn, as the original's receive ring did; one more than this is refused (BUSY, which an
#: un-enveloped request never hears: the original dropped a ring overflow silently too).
TUNNEL_QUEUE: Final = 4
#: pb_current while the breaker is tripped.
PB_TRIPPED: Final = 0xFFFF
#: How often (µs) a lease of widened joint limits is checked while one runs.
LEASE_CHECK_US: Final = 50_000
#: Requests the palm sends by itself (polls, effort caps): they do not renew a lease.
_FROM_PALM: Final = frozenset(CATALOGUE.by_name(n).type_id
                              for n in ("fmcb.status", "fmcb.effort_cap"))
#: The modes whose motor targets come from joint targets, clamped to the joint limits.
_JOINT_MODES: Final = frozenset((ControlMode.JOINT, ControlMode.JOINT_FIXED,
                                 ControlMode.JOINT_EFFORT, ControlMode.RELATIVE))

#: Internal mode after the legacy open-loop command (0x13): the control law stays out
#: (not a ControlMode: no control message selects it).
MODE_OPEN_LOOP: Final = -1
# The idle mode for the 1 kHz tick (an enum member read off its class costs ~0.4 µs).
_IDLE: Final = ControlMode.IDLE

_FAST_POLLS: Final = ("f2.tactile", "f3.tactile")
_SLOW_POLLS: Final = ("f2.strain", "f3.temperatures")
#: The autopoll request frames (empty payloads), built once.
_POLL_FRAMES: Final = {
    name: CATALOGUE[name].request_frame(NODE_ADDRESS[NodeKind(CATALOGUE[name].node)])
    for name in (*_FAST_POLLS, *_SLOW_POLLS)
}
#: Status keys a tactile reply lands in, by phalange prefix: taxels, IMU, time.
_TACTILE_KEYS: Final = {p: (f"{p}_tactile", f"{p}_imu", f"{p}_time") for p in ("pp", "dp")}


def _clamp(v: int, lo: int, hi: int) -> int:
    return lo if v < lo else hi if v > hi else v


def _u16(v: int) -> int:
    return _clamp(int(v), 0, 0xFFFF)


def _i16(v: int) -> int:
    return _clamp(int(v), -0x8000, 0x7FFF)


def _i32(v: int) -> int:
    return _clamp(int(v), -0x80000000, 0x7FFFFFFF)


def _clamped(values: Iterable[int], lo: int, hi: int) -> list[int]:
    """``[_clamp(int(v), lo, hi) for v in values]`` without a call per value."""
    return [lo if v < lo else hi if v > hi else v for v in map(int, values)]


@dataclass
class TendonCounters:
    """Tendon-bus master statistics (counts)."""

    requests: int = 0
    replies: int = 0
    timeouts: int = 0
    bad_replies: int = 0
    stray_frames: int = 0
    overruns: int = 0
    tunnels: int = 0


@dataclass
class _Pending:
    """A phalange request on the tendon bus awaiting its reply."""

    message: Message
    timer: Timer

    # Written out: a dataclass's generated __init__ stays interpreted in the compiled core.
    def __init__(self, message: Message, timer: Timer) -> None:
        self.message = message
        self.timer = timer


# The compiled core (mypyc) lets a program written in Python subclass it, as the source does.
@mypyc_attr(allow_interpreted_subclasses=True)
class FmcbApp(HandNode):
    """The fmcb application on ``hal``; ``mcu`` is the node running it (may be None)."""

    node_kind = "fmcb"
    FW_VERSION = (1, 0, 0)

    def __init__(self, hal: Hal, mcu: Any = None) -> None:
        super().__init__(hal)
        self.mcu = mcu
        self.params = ParamTable()
        # Indices of the parameters the 1 kHz tick reads (the table's layout is fixed).
        index = self.params.index
        self._p_kp, self._p_kd, self._p_deadband = index("kp"), index("kd"), index("deadband")
        self._p_max_effort = index("max_effort")
        self._p_breaker_ma, self._p_breaker_ms = index("breaker_ma"), index("breaker_ms")
        self._p_tendon_timeout = index("tendon_timeout_us")  # read by every poll
        self.params_valid = self.params.load_page(hal.flash.read_page(PARAM_PAGE))
        self._p_limits = tuple(index(n) for n in LIMIT_NAMES)
        #: Widened joint limits on lease while the host is there (:mod:`.limit_lease`).
        self.limit_lease = LimitLease()
        self._lease_timer: Timer | None = None
        self.pogo = hal.uart("pogo")
        self.tendon = hal.uart("tendon")
        self.phalange = hal.power("phalange")
        self.motors = [hal.motor(i) for i in range(3)]
        # Motion state.
        self.hall = [HallCounter() for _ in range(3)]
        self.offsets = [0, 0, 0]
        self.velocity = [0.0, 0.0, 0.0]
        self._history: deque[tuple[int, int, int]] = deque(maxlen=_HISTORY_FULL)
        self.mode: int = ControlMode.IDLE  # a ControlMode, or MODE_OPEN_LOOP
        self.hall_target = [0, 0, 0]
        self.joint_caps = [EFFORT_FULL] * 3
        self.effort_cap = EFFORT_FULL
        self.effort = [0, 0, 0]
        # Sensors.
        self.imu = [0] * 6
        self.temperatures = [0, 0, 0]
        self.voltage = 0
        # Phalange bus.
        self.breaker_tripped = False
        self._over_since: int | None = None
        self._pb_current = 0
        self.autopoll = False
        self.tendon_counters = TendonCounters()
        self._tendon_decoder = StreamDecoder(gap_s=FRAME_GAP_US / 1e6)
        self._pending: _Pending | None = None
        self._queue: list[str] = []
        self._cycles = 0
        #: Tunnel requests waiting or in progress (the head is on the bus while
        #: ``_tunnel_heard`` is not None): request, bytes to send, listening time (ms).
        self._tunnels: deque[tuple[Request, bytes, int]] = deque()
        self._tunnel_timer: Timer | None = None
        self._tunnel_heard: bytearray | None = None
        self.phalanges: dict[str, Any] = {
            "pp_time": 0, "dp_time": 0, "pp_tactile": [0] * 6, "dp_tactile": [0] * 12,
            "pp_imu": [0] * 6, "dp_imu": [0] * 6, "pp_temp": [0] * 4, "dp_temp": [0] * 4,
            "pp_strain": 0,
        }
        #: What the last status refresh read (see :meth:`_refresh_status`), the fields built.
        self._snapshot_taken: tuple[Any, ...] | None = None
        self._snapshot: dict[str, Any] | None = None
        self._timers: list[Timer] = []
        #: The control law sleeps (see :meth:`_control_tick`) only on a board whose hall
        #: inputs and phalange-bus current sense interrupt on a change.
        self._can_sleep = False
        #: True while the control tick has nothing to do: it returns at once until a hall
        #: change, a current change or a frame for this node wakes it.
        self.asleep = False
        self._register()

    # --- lifecycle ------------------------------------------------------------------------
    def _register(self) -> None:
        for name, handler in (
            ("fmcb.imu", lambda r: {"accel": self.imu[:3], "mag": self.imu[3:]}),
            ("fmcb.halls", lambda r: {"bits": [m.hall_state() & 7 for m in self.motors]}),
            ("fmcb.motor_raw", self._on_motor_raw),
            ("fmcb.hall_counts", self._on_hall_counts),
            ("fmcb.param_count", lambda r: {"count": len(self.params)}),
            ("fmcb.param_name", lambda r: {"name": self.params.name(r.fields["index"])}),
            ("fmcb.param_get", lambda r: {"value": self.params.get_bits(r.fields["index"])}),
            ("fmcb.param_set", self._on_param_set),
            ("fmcb.param_commit", self._on_param_commit),
            ("fmcb.param_reload", self._on_param_reload),
            ("fmcb.param_defaults", self._on_param_defaults),
            ("fmcb.control", self._on_control),
            ("fmcb.phalange_power", self._on_phalange_power),
            ("fmcb.tunnel", self._on_tunnel),
            ("fmcb.autopoll", self._on_autopoll),
            ("fmcb.status", lambda r: self.snapshot),
            ("fmcb.temperatures", lambda r: {"temp": list(self.temperatures)}),
            ("fmcb.effort_cap", self._on_effort_cap),
            ("fmcb.set_home", self._on_set_home),
        ):
            self.handle(name, handler)

    def start(self) -> None:
        """Begin: listen on pogo, master the tendon bus, start the timers."""
        self.listen(self.pogo)
        self.tendon.set_receiver(self._on_tendon_bytes)
        wake = self._wake
        interrupts = [m.set_hall_interrupt(wake) for m in self.motors]
        interrupts.append(self.phalange.set_current_interrupt(wake))
        self._can_sleep = all(interrupts)
        for m in self.motors:
            m.set_duty(0.0)
            m.set_enabled(False)
            m.set_brake(False)
        self._control_tick()
        self._sample_imu()
        self._sample_temperatures()
        self._refresh_status()
        clock = self.hal.clock
        self._timers = [
            clock.call_every(CONTROL_PERIOD_US, self._control_tick),
            clock.call_every(STATUS_PERIOD_US, self._refresh_status),
            clock.call_every(IMU_PERIOD_US, self._sample_imu),
            clock.call_every(TEMPERATURE_PERIOD_US, self._sample_temperatures),
            clock.call_every(AUTOPOLL_PERIOD_US, self._autopoll_cycle),
        ]

    # --- sensors and status ---------------------------------------------------------------
    def _read(self, channel: str, default: int | tuple[int, ...]) -> int | tuple[int, ...]:
        try:
            return self.hal.sensors.read(channel)
        except LookupError:
            return default

    def _sample_imu(self) -> None:
        accel = self._read("accel", (0, 0, 0))
        mag = self._read("mag", (0, 0, 0))
        if isinstance(accel, tuple) and isinstance(mag, tuple):
            self.imu = [_i16(v) for v in (*accel[:3], *mag[:3])]

    def _sample_temperatures(self) -> None:
        temps = []
        for i in range(3):
            v = self._read(f"temperature{i}", 0)  # 0.1 °C; the ADC reading goes out
            temps.append(temperature_counts(v / 10) if isinstance(v, int) else 0)
        self.temperatures = temps

    @property
    def hall_pos(self) -> list[int]:
        """Motor positions relative to the homing offsets (hall counts)."""
        # Indexed, not zip(strict=True), which compiled (mypyc) is a generic Python call;
        # the status refresh takes it 200 times a second.
        hall, offsets = self.hall, self.offsets
        if len(offsets) != len(hall):
            raise ValueError(f"{len(offsets)} homing offsets for {len(hall)} motors")
        return [hall[i].count - offsets[i] for i in range(len(hall))]

    @property
    def pb_current(self) -> int:
        """Phalange-bus current as reported: its ADC reading (counts, as the original fmcb
        sent it); 0xFFFF while the breaker is tripped."""
        return PB_TRIPPED if self.breaker_tripped else pb_current_counts(self._pb_current / 1000)

    def _refresh_status(self) -> None:
        """Take the status snapshot (every :data:`STATUS_PERIOD_US`).

        What it reads is kept as it is now (the lists it names are replaced, never changed
        in place, except the effort, which is copied) and :attr:`snapshot` builds the reply
        fields from it when asked: the palm asks far less often than every 5 ms."""
        supply = self._read("supply_mv", 0)  # mV; the ADC reading (counts) goes out
        self.voltage = supply_counts(supply / 1000) if isinstance(supply, int) else 0
        ph = self.phalanges
        self._snapshot_taken = (
            ph["pp_time"], ph["dp_time"], self.hal.clock.now_us() & 0xFFFFFFFF,
            ph["pp_tactile"], ph["dp_tactile"], ph["pp_imu"], ph["dp_imu"], self.imu,
            ph["pp_temp"], ph["dp_temp"], self.temperatures, self.voltage, self.pb_current,
            ph["pp_strain"], self.hall_target, self.hall_pos, tuple(self.effort))
        self._snapshot = None

    @property
    def snapshot(self) -> dict[str, Any]:
        """The ``fmcb.status`` reply fields as of the last refresh (empty before the first)."""
        if self._snapshot is None:
            taken = self._snapshot_taken
            if taken is None:
                return {}
            (pp_time, dp_time, fmcb_time, pp_tactile, dp_tactile, pp_imu, dp_imu, imu,
             pp_temp, dp_temp, temps, voltage, pb_current, pp_strain, hall_target, hall_pos,
             effort) = taken
            self._snapshot = {
                "pp_time": pp_time, "dp_time": dp_time, "fmcb_time": fmcb_time,
                "pp_tactile": list(pp_tactile), "dp_tactile": list(dp_tactile),
                "pp_imu": list(pp_imu), "dp_imu": list(dp_imu), "fmcb_imu": list(imu),
                "pp_temp": list(pp_temp), "dp_temp": list(dp_temp), "fmcb_temp": list(temps),
                "voltage": voltage, "pb_current": pb_current, "pp_strain": pp_strain,
                "hall_tgt": _clamped(hall_target, -0x80000000, 0x7FFFFFFF),
                "hall_pos": _clamped(hall_pos, -0x80000000, 0x7FFFFFFF),
                "effort": _clamped(effort, -0x8000, 0x7FFF),
            }
        return self._snapshot

    # --- control --------------------------------------------------------------------------
    def _wake(self) -> None:
        """A hall or current interrupt, or a frame for this node: the next tick runs."""
        self.asleep = False

    def dispatch(self, msg_type: int, payload: bytes, frame: Frame, uart: Uart,
                 send: Callable[[bytes | None, int], None]) -> None:
        """Any command may change what the control tick reads: wake it, then dispatch.
        A request from the host renews a lease of widened joint limits."""
        self.asleep = False
        if msg_type not in _FROM_PALM:
            self.limit_lease.heard(self.hal.clock.now_us())
        super().dispatch(msg_type, payload, frame, uart, send)

    def _control_tick(self) -> None:
        """The 1 kHz tick: halls, velocities, breaker, control law.

        It goes to sleep (returns at once from the next tick on) when a tick would change
        nothing: every hall state valid and counted, the velocity window full of the same
        counts (velocities 0), the breaker not timing an overcurrent; then the next ticks
        would read the same inputs and write the same outputs, until a hall edge, a change
        of the phalange-bus current or a command, each of which wakes it.  The tick timer
        keeps its phase meanwhile, so a woken tick runs exactly when it would have.
        """
        if self.asleep:
            return
        h, m = self.hall, self.motors
        c0, c1, c2 = (h[0].update(m[0].hall_state()), h[1].update(m[1].hall_state()),
                      h[2].update(m[2].hall_state()))
        hist = self._history
        hist.append((c0, c1, c2))
        n = len(hist)
        if n > 1:
            span_s = _VELOCITY_SPAN_S[n]
            f0, f1, f2 = hist[0]
            self.velocity = [(c0 - f0) / span_s, (c1 - f1) / span_s, (c2 - f2) / span_s]
        self._check_breaker()
        if (self._can_sleep and n == _HISTORY_FULL and hist.count(hist[-1]) == _HISTORY_FULL
                and self._over_since is None and h[0].holds() and h[1].holds()
                and h[2].holds()):
            # This tick's outputs (below) are computed from settled inputs: the same ones
            # would follow every tick, so sleep after it.
            self.asleep = True
        mode = self.mode
        if mode == _IDLE:
            self.hall_target = self.hall_pos  # targets follow the pose: no jump on resume
            return
        if mode == MODE_OPEN_LOOP:
            return
        values = self.params.values
        kp, kd = float(values[self._p_kp]), float(values[self._p_kd])
        deadband = float(values[self._p_deadband])
        # min_cap(max_effort, effort_cap, joint cap): the joint-independent part once.
        cap_all = min(EFFORT_FULL, int(values[self._p_max_effort]), self.effort_cap)
        o = self.offsets
        pos = (c0 - o[0], c1 - o[1], c2 - o[2])
        target, velocity, joint_caps, effort = (self.hall_target, self.velocity,
                                                self.joint_caps, self.effort)
        for i, motor in enumerate(m):
            cap = joint_caps[i]  # min_cap(...) = max(0, min(cap_all, joint cap))
            if cap_all < cap:
                cap = cap_all
            if cap < 0:
                cap = 0
            e = pd_effort(target[i] - pos[i], velocity[i], kp, kd, deadband, cap)
            effort[i] = e
            motor.set_enabled(True)
            motor.set_duty(e / EFFORT_FULL)

    def _set_idle(self) -> None:
        self.mode = ControlMode.IDLE
        self.effort = [0, 0, 0]
        for m in self.motors:
            m.set_duty(0.0)
            m.set_enabled(False)
        self.hall_target = self.hall_pos

    def _joint_limits(self) -> tuple[list[float], list[float]]:
        p = self.params
        lower = [float(p[f"joint_lower_{j}"]) for j in range(3)]
        upper = [float(p[f"joint_upper_{j}"]) for j in range(3)]
        return lower, upper

    def _set_joint_target(self, q: list[float]) -> bool:
        if not all(math.isfinite(v) for v in q):
            return False
        lower, upper = self._joint_limits()
        m = joint_to_motor(clamp_joints(q, lower, upper))
        self.hall_target = [_i32(round(v)) for v in m]
        return True

    def _on_control(self, req: Request) -> None:
        mode = req.fields["mode"]
        args = req.fields["args"]
        if mode == ControlMode.IDLE:
            self._set_idle()
            self.joint_caps = [EFFORT_FULL] * 3
            return None
        caps = [EFFORT_FULL] * 3
        if mode == ControlMode.MOTOR:
            self.hall_target = [int(v) for v in args["hall_target"]]
        elif mode in (ControlMode.JOINT, ControlMode.JOINT_FIXED, ControlMode.JOINT_EFFORT,
                      ControlMode.RELATIVE):
            scale = 1e-4 if mode == ControlMode.JOINT_FIXED else 1.0
            q = [float(v) * scale for v in args["target"]]
            if mode == ControlMode.RELATIVE:
                base = motor_to_joint(self.hall_target)
                q = [b + d for b, d in zip(base, q, strict=True)]
            if not self._set_joint_target(q):
                return None  # non-finite target: ignored, no motor change
            if mode in (ControlMode.JOINT_EFFORT, ControlMode.RELATIVE):
                caps = [int(v) for v in args["max_effort"]]
        else:  # pragma: no cover - the catalogue rejects other modes
            return None
        self.joint_caps = caps
        self.mode = mode
        return None

    def _on_effort_cap(self, req: Request) -> None:
        self.effort_cap = int(req.fields["cap"])
        return None

    def _on_motor_raw(self, req: Request) -> dict[str, Any]:
        f = req.fields
        self.mode = MODE_OPEN_LOOP
        cap = min_cap(int(self.params["max_effort"]), self.effort_cap)
        for i, motor in enumerate(self.motors):
            enabled = bool(f["enable"] >> i & 1)
            sign = -1 if f["direction"] >> i & 1 else 1
            e = clamp_effort(sign * f["duty"][i], cap) if enabled else 0
            self.effort[i] = e
            motor.set_enabled(enabled)
            motor.set_brake(bool(f["brake"] >> i & 1))
            motor.set_duty(e / EFFORT_FULL)
        return {"counts": [_i32(h.count) for h in self.hall]}

    def _on_hall_counts(self, req: Request) -> dict[str, Any]:
        counts = [h.count for h in self.hall] if req.fields["raw"] else self.hall_pos
        return {"counts": [_i32(v) for v in counts],
                "velocity": [_i32(round(v)) for v in self.velocity]}

    def _on_set_home(self, req: Request) -> dict[str, Any]:
        self.offsets = [int(v) for v in req.fields["offset"]]
        self.hall_target = self.hall_pos  # hold the pose under the new zero
        # A status asked for next reports positions under the new zero, not the snapshot
        # of before (a resting fmcb may not take another for a while).
        self._refresh_status()
        return {}

    # --- parameters -----------------------------------------------------------------------
    def _limits(self) -> tuple[float, ...]:
        values = self.params.values
        return tuple(float(values[i]) for i in self._p_limits)

    def _on_param_set(self, req: Request) -> dict[str, Any]:
        index = req.fields["index"]
        before = self._limits()
        self.params.set_bits(index, req.fields["value"])
        if index in self._p_limits:
            self.limit_lease.written(before, self._limits(), self.hal.clock.now_us())
            if self.limit_lease.active and self._lease_timer is None:
                self._lease_timer = self.hal.clock.call_every(LEASE_CHECK_US,
                                                              self._check_lease)
        return {}

    def _check_lease(self) -> None:
        """While widened limits are on lease: put the standing ones back when it ran out,
        and bring a joint target outside them back inside."""
        standing = self.limit_lease.check(self.hal.clock.now_us())
        if standing is not None:
            for i, value in zip(self._p_limits, standing, strict=True):
                self.params.values[i] = value
            if self.mode in _JOINT_MODES:
                self._set_joint_target(list(motor_to_joint(self.hall_target)))
                self.asleep = False
        if not self.limit_lease.active and self._lease_timer is not None:
            self._lease_timer.cancel()
            self._lease_timer = None

    def _on_param_commit(self, req: Request) -> Any:
        flash = self.hal.flash
        if flash.busy:
            req.respond(None, TxnStatus.BUSY)
            return DEFERRED

        def done(ok: bool) -> None:
            if ok:
                req.respond({})
            else:
                req.respond(None, TxnStatus.REFUSED)

        self.limit_lease.end()  # the host keeps what it commits
        flash.write_page(PARAM_PAGE, self.params.to_page(), done)
        return DEFERRED

    def _on_param_reload(self, req: Request) -> dict[str, Any]:
        self.params_valid = self.params.load_page(self.hal.flash.read_page(PARAM_PAGE))
        self.limit_lease.end()
        return {}

    def _on_param_defaults(self, req: Request) -> dict[str, Any]:
        self.params.restore_defaults()
        self.limit_lease.end()
        return {}

    # --- phalange power and breaker -------------------------------------------------------
    def _on_phalange_power(self, req: Request) -> dict[str, Any]:
        if req.fields["on"] & 1:
            self.breaker_tripped = False
            self._over_since = None
            self.phalange.set(2)
        else:
            self.phalange.set(0)
            self._abort_polls()
        return {}

    def _check_breaker(self) -> None:
        if not self.phalange.state:
            self._pb_current = 0
            self._over_since = None
            return
        ma = self.phalange.current_ma()
        self._pb_current = ma
        values = self.params.values
        if ma <= int(values[self._p_breaker_ma]):
            self._over_since = None
            return
        now = self.hal.clock.now_us()
        if self._over_since is None:
            self._over_since = now
        elif now - self._over_since > int(values[self._p_breaker_ms]) * 1000:
            self.breaker_tripped = True
            self._over_since = None
            self.phalange.set(0)
            self._abort_polls()

    # --- tendon bus master ----------------------------------------------------------------
    def _on_autopoll(self, req: Request) -> dict[str, Any]:
        self.autopoll = bool(req.fields["on"] & 1)
        if not self.autopoll:
            self._queue.clear()
        return {}

    def _autopoll_cycle(self) -> None:
        """Every 10 ms: queue this cycle's phalange requests and start the first."""
        self._cycles += 1
        if not self.autopoll or not self.phalange.state or self._tunnels:
            return
        if self._pending is not None or self._queue:
            self.tendon_counters.overruns += 1
            return
        self._queue = list(_FAST_POLLS)
        if self._cycles % SLOW_POLL_CYCLES == 0:
            self._queue += _SLOW_POLLS
        self._next_on_bus()

    def _abort_polls(self) -> None:
        self._queue.clear()
        if self._pending is not None:
            self._pending.timer.cancel()
            self._pending = None
            self._next_on_bus()

    def _next_on_bus(self) -> None:
        """The bus is free: start the waiting tunnel, else the next queued request."""
        if self._pending is not None or self._tunnel_heard is not None:
            return
        if self._tunnels:
            self._start_tunnel()
            return
        if self._queue:
            self._send_request(CATALOGUE[self._queue.pop(0)])

    def _send_request(self, msg: Message) -> None:
        data = _POLL_FRAMES.get(msg.name)
        if data is None:
            data = msg.request_frame(NODE_ADDRESS[NodeKind(msg.node)])
        timeout = (wire_time_us(len(data), int(self.tendon.baud))
                   + int(self.params.values[self._p_tendon_timeout]))
        self._pending = _Pending(msg, self.hal.clock.call_later(timeout, self._on_timeout))
        self.tendon_counters.requests += 1
        self.tendon.send(data)

    def _on_timeout(self) -> None:
        self.tendon_counters.timeouts += 1
        self._pending = None
        self._next_on_bus()

    def _on_tendon_bytes(self, data: bytes, t_us: int) -> None:
        if self._tunnel_heard is not None:
            room = TUNNEL_MAX - len(self._tunnel_heard)
            self._tunnel_heard += data[:max(0, room)]
            # A complete reply to the host ends the listening early: a relayed request is
            # answered as soon as its answer is in, not after the whole ``max_ms``.
            replied = any(f.address == ADDR_HOST
                          for f in self._tendon_decoder.feed(data, t_us / 1e6))
            if replied and self._tunnel_timer is not None:
                self._tunnel_timer.cancel()
                self._tunnel_timer = None
                self._finish_tunnel()
            return
        for frame in self._tendon_decoder.feed(data, t_us / 1e6):
            self._on_tendon_frame(frame)

    def _on_tendon_frame(self, frame: Frame) -> None:
        pending = self._pending
        if frame.address != ADDR_HOST or pending is None or frame.type != pending.message.type_id:
            self.tendon_counters.stray_frames += 1
            return
        pending.timer.cancel()
        self._pending = None
        try:
            fields = pending.message.parse_reply(frame.payload)
        except ProtocolError:
            self.tendon_counters.bad_replies += 1
        else:
            self.tendon_counters.replies += 1
            self._store_reply(pending.message.name, fields)
        self._next_on_bus()

    def _store_reply(self, name: str, fields: dict[str, Any]) -> None:
        ph = self.phalanges
        now = self.hal.clock.now_us() & 0xFFFFFFFF
        prefix = "pp" if name.startswith("f2.") else "dp"
        if name.endswith(".tactile"):
            tactile, imu_key, time_key = _TACTILE_KEYS[prefix]
            imu = fields["imu"]
            # The reply's fields are u16 taxels and i16 IMU counts, the status fields'
            # own types: copied, not clamped (a test checks the two catalogues agree).
            ph[tactile] = list(fields["taxels"])
            ph[imu_key] = [*imu["accel"], *imu["mag"]]
            ph[time_key] = now
        elif name.endswith(".temperatures"):
            ph[f"{prefix}_temp"] = [_u16(v) for v in fields["temp"]]
        elif name == "f2.strain":
            ph["pp_strain"] = int(fields["strain"])

    # --- tunnel ---------------------------------------------------------------------------
    def _on_tunnel(self, req: Request) -> Any:
        """Queue the tunnel request (up to :data:`TUNNEL_QUEUE` behind the one on the bus);
        autopoll pauses while any waits; a poll in flight finishes first."""
        if len(self._tunnels) > TUNNEL_QUEUE:
            req.respond(None, TxnStatus.BUSY)
            return DEFERRED
        self._tunnels.append((req, bytes(req.fields["data"]), int(req.fields["max_ms"])))
        self._queue.clear()
        self._next_on_bus()
        return DEFERRED

    def _start_tunnel(self) -> None:
        _req, data, max_ms = self._tunnels[0]
        self.tendon_counters.tunnels += 1
        self._tunnel_heard = bytearray()
        self._tendon_decoder.reset()
        self.tendon.send(data)
        self._tunnel_timer = self.hal.clock.call_later(
            wire_time_us(len(data), int(self.tendon.baud)) + max_ms * 1000, self._end_tunnel)

    def _end_tunnel(self) -> None:
        self._tunnel_timer = None
        self._finish_tunnel()

    def _finish_tunnel(self) -> None:
        assert self._tunnels and self._tunnel_heard is not None
        req = self._tunnels.popleft()[0]
        heard = bytes(self._tunnel_heard)
        self._tunnel_heard = None
        self._tendon_decoder.reset()
        req.respond({"data": heard})
        self._next_on_bus()
