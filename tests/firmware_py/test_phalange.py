"""The phalange applications f2 and f3 on the tendon bus, through the virtual HAL."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_py.hal import Hal
from firmware_py.mcu import Mcu
from firmware_py.phalange import (
    ADC_SAMPLES,
    HOLD_UP_US,
    TURNAROUND_US,
    F2App,
    F3App,
    PowerMonitor,
    supply_interrupted,
)
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import APP_PROGRAMS, load_program, make_hal, make_node
from firmware_py.sim.virtual_hal import VirtualHal
from firmware_py.sim.virtual_sensors import VirtualSensors
from protocol.framing import Frame, encode_frame
from protocol.image import BoardType
from protocol.messages import CATALOGUE
from protocol.stream import decode_all
from protocol.topology import ADDR_BROADCAST

F2_ADDR, F3_ADDR = 1, 2
BOARDS: dict[str, tuple[BoardType, type[F2App | F3App], int, int]] = {"f2": (BoardType.F2, F2App, F2_ADDR, 6), "f3": (BoardType.F3, F3App, F3_ADDR, 12)}


def make_app(kind: str) -> tuple[Scheduler, VirtualHal, F2App | F3App]:
    board, cls, _addr, _n = BOARDS[kind]
    scheduler = Scheduler()
    hal = make_hal(scheduler, board)
    app = cls(hal, None)
    app.start()
    return scheduler, hal, app


def sensors(hal: VirtualHal) -> VirtualSensors:
    """The board's sensor values, as the test sets them."""
    assert isinstance(hal.sensors, VirtualSensors)
    return hal.sensors


def send(hal: VirtualHal, address: int, name: str, payload: bytes | None = None,
         **fields: Any) -> None:
    msg = CATALOGUE[name]
    body = payload if payload is not None else msg.build_request(fields)
    hal.uart("tendon").deliver(encode_frame(address, msg.type_id, body))


def replies(scheduler: Scheduler, hal: VirtualHal, run_us: int = 500) -> list[Frame]:
    scheduler.run_for(run_us)
    return decode_all(b"".join(hal.uart("tendon").take_sent()))


def ask(scheduler: Scheduler, hal: VirtualHal, address: int, name: str,
        **fields: Any) -> dict[str, Any]:
    send(hal, address, name, **fields)
    frames = replies(scheduler, hal)
    assert len(frames) == 1
    assert frames[0].address == 0 and frames[0].type == CATALOGUE[name].type_id
    return CATALOGUE[name].parse_reply(frames[0].payload)


# --- addressing -------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["f2", "f3"])
def test_ping_answered_only_at_own_address(kind: str) -> None:
    scheduler, hal, app = make_app(kind)
    own = BOARDS[kind][2]
    other = F3_ADDR if own == F2_ADDR else F2_ADDR
    assert app.address == own
    send(hal, other, "ping")
    assert replies(scheduler, hal) == []
    assert app.counters.not_for_me == 1
    send(hal, own, "ping")
    frames = replies(scheduler, hal)
    assert [(f.address, f.type, f.payload) for f in frames] == [(0, 0x01, b"")]


@pytest.mark.parametrize("kind", ["f2", "f3"])
def test_broadcast_is_handled_but_never_answered(kind: str) -> None:
    scheduler, hal, app = make_app(kind)
    send(hal, ADDR_BROADCAST, f"{kind}.imu_power", on=0)
    send(hal, ADDR_BROADCAST, f"{kind}.tactile")
    assert replies(scheduler, hal) == []
    assert app.imu_powered is False  # the broadcast command was obeyed


def test_reply_starts_after_turnaround() -> None:
    scheduler, hal, _app = make_app("f2")
    scheduler.run_for(1234)
    t_request = scheduler.now_us()
    send(hal, F2_ADDR, "ping")
    scheduler.run_for(TURNAROUND_US - 1)
    assert hal.uart("tendon").sent == []  # still the master's turn
    scheduler.run_for(200)
    sent = hal.uart("tendon").sent
    assert len(sent) == 1
    assert sent[0].start_us - t_request >= TURNAROUND_US


@pytest.mark.parametrize("kind", ["f2", "f3"])
def test_bad_payload_length_is_dropped(kind: str) -> None:
    scheduler, hal, app = make_app(kind)
    send(hal, BOARDS[kind][2], f"{kind}.tactile", payload=b"\x00")
    send(hal, BOARDS[kind][2], f"{kind}.imu_power", payload=b"\x00\x00")
    assert replies(scheduler, hal) == []
    assert app.counters.bad_payload == 2
    assert app.imu_powered is True  # the malformed imu_power was not acted on


def test_app_is_registered_for_the_boards() -> None:
    scheduler = Scheduler()
    for kind, cls in (("f2", F2App), ("f3", F3App)):
        hal = make_hal(scheduler, BOARDS[kind][0])
        assert isinstance(load_program(APP_PROGRAMS[kind])(hal, None), cls)  # type: ignore[arg-type]


# --- tactile ----------------------------------------------------------------------------
def test_f2_tactile_golden_bytes_after_one_scan() -> None:
    scheduler, hal, _app = make_app("f2")
    values = sensors(hal).values
    for i, v in enumerate([0x0102, 0x0304, 2000, 0, 70_000, 0x1234]):
        values[f"taxel{i}"] = v
    values["accel"] = (1, -2, 1000)
    values["mag"] = (-300, 5, 0x1234)
    scheduler.run_until(10_000)  # a scan completes every 6 ms; the IMU samples at 10 ms
    send(hal, F2_ADDR, "f2.tactile")
    scheduler.run_for(500)
    raw = b"".join(hal.uart("tendon").take_sent())
    payload = bytes.fromhex(
        "0201" "0403" "d007" "0000" "ffff" "3412"  # taxels, u16 LE (70 000 clamped to 0xFFFF)
        "0100" "feff" "e803"  # accel 1, -2, 1000 (i16 LE)
        "d4fe" "0500" "3412"  # mag -300, 5, 0x1234
    )
    assert len(payload) == 24
    assert raw[:5] == bytes.fromhex("42" "00" "1800" "10")  # sync, to host, length 24, type
    assert raw[5:-2] == payload
    assert len(raw) == 5 + 24 + 2
    (frame,) = decode_all(raw)  # CRC checked by the decoder
    assert frame.payload == payload


def test_f3_tactile_after_twelve_ms() -> None:
    scheduler, hal, _app = make_app("f3")
    for i in range(12):
        sensors(hal).values[f"taxel{i}"] = 100 + i
    scheduler.run_until(11_500)
    early = ask(scheduler, hal, F3_ADDR, "f3.tactile")
    assert early["taxels"] == [0] * 12  # no scan complete yet
    scheduler.run_until(12_000)
    send(hal, F3_ADDR, "f3.tactile")
    (frame,) = replies(scheduler, hal)
    assert len(frame.payload) == 12 * 2 + 12
    reply = CATALOGUE["f3.tactile"].parse_reply(frame.payload)
    assert reply["taxels"] == [100 + i for i in range(12)]
    assert reply["imu"] == {"accel": [0, 0, 1000], "mag": [0, 0, 0]}


class UnannouncedSensors(VirtualSensors):
    """Sensors that do not announce changes (real hardware): the scan reads each taxel in
    its own millisecond, one timer per taxel."""

    def watch_series(self, prefix: str, before_change: Any) -> bool:
        return False


def make_app_on(kind: str, announced: bool) -> tuple[Scheduler, VirtualHal, F2App | F3App]:
    board, cls, _addr, _n = BOARDS[kind]
    scheduler = Scheduler()
    hal = make_hal(scheduler, board)
    if not announced:
        hal.sensors = UnannouncedSensors(dict(hal.sensors.values))
    app = cls(hal, None)
    app.start()
    return scheduler, hal, app


@pytest.mark.parametrize("announced", [True, False], ids=["one timer a scan", "a taxel a ms"])
def test_published_taxels_change_only_when_a_scan_completes(announced: bool) -> None:
    scheduler, hal, app = make_app_on("f2", announced)
    pad = sensors(hal)
    pad.set_taxels([1000] * 6)
    assert scheduler.run_until(6_000) == (1 if announced else 6)  # callbacks run
    assert app.scans == 1
    # Second scan reads taxel0 at 7 ms and taxel1 at 8 ms; the pad changes in between.
    scheduler.run_until(8_500)
    pad.set_taxels([3000] * 6)
    scheduler.run_until(11_900)
    assert ask(scheduler, hal, F2_ADDR, "f2.tactile")["taxels"] == [1000] * 6
    scheduler.run_until(12_000)
    assert app.scans == 2
    mixed = ask(scheduler, hal, F2_ADDR, "f2.tactile")["taxels"]
    assert mixed == [1000, 1000, 3000, 3000, 3000, 3000]  # each taxel as read in its ms
    scheduler.run_until(18_000)
    assert ask(scheduler, hal, F2_ADDR, "f2.tactile")["taxels"] == [3000] * 6


class CountingSensors(VirtualSensors):
    """Sensors whose taxel reads alternate between two values and are counted."""

    def __init__(self, base: VirtualSensors) -> None:
        super().__init__(dict(base.values))
        self.reads: dict[str, int] = {}

    def read(self, channel: str) -> int | tuple[int, ...]:
        n = self.reads.get(channel, 0)
        self.reads[channel] = n + 1
        if channel.startswith("taxel"):
            return 100 + (n % 2) * 3  # 100, 103, 100, 103, …
        return super().read(channel)


def test_each_taxel_averages_ten_adc_reads() -> None:
    scheduler, hal, app = make_app("f2")
    counting = CountingSensors(sensors(hal))
    hal.sensors = counting
    scheduler.run_until(6_000)
    assert all(counting.reads[f"taxel{i}"] == ADC_SAMPLES for i in range(6))
    assert app.taxels == (102,) * 6  # mean 101.5 rounds to 102


# --- strain, temperatures ---------------------------------------------------------------
@pytest.mark.parametrize(
    ("raw", "expected"),
    [(-1234, -1234), (0, 0), ((1 << 23) + 5, (1 << 23) - 1), (-(1 << 23) - 7, -(1 << 23)),
     ((1 << 23) - 1, (1 << 23) - 1)],
)
def test_f2_strain_is_signed_and_clamped_to_24_bits(raw: int, expected: int) -> None:
    scheduler, hal, _app = make_app("f2")
    sensors(hal).values["strain"] = raw
    send(hal, F2_ADDR, "f2.strain")
    (frame,) = replies(scheduler, hal)
    assert frame.payload == expected.to_bytes(4, "little", signed=True)


def test_f3_has_no_strain_gauge() -> None:
    scheduler, hal, app = make_app("f3")
    hal.uart("tendon").deliver(encode_frame(F3_ADDR, CATALOGUE["f2.strain"].type_id, b""))
    assert replies(scheduler, hal) == []
    assert app.counters.unknown_type == 1


def test_f3_thermistors_and_f2_zeros() -> None:
    scheduler, hal, _app = make_app("f3")
    for i, v in enumerate([1000, 2048, 70_000, 5]):
        sensors(hal).values[f"thermistor{i}"] = v
    assert ask(scheduler, hal, F3_ADDR, "f3.temperatures")["temp"] == [1000, 2048, 0xFFFF, 5]
    scheduler, hal, _app = make_app("f2")
    for i in range(4):
        sensors(hal).values[f"thermistor{i}"] = 1234  # the channel exists, the board does not
    assert ask(scheduler, hal, F2_ADDR, "f2.temperatures")["temp"] == [0, 0, 0, 0]


# --- IMU --------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["f2", "f3"])
def test_imu_sampled_at_100_hz_while_powered(kind: str) -> None:
    scheduler, hal, _app = make_app(kind)
    addr = BOARDS[kind][2]
    sensors(hal).values["accel"] = (10, -20, 990)
    sensors(hal).values["mag"] = (40_000, -40_000, 7)  # clamped to i16
    assert ask(scheduler, hal, addr, f"{kind}.imu")["accel"] == [0, 0, 1000]  # boot sample
    scheduler.run_until(10_000)
    imu = ask(scheduler, hal, addr, f"{kind}.imu")
    assert imu == {"accel": [10, -20, 990], "mag": [32767, -32768, 7]}


@pytest.mark.parametrize("kind", ["f2", "f3"])
def test_imu_power_off_reports_zeros(kind: str) -> None:
    scheduler, hal, app = make_app(kind)
    addr = BOARDS[kind][2]
    sensors(hal).values["accel"] = (5, 6, 1001)
    scheduler.run_until(12_000)
    assert ask(scheduler, hal, addr, f"{kind}.imu")["accel"] == [5, 6, 1001]
    assert ask(scheduler, hal, addr, f"{kind}.imu_power", on=0) == {}
    assert app.imu_powered is False
    zeros = {"accel": [0, 0, 0], "mag": [0, 0, 0]}
    scheduler.run_for(25_000)  # sampling ticks pass: the chip stays unpowered
    assert ask(scheduler, hal, addr, f"{kind}.imu") == zeros
    assert ask(scheduler, hal, addr, f"{kind}.tactile")["imu"] == zeros
    # Power on again (only bit 0 counts): zeros until the next 100 Hz sample.
    ask(scheduler, hal, addr, f"{kind}.imu_power", on=0xFF)
    assert ask(scheduler, hal, addr, f"{kind}.imu") == zeros
    scheduler.run_for(10_000)
    assert ask(scheduler, hal, addr, f"{kind}.imu")["accel"] == [5, 6, 1001]


# --- power glitches ---------------------------------------------------------------------
class BootAtOnce:
    """Bootloader stand-in: jumps to the application immediately."""

    def __init__(self, hal: Hal, mcu: Mcu, app: str) -> None:
        self.mcu, self.app = mcu, app

    def start(self) -> None:
        self.mcu.boot(self.app)


def make_mcu(kind: str) -> tuple[Scheduler, VirtualHal, Mcu]:
    board, cls, _addr, _n = BOARDS[kind]
    scheduler = Scheduler()
    hal = make_hal(scheduler, board)
    mcu = Mcu(hal, lambda h, m: BootAtOnce(h, m, kind), {kind: cls})
    mcu.power_on()
    return scheduler, hal, mcu


def uptime(scheduler: Scheduler, hal: VirtualHal, address: int) -> int:
    send(hal, address, "identify")
    (frame,) = replies(scheduler, hal, 200)
    return int(CATALOGUE["identify"].parse_reply(frame.payload)["uptime_us"])


@pytest.mark.parametrize("kind", ["f2", "f3"])
def test_short_glitch_rides_through_long_glitch_reboots(kind: str) -> None:
    scheduler, hal, mcu = make_mcu(kind)
    addr = BOARDS[kind][2]
    app = mcu.program
    scheduler.run_until(50_000)
    assert supply_interrupted(mcu, HOLD_UP_US - 500) is False
    assert supply_interrupted(mcu, HOLD_UP_US) is False
    assert mcu.program is app
    assert uptime(scheduler, hal, addr) >= 50_000
    scheduler.run_until(80_000)
    assert supply_interrupted(mcu, HOLD_UP_US + 1) is True
    assert mcu.program is not app and isinstance(mcu.program, BOARDS[kind][1])
    assert uptime(scheduler, hal, addr) < 1_000  # restarted from zero, and answering


def test_power_monitor_browns_out_after_hold_up() -> None:
    scheduler, hal, mcu = make_mcu("f2")
    monitor = PowerMonitor(mcu, scheduler.call_later)
    scheduler.run_until(20_000)
    app = mcu.program
    # Short loss: the node keeps running through it.
    monitor.supply_lost()
    scheduler.run_for(HOLD_UP_US - 100)
    monitor.supply_restored()
    scheduler.run_for(1_000)
    assert mcu.powered and mcu.program is app and monitor.brownouts == 0
    assert uptime(scheduler, hal, F2_ADDR) > 20_000
    # Long loss: silent while browned out, fresh boot when the supply returns.
    monitor.supply_lost()
    scheduler.run_for(HOLD_UP_US + 100)
    assert monitor.browned_out and not mcu.powered
    send(hal, F2_ADDR, "ping")
    assert replies(scheduler, hal) == []
    scheduler.run_for(5_000)
    monitor.supply_restored()
    assert mcu.powered and mcu.program is not app and monitor.brownouts == 1
    assert uptime(scheduler, hal, F2_ADDR) < 1_000
    scheduler.run_for(6_000)
    assert mcu.program is not None
    assert ask(scheduler, hal, F2_ADDR, "f2.tactile")["taxels"] == [2000] * 6


@pytest.mark.parametrize("kind", ["f2", "f3"])
def test_boots_from_its_image_through_the_bootloader(kind: str) -> None:
    board, cls, addr, n = BOARDS[kind]
    scheduler = Scheduler()
    mcu = make_node(scheduler, board)
    mcu.power_on()
    for _ in range(100):  # the autoboot window is a few seconds
        if mcu.program_name == kind:
            break
        scheduler.run_for(100_000)
    assert isinstance(mcu.program, cls)
    hal = mcu.hal
    assert isinstance(hal, VirtualHal)
    hal.uart("tendon").take_sent()
    scheduler.run_for(n * 1_000)
    assert ask(scheduler, hal, addr, f"{kind}.tactile")["taxels"] == [2000] * n


@settings(max_examples=60, deadline=None)
@given(st.sampled_from(["f2", "f3"]),
       st.lists(st.tuples(st.one_of(st.integers(1, 4_000),  # on, or just off, a taxel's µs
                                    st.integers(1, 4).map(lambda ms: 1_000 * ms - 1),
                                    st.integers(1, 4).map(lambda ms: 1_000 * ms + 1)),
                          st.integers(0, 70_000)), max_size=30))
def test_one_timer_a_scan_reads_what_a_taxel_a_ms_reads(
        kind: str, changes: list[tuple[int, int]]) -> None:
    """The pad changes at random instants (often mid-scan, sometimes on a taxel's very
    microsecond): both scans publish the same taxels at the same times."""
    runs = [make_app_on(kind, announced) for announced in (True, False)]
    published: list[list[tuple[int, tuple[int, ...]]]] = [[], []]
    n = BOARDS[kind][3]
    for k, (gap_us, base) in enumerate(changes):
        for (scheduler, hal, app), seen in zip(runs, published, strict=True):
            scheduler.run_for(gap_us)
            sensors(hal).set_taxels([(base + 97 * i * k) % 70_000 for i in range(n)])
            seen.append((app.scans, app.taxels))
    for (scheduler, _hal, app), seen in zip(runs, published, strict=True):
        scheduler.run_for(30_000)
        seen.append((app.scans, app.taxels))
    assert published[0] == published[1]
