"""Tests of the fmcb application (firmware_py.fmcb) on the VirtualHal, without physics.

The phalanges are simulated by delivering reply frames to the fmcb's tendon UART after the
test has seen the request; hall sensors by setting the virtual motors' hall states.
"""

from __future__ import annotations

import math
import struct
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_py.flash_layout import PARAM_PAGE, page_address
from firmware_py.fmcb import TUNNEL_QUEUE, FmcbApp
from firmware_py.fmcb_control import HallCounter, min_cap, pd_effort
from firmware_py.fmcb_params import FMCB_PARAMS, PARAM_SENTINEL, ParamTable
from firmware_py.mcu import Mcu
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import make_hal, make_node
from firmware_py.sim.virtual_hal import VirtualHal
from protocol.framing import Frame, encode_frame
from protocol.image import BoardType
from protocol.messages import CATALOGUE
from protocol.robot import HALL_SEQUENCE, joint_to_motor
from protocol.stream import decode_all

K = 36 / (2 * math.pi)


# --- helpers -------------------------------------------------------------------------------
class Rig:
    """A started FmcbApp on a virtual fmcb board."""

    def __init__(self, hal: VirtualHal | None = None, sched: Scheduler | None = None) -> None:
        self.sched = sched or Scheduler()
        self.hal = hal or make_hal(self.sched, BoardType.FMCB)
        for m in self.hal.motors:
            m.hall = HALL_SEQUENCE[0]
        self.app = FmcbApp(self.hal, None)
        self.app.start()
        self.pogo = self.hal.uart("pogo")
        self.tendon = self.hal.uart("tendon")

    def run_ms(self, ms: float) -> None:
        self.sched.run_for(int(ms * 1000))

    def send(self, name: str, fields: dict[str, Any] | None = None, run_ms: float = 0.5,
             payload: bytes | None = None) -> list[Frame]:
        msg = CATALOGUE[name]
        body = msg.build_request(fields or {}) if payload is None else payload
        self.pogo.deliver(encode_frame(10, msg.type_id, body))
        self.run_ms(run_ms)
        return decode_all(b"".join(self.pogo.take_sent()))

    def ask(self, name: str, fields: dict[str, Any] | None = None, run_ms: float = 0.5
            ) -> dict[str, Any]:
        frames = self.send(name, fields, run_ms)
        assert len(frames) == 1, frames
        assert frames[0].address == 0 and frames[0].type == CATALOGUE[name].type_id
        return CATALOGUE[name].parse_reply(frames[0].payload)

    def status_bytes(self) -> bytes:
        frames = self.send("fmcb.status")
        assert len(frames) == 1
        return frames[0].payload

    def step_hall(self, motor: int, steps: int) -> None:
        """Advance motor's hall state |steps| positions (sign = direction), 1 ms apart."""
        m = self.hal.motors[motor]
        for _ in range(abs(steps)):
            idx = HALL_SEQUENCE.index(m.hall)
            m.hall = HALL_SEQUENCE[(idx + (1 if steps > 0 else -1)) % 6]
            self.run_ms(1)

    def duties(self) -> list[float]:
        return [m.duty for m in self.hal.motors]

    def tendon_frames(self) -> list[Frame]:
        return decode_all(b"".join(self.tendon.take_sent()))


@pytest.fixture
def rig() -> Rig:
    return Rig()


# --- hall counting --------------------------------------------------------------------------
def test_hall_counter_forward_backward_and_invalid() -> None:
    h = HallCounter()
    h.update(1)
    for s in (3, 2, 6, 4, 5, 1, 3):  # seven steps forward
        h.update(s)
    assert h.count == 7 and h.invalid == 0
    for s in (1, 5, 4):  # three back
        h.update(s)
    assert h.count == 4
    h.update(3)  # 4 → 3 jumps over 6 and 2: ignored
    h.update(0)  # impossible states
    h.update(7)
    assert h.count == 4 and h.invalid == 3
    h.update(6)  # the next valid neighbour of 4 (still the reference) counts again
    assert h.count == 3


def test_app_counts_halls_and_reports_velocity(rig: Rig) -> None:
    rig.step_hall(0, 12)
    rig.step_hall(1, -5)
    rig.hal.motors[2].hall = 6  # jump of two from 1: ignored
    rig.run_ms(1)
    reply = rig.ask("fmcb.hall_counts", {"raw": 1})
    assert reply["counts"] == [12, -5, 0]
    assert rig.app.hall[2].invalid == 1
    rig.step_hall(0, 10)  # one step per ms: 1000 counts/s over the 10 ms window
    assert rig.ask("fmcb.hall_counts", {"raw": 1})["velocity"][0] == 1000
    assert rig.ask("fmcb.halls")["bits"] == [rig.hal.motors[i].hall for i in range(3)]


def test_set_home_offsets_positions(rig: Rig) -> None:
    rig.step_hall(0, 8)
    rig.ask("fmcb.set_home", {"offset": [8, -2, 0]})
    assert rig.ask("fmcb.hall_counts", {"raw": 0})["counts"] == [0, 2, 0]
    assert rig.ask("fmcb.hall_counts", {"raw": 1})["counts"] == [8, 0, 0]


# --- control ------------------------------------------------------------------------------
def test_idle_at_start_motors_disabled(rig: Rig) -> None:
    rig.run_ms(5)
    assert not any(m.enabled for m in rig.hal.motors)
    assert rig.duties() == [0.0, 0.0, 0.0]


def test_motor_mode_drives_toward_target_and_stops_in_deadband(rig: Rig) -> None:
    rig.send("fmcb.control", {"mode": 1, "args": {"hall_target": [80, -80, 2]}}, run_ms=2)
    d = rig.duties()
    assert d[0] > 0 and d[1] < 0 and d[2] == 0.0  # motor 2 is within the 2-count deadband
    assert all(m.enabled for m in rig.hal.motors)
    assert d[0] == pytest.approx(80 / 255, abs=1 / 255)  # kp = 1 PWM count per hall count
    rig.step_hall(0, 78)  # error 2: inside the deadband
    rig.step_hall(1, -77)  # error 3: still driving
    assert rig.hal.motors[0].duty == 0.0
    assert rig.hal.motors[1].duty < 0
    rig.step_hall(1, -1)
    assert rig.hal.motors[1].duty == 0.0


def test_joint_modes_use_the_coupling(rig: Rig) -> None:
    # q2 = 0.1 rad: m = (+327, −327, +368) hall counts.
    rig.send("fmcb.control", {"mode": 2, "args": {"target": [0.0, 0.0, 0.1]}}, run_ms=2)
    assert rig.app.hall_target == [round(v) for v in joint_to_motor((0, 0, 0.1))]
    d = rig.duties()
    assert d[0] > 0 and d[1] < 0 and d[2] > 0
    # Fixed point: 1000 × 1e-4 rad = 0.1 rad on J0 only.
    rig.send("fmcb.control", {"mode": 3, "args": {"target": [1000, 0, 0]}}, run_ms=2)
    assert rig.app.hall_target == [round(K * 173.4 * 0.1), 0, 0]
    d = rig.duties()
    assert d[0] > 0 and d[1] == 0.0 and d[2] == 0.0
    # Relative: add −0.2 rad to J0 → target −0.1 rad.
    rig.send("fmcb.control", {"mode": 5, "args": {"target": [-0.2, 0, 0],
                                                  "max_effort": [255, 255, 255]}}, run_ms=2)
    assert rig.app.hall_target[0] == pytest.approx(-K * 173.4 * 0.1, abs=1)
    assert rig.duties()[0] < 0
    # Joint limits clamp (default ±1.57 rad).
    rig.send("fmcb.control", {"mode": 2, "args": {"target": [5.0, 0, 0]}})
    assert rig.app.hall_target[0] == round(K * 173.4 * 1.57)
    # Back to idle: motors disabled.
    rig.send("fmcb.control", {"mode": 0, "args": {}}, run_ms=2)
    assert not any(m.enabled for m in rig.hal.motors) and rig.duties() == [0.0] * 3


def test_effort_clamps_and_min_of_caps(rig: Rig) -> None:
    assert pd_effort(1000, 0, 1.0, 0.0, 50, 255) == 255
    assert pd_effort(-1000, 0, 1.0, 0.0, 50, 255) == -255
    assert pd_effort(50, 0, 1.0, 0.0, 50, 255) == 0
    assert pd_effort(100, 10_000, 1.0, 0.002, 50, 255) == 80  # derivative term damps
    assert min_cap(255, 100, 40) == 40 and min_cap(300) == 255
    targets = {"hall_target": [2000, -2000, 2000]}
    rig.send("fmcb.control", {"mode": 1, "args": targets}, run_ms=2)
    assert rig.app.effort == [255, -255, 255]
    rig.send("fmcb.effort_cap", {"cap": 100}, run_ms=2)  # hand-wide cap from the palm
    assert rig.app.effort == [100, -100, 100]
    assert rig.duties()[0] == pytest.approx(100 / 255)
    big = joint_to_motor((0.5, -0.5, 0.5))
    rig.send("fmcb.control", {"mode": 4, "args": {"target": [0.5, -0.5, 0.5],
                                                  "max_effort": [40, 200, 255]}}, run_ms=2)
    assert all(abs(v) > 300 for v in big)
    assert [abs(e) for e in rig.app.effort] == [40, 100, 100]
    rig.app.params.set("max_effort", 30)  # board-wide parameter clamp
    rig.run_ms(5)  # and a fresh status snapshot
    assert [abs(e) for e in rig.app.effort] == [30, 30, 30]
    status = CATALOGUE["fmcb.status"].parse_reply(rig.status_bytes())
    assert [abs(e) for e in status["effort"]] == [30, 30, 30]


def test_control_with_wrong_length_is_ignored(rig: Rig) -> None:
    rig.send("fmcb.control", {"mode": 1, "args": {"hall_target": [500, 500, 500]}}, run_ms=2)
    before = (rig.duties(), list(rig.app.hall_target))
    good = CATALOGUE["fmcb.control"].build_request({"mode": 1,
                                                    "args": {"hall_target": [-500, 0, 0]}})
    for bad in (good[:-1], good + b"\x00", bytes([9]) + good[1:]):
        rig.send("fmcb.control", payload=bad, run_ms=2)
    assert (rig.duties(), rig.app.hall_target) == before
    assert rig.app.counters.bad_payload == 3
    # NaN joint targets are ignored too.
    rig.send("fmcb.control", {"mode": 2, "args": {"target": [math.nan, 0, 0]}}, run_ms=2)
    assert (rig.duties(), rig.app.hall_target) == before


def test_motor_raw_open_loop(rig: Rig) -> None:
    rig.step_hall(2, 3)
    reply = rig.ask("fmcb.motor_raw", {"enable": 0b011, "direction": 0b010, "brake": 0b100,
                                       "duty": [100, 50, 200]}, run_ms=3)
    assert reply["counts"] == [0, 0, 3]
    m = rig.hal.motors
    assert m[0].duty == pytest.approx(100 / 255) and m[1].duty == pytest.approx(-50 / 255)
    assert not m[2].enabled and m[2].brake and m[2].duty == 0.0


# --- status -------------------------------------------------------------------------------
def test_status_layout_and_values(rig: Rig) -> None:
    v = rig.hal.sensors.values
    v["accel"] = (1, -2, 1000)
    v["mag"] = (-300, 400, 500)
    v["temperature0"], v["temperature1"], v["temperature2"] = 251, 252, 253
    v["supply_mv"] = 23_456
    rig.hal.power("phalange").load_ma = 150
    rig.send("fmcb.phalange_power", {"on": 1})
    rig.step_hall(1, 7)
    rig.send("fmcb.control", {"mode": 1, "args": {"hall_target": [-100, 7, 0]}})
    rig.run_ms(260)  # past the 250 ms temperature sample and the 40 ms IMU sample
    raw = rig.status_bytes()
    assert len(raw) == 148
    fmcb_time = struct.unpack_from("<I", raw, 8)[0]
    assert 0 < rig.hal.clock.now_us() - fmcb_time <= 5_000
    assert struct.unpack_from("<6h", raw, 72) == (1, -2, 1000, -300, 400, 500)
    # Raw 12-bit ADC counts on a 3.3 V reference, as the original sent them (by hand):
    # 25.1 °C → 0.751 V → 931.9; 23.456 V / 11 → 2.1324 V → 2646.1; 0.150 A · 2.7 V/A → 502.6.
    assert struct.unpack_from("<3H", raw, 100) == (932, 933, 934)
    assert struct.unpack_from("<HH", raw, 106) == (2646, 503)
    assert raw[110:112] == b"\x00\x00" and raw[146:148] == b"\x00\x00"
    assert struct.unpack_from("<3i", raw, 116) == (-100, 7, 0)
    assert struct.unpack_from("<3i", raw, 128) == (0, 7, 0)
    effort = struct.unpack_from("<3h", raw, 140)
    assert effort[0] == -100 and effort[1:] == (0, 0)
    assert rig.ask("fmcb.temperatures")["temp"] == [932, 933, 934]
    assert rig.ask("fmcb.imu") == {"accel": [1, -2, 1000], "mag": [-300, 400, 500]}
    # The snapshot is monotonic and refreshed every 5 ms.
    rig.run_ms(5)
    assert struct.unpack_from("<I", rig.status_bytes(), 8)[0] > fmcb_time


# --- parameters -----------------------------------------------------------------------------
def test_param_table_page_roundtrip_and_corruption() -> None:
    t = ParamTable()
    t.set("kp", 2.5)
    page = t.to_page()
    assert len(page) == 256 and struct.unpack_from("<I", page)[0] == PARAM_SENTINEL
    fresh = ParamTable()
    assert fresh.load_page(page) and fresh["kp"] == 2.5
    assert not fresh.load_page(b"\xff" * 256) and fresh["kp"] == 1.0
    corrupt = bytearray(page)
    corrupt[14] ^= 1
    assert not fresh.load_page(bytes(corrupt)) and fresh["kp"] == 1.0
    assert not t.set_bits(0, struct.pack("<f", math.inf)) and t["kp"] == 2.5
    assert not t.set_bits(len(FMCB_PARAMS), bytes(4))


def test_params_over_the_wire_commit_and_reload(rig: Rig) -> None:
    n = rig.ask("fmcb.param_count")["count"]
    names = [rig.ask("fmcb.param_name", {"index": i})["name"] for i in range(n)]
    assert names[:4] == ["kp", "kd", "deadband", "max_effort"]
    assert "joint_upper_2" in names
    kp, deadband = names.index("kp"), names.index("deadband")
    assert rig.ask("fmcb.param_get", {"index": kp})["value"] == struct.pack("<f", 1.0)
    assert rig.ask("fmcb.param_get", {"index": deadband})["value"] == struct.pack("<I", 2)
    rig.ask("fmcb.param_set", {"index": kp, "value": struct.pack("<f", 2.5)})
    rig.ask("fmcb.param_set", {"index": deadband, "value": struct.pack("<I", 20)})
    assert rig.app.params["kp"] == 2.5
    assert rig.hal.flash.writes == []
    rig.ask("fmcb.param_commit", run_ms=3)  # replies when the page is programmed
    assert rig.hal.flash.writes == [PARAM_PAGE]
    rig.ask("fmcb.param_set", {"index": kp, "value": struct.pack("<f", 9.0)})
    rig.ask("fmcb.param_reload")
    assert rig.app.params["kp"] == 2.5
    rig.ask("fmcb.param_defaults")
    assert rig.app.params["kp"] == 1.0 and rig.app.params["deadband"] == 2
    # A new application instance on the same flash starts with the committed values.
    again = FmcbApp(rig.hal, None)
    assert again.params_valid and again.params["kp"] == 2.5 and again.params["deadband"] == 20


def test_blank_or_corrupt_param_page_gives_defaults(rig: Rig) -> None:
    assert not rig.app.params_valid and rig.app.params["kp"] == 1.0
    rig.hal.flash.load(page_address(PARAM_PAGE), b"\xef\xbe\xad\xde" + b"\x00" * 252)
    app = FmcbApp(rig.hal, None)
    assert not app.params_valid and app.params["deadband"] == 2


# --- breaker --------------------------------------------------------------------------------
def test_breaker_trips_after_more_than_10_ms(rig: Rig) -> None:
    sw = rig.hal.power("phalange")
    rig.send("fmcb.phalange_power", {"on": 1}, run_ms=1)
    assert sw.state == 2
    sw.load_ma = 300
    rig.run_ms(9)
    sw.load_ma = 100  # a 9 ms spike: no trip
    rig.run_ms(2)
    assert sw.state == 2
    sw.load_ma = 300
    rig.run_ms(10)
    assert sw.state == 2  # 10 ms over, not more
    rig.run_ms(3)
    assert sw.state == 0
    rig.run_ms(5)
    status = CATALOGUE["fmcb.status"].parse_reply(rig.status_bytes())
    assert status["pb_current"] == 0xFFFF
    rig.send("fmcb.phalange_power", {"on": 0}, run_ms=6)
    assert CATALOGUE["fmcb.status"].parse_reply(rig.status_bytes())["pb_current"] == 0xFFFF
    sw.load_ma = 120
    rig.send("fmcb.phalange_power", {"on": 1}, run_ms=6)  # commanded on again: cleared
    assert sw.state == 2
    assert CATALOGUE["fmcb.status"].parse_reply(rig.status_bytes())["pb_current"] == 402  # 0.324 V


# --- tendon bus -----------------------------------------------------------------------------
def f2_reply(taxels: list[int], accel: list[int], mag: list[int]) -> bytes:
    body = CATALOGUE["f2.tactile"].build_reply(taxels=taxels, imu={"accel": accel, "mag": mag})
    return encode_frame(0, 0x10, body)


def f3_reply(taxels: list[int]) -> bytes:
    body = CATALOGUE["f3.tactile"].build_reply(taxels=taxels,
                                               imu={"accel": [0, 0, 1000], "mag": [0, 0, 0]})
    return encode_frame(0, 0x10, body)


def test_autopoll_cadence_without_replies(rig: Rig) -> None:
    rig.send("fmcb.phalange_power", {"on": 1})
    rig.run_ms(20)
    assert rig.tendon.sent == []  # autopoll off
    rig.send("fmcb.autopoll", {"on": 1})
    rig.tendon.take_sent()
    start = rig.sched.now_us()
    rig.run_ms(52)  # polls at +9.5, +19.5, … +49.5 ms, each f3 request ~2 ms after f2's
    chunks = list(rig.tendon.sent)
    frames = [decode_all(c.data)[0] for c in chunks]
    addrs = [(f.address, f.type) for f in frames]
    assert addrs == [(1, 0x10), (2, 0x10)] * 5
    f2_times = [c.start_us - start for c, f in zip(chunks, frames, strict=True) if f.address == 1]
    assert [b - a for a, b in zip(f2_times, f2_times[1:], strict=False)] == [10_000] * 4
    # Half duplex: f3 is asked only after f2's reply timeout (2 ms).
    assert chunks[1].start_us - chunks[0].start_us >= 2_000
    assert rig.app.tendon_counters.timeouts == 9  # the last f3 request is still waiting


def test_autopoll_replies_reach_the_status(rig: Rig) -> None:
    rig.send("fmcb.phalange_power", {"on": 1})
    rig.send("fmcb.autopoll", {"on": 1})
    rig.tendon.take_sent()
    rig.sched.run_until(rig.sched.now_us() // 10_000 * 10_000 + 10_000)  # the next poll
    frames = rig.tendon_frames()
    assert [(f.address, f.type) for f in frames] == [(1, 0x10)]
    rig.run_ms(0.2)
    rig.tendon.deliver(f2_reply([11, 12, 13, 14, 15, 16], [1, 2, 3], [-4, 5, -6]))
    rig.run_ms(0.1)
    t_f2 = rig.sched.now_us()
    frames = rig.tendon_frames()
    assert [(f.address, f.type) for f in frames] == [(2, 0x10)]  # f3 asked at once
    rig.tendon.deliver(f3_reply(list(range(100, 112))))
    rig.run_ms(6)
    status = CATALOGUE["fmcb.status"].parse_reply(rig.status_bytes())
    assert status["pp_tactile"] == [11, 12, 13, 14, 15, 16]
    assert status["pp_imu"] == [1, 2, 3, -4, 5, -6]
    assert status["dp_tactile"] == list(range(100, 112))
    assert status["dp_imu"] == [0, 0, 1000, 0, 0, 0]
    assert 0 < t_f2 - status["pp_time"] <= 200 and status["dp_time"] >= status["pp_time"]
    assert rig.app.tendon_counters.replies == 2


def test_autopoll_slow_polls_fill_strain_and_temperatures(rig: Rig) -> None:
    rig.send("fmcb.phalange_power", {"on": 1})
    rig.send("fmcb.autopoll", {"on": 1})
    answers = {
        (1, 0x10): CATALOGUE["f2.tactile"].reply_frame(
            taxels=[1] * 6, imu={"accel": [0] * 3, "mag": [0] * 3}),
        (2, 0x10): f3_reply([2] * 12),
        (1, 0x13): CATALOGUE["f2.strain"].reply_frame(strain=-12345),
        (2, 0x22): CATALOGUE["f3.temperatures"].reply_frame(temp=[2000, 2001, 2002, 2003]),
    }
    for _ in range(1010):  # a phalange pair answering every request 100 µs later
        for f in rig.tendon_frames():
            rig.tendon.deliver(answers[(f.address, f.type)])
        rig.run_ms(1)
    status = CATALOGUE["fmcb.status"].parse_reply(rig.status_bytes())
    assert status["pp_strain"] == -12345 and status["dp_temp"] == [2000, 2001, 2002, 2003]
    assert rig.app.tendon_counters.timeouts == 0


def test_tunnel_returns_bytes_heard_and_pauses_autopoll(rig: Rig) -> None:
    rig.send("fmcb.phalange_power", {"on": 1})
    rig.send("fmcb.autopoll", {"on": 1})
    rig.run_ms(25)  # some polls time out meanwhile
    rig.tendon.take_sent()
    raw = encode_frame(1, 0x0C)  # e.g. "halt autoboot" to f2's bootloader
    rig.send("fmcb.tunnel", {"max_ms": 30, "data": raw}, run_ms=0)
    rig.run_ms(3)  # any request in flight has finished; the tunnel's bytes went out
    sent = b"".join(rig.tendon.take_sent())
    assert sent.endswith(raw)
    rig.tendon.deliver(b"\x42\x00\x00")
    rig.run_ms(5)
    rig.tendon.deliver(b"\x00\x0c\xab\xcd")
    rig.run_ms(20)
    assert rig.tendon.take_sent() == []  # autopoll paused during the tunnel
    assert rig.pogo.sent == []
    rig.run_ms(5)
    rig.tendon.deliver(b"late")  # after max_ms: not part of the reply
    frames = decode_all(b"".join(rig.pogo.take_sent()))
    assert len(frames) == 1
    reply = CATALOGUE["fmcb.tunnel"].parse_reply(frames[0].payload)
    assert reply["data"] == b"\x42\x00\x00\x00\x0c\xab\xcd"
    rig.run_ms(20)
    assert any(f.address == 1 for f in rig.tendon_frames())  # autopoll resumed


def test_overlapping_tunnels_are_queued_and_answered_in_order(rig: Rig) -> None:
    """The original host may send a second relay request before the first is answered:
    the fmcb answers both, each with the bytes heard during its own turn on the bus."""
    rig.send("fmcb.phalange_power", {"on": 1})
    first, second = encode_frame(1, 0x01), encode_frame(2, 0x01)
    rig.send("fmcb.tunnel", {"max_ms": 10, "data": first}, run_ms=0)
    rig.send("fmcb.tunnel", {"max_ms": 10, "data": second}, run_ms=0)
    rig.run_ms(2)
    assert b"".join(rig.tendon.take_sent()) == first  # one at a time on the bus
    rig.tendon.deliver(b"one")
    rig.run_ms(10)
    assert b"".join(rig.tendon.take_sent()) == second  # the second's turn
    rig.tendon.deliver(b"two")
    rig.run_ms(12)
    frames = decode_all(b"".join(rig.pogo.take_sent()))
    heard = [CATALOGUE["fmcb.tunnel"].parse_reply(f.payload)["data"] for f in frames]
    assert heard == [b"one", b"two"]


def test_a_tunnel_ends_as_soon_as_a_reply_to_the_host_is_heard(rig: Rig) -> None:
    rig.send("fmcb.phalange_power", {"on": 1})
    rig.send("fmcb.tunnel", {"max_ms": 30, "data": encode_frame(1, 0x01)}, run_ms=0)
    rig.run_ms(1)
    rig.tendon.take_sent()
    pong = encode_frame(0, 0x01)
    rig.tendon.deliver(b"\x00\x13")  # noise first: not a frame to the host
    rig.tendon.deliver(pong)
    rig.run_ms(1)  # far less than max_ms
    frames = decode_all(b"".join(rig.pogo.take_sent()))
    assert [CATALOGUE["fmcb.tunnel"].parse_reply(f.payload)["data"] for f in frames] == [
        b"\x00\x13" + pong]


def test_a_tunnel_queue_overflow_is_refused_not_reordered(rig: Rig) -> None:
    rig.send("fmcb.phalange_power", {"on": 1})
    for k in range(TUNNEL_QUEUE + 3):
        rig.send("fmcb.tunnel", {"max_ms": 1, "data": bytes([k])}, run_ms=0)
    rig.run_ms(50)
    frames = decode_all(b"".join(rig.pogo.take_sent()))
    assert len(frames) == TUNNEL_QUEUE + 1  # the one on the bus and the queue
    assert rig.app.tendon_counters.tunnels == TUNNEL_QUEUE + 1


# --- booted by the Mcu ----------------------------------------------------------------------
class _BootStub:
    """Stands in for the bootloader: boots the installed application at once."""

    def __init__(self, hal: Any, mcu: Mcu) -> None:
        self.mcu = mcu

    def start(self) -> None:
        self.mcu.boot("fmcb")


def test_make_node_boots_fmcb_app_and_it_answers_on_pogo() -> None:
    sched = Scheduler()
    node = make_node(sched, BoardType.FMCB, bootloader=_BootStub)
    node.power_on()
    assert isinstance(node.program, FmcbApp)
    assert isinstance(node.hal, VirtualHal)
    pogo = node.hal.uart("pogo")
    pogo.deliver(encode_frame(10, 0x21))
    pogo.deliver(encode_frame(3, 0x21))  # another address: ignored
    sched.run_for(1_000)
    frames = decode_all(b"".join(pogo.take_sent()))
    assert len(frames) == 1 and len(frames[0].payload) == 148


@settings(max_examples=50, deadline=None)
@given(st.sampled_from(["f2.tactile", "f3.tactile"]), st.data())
def test_a_tactile_reply_fits_the_status_fields_it_is_copied_into(name: str,
                                                                  data: st.DataObject) -> None:
    """The fmcb copies a phalange's taxels and IMU counts into its status unclamped: any
    reply the catalogue parses must hold values its status fields can carry."""
    message = CATALOGUE[name]
    assert message.reply is not None
    size = message.reply.sizeof()
    fields = message.parse_reply(data.draw(st.binary(min_size=size, max_size=size)))
    status = CATALOGUE["fmcb.status"]
    assert status.reply is not None
    prefix = "pp" if name.startswith("f2.") else "dp"
    zeros = status.parse_reply(bytes(status.reply.sizeof()))
    assert len(fields["taxels"]) == len(zeros[f"{prefix}_tactile"])
    assert all(0 <= v <= 0xFFFF for v in fields["taxels"])
    imu = [*fields["imu"]["accel"], *fields["imu"]["mag"]]
    assert len(imu) == 6 and all(-0x8000 <= v <= 0x7FFF for v in imu)
