"""Tests of the palm application: routing, finger power, polling, breakaway, governor, CAN.

The palm runs on a virtual palm HAL; each finger's fmcb is a small fake that answers ping,
hw_version, fmcb.status and fmcb.tunnel on that finger's UART after a short delay.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from firmware_py.current_governor import FULL_CAP, CurrentGovernor
from firmware_py.palm import PalmApp
from firmware_py.palm_router import LOST_AFTER_MISSES, QUEUE_DEPTH, tunnel_max_ms
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import APP_PROGRAMS, load_program, make_hal
from firmware_py.sim.virtual_hal import VirtualHal
from protocol.canlink import DEFAULT_PALM_NODE, CanReassembler, can_id, segment
from protocol.framing import Frame, encode_frame, parse_frame
from protocol.image import BoardType
from protocol.messages import CATALOGUE
from protocol.stream import StreamDecoder, decode_all

MS = 1_000
STATUS = CATALOGUE["fmcb.status"]
TUNNEL = CATALOGUE["fmcb.tunnel"]
ROUTE = CATALOGUE["palm.route"]
EVENT = CATALOGUE["palm.finger_event"]
PING_TO_FMCB = encode_frame(10, 0x01)
PING_TO_F3 = encode_frame(2, 0x01)


class FakeFmcb:
    """An fmcb on the far end of ``finger{k}``: answers after ``delay_us`` while ``alive``."""

    def __init__(self, sched: Scheduler, hal: VirtualHal, finger: int, delay_us: int = 300,
                 tunnel_delay_us: int = 2 * MS) -> None:
        self.sched = sched
        self.uart = hal.uart(f"finger{finger}")
        self.uart.sink = self._on_bytes
        self.decoder = StreamDecoder(gap_s=None)
        self.received: list[Frame] = []
        self.caps: list[int] = []
        self.alive = True
        self.delay_us = delay_us
        self.tunnel_delay_us = tunnel_delay_us
        self.hall_pos = [100 * finger + 1, 100 * finger + 2, 100 * finger + 3]
        self.effort = [-5, 0, 7]

    def types(self) -> list[int]:
        return [f.type for f in self.received]

    def _on_bytes(self, data: bytes, t_us: int) -> None:
        for frame in self.decoder.feed(data):
            self.received.append(frame)
            if not self.alive:
                continue
            reply, delay = self.answer(frame)
            if reply is not None:
                self.sched.call_later(delay, self._deliver_later(reply))

    def _deliver_later(self, reply: bytes) -> Callable[[], None]:
        return lambda: self.uart.deliver(reply)

    def answer(self, frame: Frame) -> tuple[bytes | None, int]:
        if frame.type == 0x01:
            return encode_frame(0, 0x01), self.delay_us
        if frame.type == 0xFA:
            return encode_frame(0, 0xFA, (0xBEEF0041).to_bytes(4, "little")), self.delay_us
        if frame.type == STATUS.type_id:
            fields = STATUS.parse_reply(bytes(148))
            fields.update(hall_pos=self.hall_pos, effort=self.effort)
            return STATUS.reply_frame(fields), self.delay_us
        if frame.type == TUNNEL.type_id:
            req = TUNNEL.parse_request(frame.payload)
            inner = parse_frame(req["data"])
            # The tendon bus hears the request itself (echo) and then the phalange's reply.
            heard = req["data"] + encode_frame(0, inner.type, b"")
            reply = TUNNEL.reply_frame(data=heard)
            return reply, self.tunnel_delay_us
        if frame.type == 0x23:
            self.caps.append(frame.payload[0])
        return None, 0


class Palm:
    """A palm under test with its scheduler and helpers to talk to it."""

    def __init__(self) -> None:
        self.sched = Scheduler()
        self.hal = make_hal(self.sched, BoardType.PALM)
        self.app = PalmApp(self.hal, None)
        self.app.start()
        self.host = self.hal.uart("host")
        self.fakes = [FakeFmcb(self.sched, self.hal, k) for k in range(4)]
        self.frames: list[Frame] = []

    def send(self, name: str, **fields: Any) -> None:
        self.host.deliver(CATALOGUE[name].request_frame(10, fields))

    def run(self, us: int) -> None:
        self.sched.run_for(us)
        self.frames += decode_all(b"".join(self.host.take_sent()))

    def replies(self, name: str) -> list[dict[str, Any]]:
        msg = CATALOGUE[name]
        return [msg.parse_reply(f.payload) for f in self.frames
                if f.type == msg.type_id and f.address == 0]

    def events(self) -> list[tuple[int, int]]:
        return [(e["finger"], e["event"]) for e in self.replies("palm.finger_event")]

    def power(self, finger: int, state: int = 2) -> None:
        self.send("palm.finger_power", finger=finger, state=state, stagger_ms=0)
        self.run(1 * MS)

    def route(self, finger: int, hop: int, frame: bytes, timeout_ms: int = 10) -> None:
        self.send("palm.route", finger=finger, hop=hop, timeout_ms=timeout_ms, frame=frame)


@pytest.fixture
def palm() -> Palm:
    return Palm()


# --- routing ---------------------------------------------------------------------------------
def test_route_ping_to_finger1_fmcb(palm: Palm) -> None:
    palm.power(1)
    palm.route(1, 0, PING_TO_FMCB)
    palm.run(5 * MS)
    [reply] = palm.replies("palm.route")
    assert (reply["finger"], reply["hop"], reply["status"]) == (1, 0, 0)
    answer = parse_frame(reply["frame"])
    assert (answer.address, answer.type, answer.payload) == (0, 0x01, b"")
    assert palm.fakes[1].types() == [0x01]
    assert all(not palm.fakes[k].received for k in (0, 2, 3))


def test_route_to_f3_goes_as_tunnel_and_is_unwrapped(palm: Palm) -> None:
    palm.power(2)
    palm.route(2, 2, PING_TO_F3, timeout_ms=20)
    palm.run(1 * MS)
    [tunnel] = palm.fakes[2].received
    assert (tunnel.address, tunnel.type) == (10, TUNNEL.type_id)
    req = TUNNEL.parse_request(tunnel.payload)
    assert req["data"] == PING_TO_F3
    assert 0 < req["max_ms"] < 20  # the fmcb's listening time fits inside the palm's wait
    assert req["max_ms"] == tunnel_max_ms(20, len(tunnel.payload) + 7, 2_000_000)
    assert palm.replies("palm.route") == []
    palm.run(5 * MS)
    [reply] = palm.replies("palm.route")
    assert (reply["finger"], reply["hop"], reply["status"]) == (2, 2, 0)
    answer = parse_frame(reply["frame"])  # the f3's reply, not the echo of the request
    assert (answer.address, answer.type) == (0, 0x01)


def test_no_reply_gives_status_1_after_timeout(palm: Palm) -> None:
    palm.power(1)
    palm.fakes[1].alive = False
    palm.route(1, 0, PING_TO_FMCB, timeout_ms=15)
    palm.run(14 * MS)
    assert palm.replies("palm.route") == []
    palm.run(2 * MS)
    [reply] = palm.replies("palm.route")
    assert (reply["status"], reply["frame"]) == (1, b"")


def test_unpowered_and_bad_destinations(palm: Palm) -> None:
    palm.route(1, 0, PING_TO_FMCB)
    palm.power(0)
    palm.route(4, 0, PING_TO_FMCB)
    palm.route(0, 3, PING_TO_FMCB)
    palm.route(0, 0, PING_TO_FMCB[:-1] + bytes([PING_TO_FMCB[-1] ^ 1]))  # bad CRC
    palm.route(0, 0, PING_TO_FMCB + b"\x00")  # trailing garbage
    palm.route(0, 1, encode_frame(1, 0x01, bytes(600)))  # too big for a tunnel
    palm.run(5 * MS)
    statuses = [r["status"] for r in palm.replies("palm.route")]
    assert statuses == [2, 3, 3, 3, 3, 3]
    assert palm.fakes[0].received == []


def test_two_routes_to_one_finger_are_both_answered_in_order(palm: Palm) -> None:
    palm.power(1)
    palm.route(1, 0, PING_TO_FMCB)
    palm.route(1, 0, encode_frame(10, 0xFA))
    palm.run(200)
    # Only the first is on the wire until it is answered: nothing is overwritten.
    assert len(palm.hal.uart("finger1").sent) == 1
    palm.run(5 * MS)
    replies = palm.replies("palm.route")
    assert [r["status"] for r in replies] == [0, 0]
    assert [parse_frame(r["frame"]).type for r in replies] == [0x01, 0xFA]
    assert palm.fakes[1].types() == [0x01, 0xFA]


def test_a_late_reply_of_another_type_is_not_taken_for_the_next_routes_answer(
        palm: Palm) -> None:
    """A routed reply is matched by address and type: the fmcb's late answer to a route that
    timed out (a ping), and an echo of the request (addressed to the fmcb), both arriving
    while the next route (hw_version) waits, are stray; that route gets its own answer."""
    palm.power(1)
    palm.fakes[1].delay_us = 8 * MS  # slower than the first route's 5 ms
    palm.route(1, 0, PING_TO_FMCB, timeout_ms=5)
    palm.route(1, 0, encode_frame(10, 0xFA), timeout_ms=10)
    palm.run(6 * MS)  # the ping timed out; hw_version is in flight
    assert [r["status"] for r in palm.replies("palm.route")] == [1]
    stray = palm.app.links[1].stray_frames
    palm.hal.uart("finger1").deliver(encode_frame(10, 0xFA))  # to the fmcb, not the host
    palm.run(4 * MS)  # the late ping reply arrives at 8 ms
    assert len(palm.replies("palm.route")) == 1  # neither was taken for hw_version's answer
    assert palm.app.links[1].stray_frames == stray + 2
    palm.run(10 * MS)
    replies = palm.replies("palm.route")
    assert [r["status"] for r in replies] == [1, 0]
    answer = parse_frame(replies[1]["frame"])
    assert (answer.address, answer.type) == (0, 0xFA)


def test_full_queue_refuses_with_busy(palm: Palm) -> None:
    palm.power(3)
    palm.fakes[3].alive = False
    for _ in range(QUEUE_DEPTH + 2):
        palm.route(3, 0, PING_TO_FMCB, timeout_ms=5)
    palm.run(100)
    assert [r["status"] for r in palm.replies("palm.route")] == [5]
    palm.run(50 * MS)
    assert [r["status"] for r in palm.replies("palm.route")] == [5] + [1] * (QUEUE_DEPTH + 1)


def test_powering_off_ends_waiting_routes_as_unpowered(palm: Palm) -> None:
    palm.power(1)
    palm.fakes[1].alive = False
    palm.route(1, 0, PING_TO_FMCB, timeout_ms=50)
    palm.route(1, 0, PING_TO_FMCB, timeout_ms=50)
    palm.run(2 * MS)
    palm.power(1, 0)
    assert [r["status"] for r in palm.replies("palm.route")] == [2, 2]
    assert palm.events() == [(1, 3), (1, 4)]


def test_route_reply_to_a_no_reply_message_and_timeout_zero(palm: Palm) -> None:
    palm.power(0)
    palm.route(0, 0, CATALOGUE["fmcb.effort_cap"].request_frame(10, cap=99), timeout_ms=50)
    palm.route(0, 0, PING_TO_FMCB, timeout_ms=0)
    palm.run(1 * MS)
    assert [(r["status"], r["frame"]) for r in palm.replies("palm.route")] == [(0, b"")] * 2
    assert palm.fakes[0].caps == [99]


# --- finger power --------------------------------------------------------------------------
def test_all_fingers_power_with_stagger(palm: Palm) -> None:
    palm.send("palm.finger_power", finger=0xFF, state=2, stagger_ms=30)
    palm.run(100)
    assert palm.replies("palm.finger_power") == [{"states": [2, 0, 0, 0]}]
    palm.run(29 * MS)
    assert palm.app.power_states() == [2, 0, 0, 0]
    palm.run(1 * MS)
    assert palm.app.power_states() == [2, 2, 0, 0]
    palm.run(60 * MS)
    assert [palm.hal.power(f"finger{k}").state for k in range(4)] == [2, 2, 2, 2]
    assert palm.events() == [(0, 3), (1, 3), (2, 3), (3, 3)]
    times = [e["time"] for e in palm.replies("palm.finger_event")]
    assert [t - times[0] for t in times] == [0, 30 * MS, 60 * MS, 90 * MS]
    palm.send("palm.finger_power", finger=0xFF, state=0, stagger_ms=0)
    palm.run(1 * MS)
    assert palm.replies("palm.finger_power")[-1] == {"states": [0, 0, 0, 0]}
    assert palm.events()[4:] == [(0, 4), (1, 4), (2, 4), (3, 4)]


def test_low_power_and_a_new_command_cancels_a_pending_stagger(palm: Palm) -> None:
    palm.send("palm.finger_power", finger=0xFF, state=1, stagger_ms=10)
    palm.run(5 * MS)
    palm.send("palm.finger_power", finger=3, state=0, stagger_ms=0)
    palm.run(50 * MS)
    assert palm.app.power_states() == [1, 1, 1, 0]
    palm.send("palm.finger_power", finger=1, state=7, stagger_ms=0)  # no such state: ignored
    palm.run(1 * MS)
    assert palm.replies("palm.finger_power")[-1] == {"states": [1, 1, 1, 0]}


# --- polling, hand status, breakaway -------------------------------------------------------
def test_polling_fills_hand_status(palm: Palm) -> None:
    palm.power(0)
    palm.power(1, 1)
    palm.hal.power("finger0").load_ma = 700
    palm.hal.power("finger2").load_ma = 900  # unpowered: reads 0
    palm.send("palm.poll", rate_hz=100)
    palm.run(55 * MS)
    polls = palm.fakes[0].types().count(STATUS.type_id)
    assert 5 <= polls <= 6
    assert palm.fakes[2].received == []
    palm.send("palm.hand_status")
    palm.run(1 * MS)
    [status] = palm.replies("palm.hand_status")
    assert status["poll_hz"] == 100 and status["effort_cap"] == 255
    assert status["bus_voltage"] == 24000
    f0, f1, f2, _ = status["fingers"]
    assert (f0["present"], f0["power"], f0["current"]) == (1, 2, 700)
    assert f0["hall_pos"] == [1, 2, 3] and f0["effort"] == [-5, 0, 7]
    assert f0["last_seen_ms"] <= 10
    assert (f1["present"], f1["power"], f1["hall_pos"]) == (1, 1, [101, 102, 103])
    assert (f2["present"], f2["power"], f2["current"], f2["last_seen_ms"]) == (0, 0, 0, 0xFFFF)
    palm.send("palm.poll", rate_hz=0)
    palm.run(1 * MS)
    before = len(palm.fakes[0].received)
    palm.run(50 * MS)
    assert len(palm.fakes[0].received) == before


def test_polling_skips_a_finger_while_a_route_is_in_flight(palm: Palm) -> None:
    palm.power(2)
    palm.fakes[2].tunnel_delay_us = 40 * MS
    palm.send("palm.poll", rate_hz=100)
    palm.run(15 * MS)
    palm.fakes[2].received.clear()
    palm.route(2, 1, encode_frame(1, 0x01), timeout_ms=50)
    palm.run(39 * MS)
    assert palm.fakes[2].types() == [TUNNEL.type_id]  # no status poll while it waits
    palm.run(20 * MS)
    assert palm.replies("palm.route")[0]["status"] == 0
    assert STATUS.type_id in palm.fakes[2].types()
    assert palm.events() == [(2, 3)]  # skipped polls are not misses


def test_breakaway_lost_and_returned(palm: Palm) -> None:
    palm.power(1)
    palm.send("palm.poll", rate_hz=100)
    palm.run(30 * MS)
    assert palm.events() == [(1, 3)]
    palm.fakes[1].alive = False
    palm.run((LOST_AFTER_MISSES - 1) * 10 * MS)
    assert palm.events() == [(1, 3)]
    palm.run(10 * MS)
    assert palm.events() == [(1, 3), (1, 0)]
    palm.route(1, 0, PING_TO_FMCB)
    palm.send("palm.hand_status")
    palm.run(1 * MS)
    assert palm.replies("palm.route")[-1]["status"] == 4
    assert palm.replies("palm.hand_status")[-1]["fingers"][1]["present"] == 0
    palm.fakes[1].alive = True
    palm.run(12 * MS)
    assert palm.events() == [(1, 3), (1, 0), (1, 1)]
    palm.route(1, 0, PING_TO_FMCB)
    palm.run(5 * MS)
    assert palm.replies("palm.route")[-1]["status"] == 0


def test_a_finger_lost_while_routes_keep_its_link_busy_is_reported_after_three_timeouts(
        palm: Palm) -> None:
    """Routes back to back leave no idle moment for a poll: their timeouts count as misses,
    so the loss is reported after LOST_AFTER_MISSES routed timeouts (10 ms each here), as
    fast as polls at 100 Hz would, not never."""
    palm.power(1)
    palm.send("palm.poll", rate_hz=100)
    palm.run(30 * MS)
    assert palm.events() == [(1, 3)]
    for _ in range(QUEUE_DEPTH + 1):  # one in flight, the queue full: the link never idles
        palm.route(1, 0, PING_TO_FMCB, timeout_ms=10)
    palm.run(1 * MS)
    palm.fakes[1].alive = False
    lost_at = None
    for ms in range(1, 200):
        palm.run(1 * MS)
        palm.route(1, 0, PING_TO_FMCB, timeout_ms=10)  # the queue stays full (else BUSY)
        if (1, 0) in palm.events():
            lost_at = ms
            break
    assert lost_at is not None, "no lost event in 200 ms of routed traffic"
    # the route in flight when it died may have been answered: at most one more timeout
    assert lost_at <= (LOST_AFTER_MISSES + 1) * 10 + 2
    assert palm.events() == [(1, 3), (1, 0)]


def test_a_finger_that_never_answered_is_not_lost(palm: Palm) -> None:
    palm.fakes[0].alive = False
    palm.power(0)
    palm.send("palm.poll", rate_hz=200)
    palm.run(100 * MS)
    assert palm.events() == [(0, 3)]


# --- current governor ----------------------------------------------------------------------
def test_governor_law() -> None:
    gov = CurrentGovernor(limit_ma=1000, step_down=20, step_up=5, hysteresis_ma=100)
    assert gov.update(1001) == 235
    assert gov.update(5000) == 215
    assert gov.update(950) == 215  # inside the hysteresis band: hold
    assert gov.update(1000) == 215  # at the limit: hold
    assert gov.update(899) == 220
    for _ in range(100):
        gov.update(0)
    assert gov.cap == FULL_CAP
    for _ in range(100):
        gov.update(2000)
    assert gov.cap == 0
    floor = CurrentGovernor(limit_ma=10, min_cap=40)
    for _ in range(50):
        floor.update(100)
    assert floor.cap == 40
    assert CurrentGovernor(limit_ma=2000).band_ma == 200
    assert CurrentGovernor(limit_ma=100).band_ma == 50
    with pytest.raises(ValueError):
        CurrentGovernor(step_down=0)


def test_governor_lowers_and_raises_the_cap_and_tells_the_fingers(palm: Palm) -> None:
    palm.power(0)
    palm.power(2)
    palm.send("palm.current_limit", limit_ma=1000)
    palm.run(20 * MS)
    assert palm.fakes[0].caps == [] and palm.fakes[2].caps == []
    palm.hal.power("finger0").load_ma = 600
    palm.hal.power("finger2").load_ma = 600
    palm.hal.power("finger3").load_ma = 5000  # unpowered: draws nothing
    palm.run(30 * MS)
    assert palm.app.governor.cap < FULL_CAP
    assert palm.fakes[0].caps == palm.fakes[2].caps
    assert palm.fakes[0].caps[:3] == [239, 223, 207]
    assert palm.fakes[3].received == []
    palm.hal.power("finger0").load_ma = 100
    palm.hal.power("finger2").load_ma = 100
    palm.run(1000 * MS)
    assert palm.fakes[0].caps[-1] == FULL_CAP
    caps = palm.fakes[2].caps
    assert caps == sorted(caps[:3], reverse=True) + sorted(caps[3:])
    palm.send("palm.hand_status")
    palm.run(1 * MS)
    assert palm.replies("palm.hand_status")[-1]["effort_cap"] == FULL_CAP


def test_effort_cap_waits_for_the_link_to_be_quiet(palm: Palm) -> None:
    palm.power(1)
    palm.fakes[1].tunnel_delay_us = 15 * MS
    palm.send("palm.current_limit", limit_ma=100)
    palm.hal.power("finger1").load_ma = 500
    palm.route(1, 1, encode_frame(1, 0x01), timeout_ms=30)
    palm.run(12 * MS)
    assert palm.fakes[1].caps == []  # the governor stepped at 10 ms, the link is busy
    palm.run(6 * MS)
    assert palm.fakes[1].caps and palm.fakes[1].caps[0] <= 239


# --- host links and own sensors ------------------------------------------------------------
def test_can_request_gets_a_can_reply(palm: Palm) -> None:
    palm.power(1)
    can = palm.hal.can()
    request = CATALOGUE["palm.route"].build_request(finger=1, hop=0, timeout_ms=10,
                                                    frame=PING_TO_FMCB)
    for chunk in segment(encode_frame(10, ROUTE.type_id, request)):
        can.deliver(can_id(DEFAULT_PALM_NODE, to_host=False), chunk)
    can.deliver(0x123, b"\x42\x0a")  # somebody else's traffic
    palm.run(5 * MS)
    rx = CanReassembler()
    frames = [f for cid, data, _ in can.sent for f in rx.feed(cid, data)]
    assert {cid for cid, _, _ in can.sent} == {0x180 + DEFAULT_PALM_NODE}
    assert all(len(data) <= 8 for _, data, _ in can.sent)
    [frame] = frames
    reply = ROUTE.parse_reply(frame.payload)
    assert (frame.address, reply["status"], parse_frame(reply["frame"]).type) == (0, 0, 0x01)
    assert palm.replies("palm.route") == []  # not on the serial link


def test_palm_state_and_tactile(palm: Palm) -> None:
    values = palm.hal.sensors.values
    values.update(accel=(10, -20, 1000), gyro=(1, 2, 3), mag=(-7, 8, 40000))
    for i in range(7):
        values[f"temperature{i}"] = 200 + i
    for i in range(32):
        values[f"taxel{i}"] = 1000 + i
    palm.run(40 * MS)
    state_msg = CATALOGUE["palm.state"]
    palm.send("palm.state")
    palm.send("palm.tactile")
    palm.run(1 * MS)
    [frame] = [f for f in palm.frames if f.type == state_msg.type_id]
    assert len(frame.payload) == 100
    state = state_msg.parse_reply(frame.payload)
    assert state["accel"] == [10, -20, 1000] and state["gyro"] == [1, 2, 3]
    assert state["mag"] == [-7, 8, 32767]  # clamped to i16
    assert state["temps"] == [200, 201, 202, 203, 204, 205, 206]
    assert state["tactile"] == [1000 + i for i in range(32)]
    assert state["time"] == 40 * MS  # rebuilt at 100 Hz: the snapshot of t = 40 ms
    assert palm.replies("palm.tactile") == [{"taxels": [1000 + i for i in range(32)]}]


def test_taxels_are_scanned_one_per_millisecond(palm: Palm) -> None:
    for i in range(32):
        palm.hal.sensors.values[f"taxel{i}"] = 7
    palm.run(int(10.5 * MS))
    assert palm.app.taxels.count(7) == 10
    palm.run(22 * MS)
    assert palm.app.taxels == [7] * 32


def test_bad_payloads_and_unknown_types_are_ignored(palm: Palm) -> None:
    palm.host.deliver(encode_frame(10, CATALOGUE["palm.poll"].type_id, b"\x01\x02"))
    palm.host.deliver(encode_frame(10, 0x7E, b""))
    palm.host.deliver(encode_frame(10, CATALOGUE["fmcb.control"].type_id, b"\x00"))
    palm.send("ping")
    palm.run(1 * MS)
    assert [(f.type, f.payload) for f in palm.frames] == [(0x01, b"")]
    assert palm.app.counters.bad_payload == 1
    assert palm.app.counters.unknown_type == 2
    assert palm.app.poll_hz == 0


def test_boards_table_loads_the_palm() -> None:
    assert APP_PROGRAMS["palm"] == "firmware_py.palm:PalmApp"
    sched = Scheduler()
    hal = make_hal(sched, BoardType.PALM)
    program = load_program(APP_PROGRAMS["palm"])(hal, None)  # type: ignore[arg-type]
    assert isinstance(program, PalmApp) and program.address == 10


def test_route_inside_a_txn_envelope_is_answered_with_its_sequence(palm: Palm) -> None:
    palm.power(0)
    inner = ROUTE.build_request(finger=0, hop=0, timeout_ms=10, frame=PING_TO_FMCB)
    palm.send("txn", seq=42, inner_type=ROUTE.type_id, inner=inner)
    palm.run(5 * MS)
    [reply] = palm.replies("txn")
    assert (reply["seq"], reply["status"], reply["inner_type"]) == (42, 0, ROUTE.type_id)
    assert ROUTE.parse_reply(reply["inner"])["status"] == 0


def test_palm_boots_from_its_bootloader_and_answers() -> None:
    from firmware_py.sim.boards import make_node

    sched = Scheduler()
    node = make_node(sched, BoardType.PALM)
    node.power_on()
    for _ in range(100):
        if node.program_name == "palm":
            break
        sched.run_for(100 * MS)
    assert isinstance(node.program, PalmApp)
    hal = node.hal
    assert isinstance(hal, VirtualHal)
    host = hal.uart("host")
    host.take_sent()
    host.deliver(encode_frame(10, 0x01))
    sched.run_for(1 * MS)
    assert [(f.address, f.type) for f in decode_all(b"".join(host.take_sent()))] == [(0, 0x01)]
