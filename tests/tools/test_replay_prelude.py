"""A recording made over a port starts on a robot an earlier program used (``armctl torque
on``: torque on, return delay 0) without saying so: the replay rebuilds that state from the
recording's own replies before its first message (:mod:`tools.hil_bench.replay.prelude`)."""

from __future__ import annotations

from dataclasses import replace

import pytest

from hil_emulator.inprocess import forget_shared_emulators
from host.arm.facade import Arm
from host.arm.recording import ArmRecorder
from tools.hil_bench.replay import session
from tools.hil_bench.replay.compare import Channel, over_a_port
from tools.hil_bench.replay.exchanges import Exchange
from tools.hil_bench.replay.prelude import first_writes, start_values, writes
from tools.hil_bench.replay.source import Recorded, Timed, load

URL = "emu://arm/arm?seed=0&name=test-replay-prelude"

# WRITE id 2, address 24 (torque_enable), 1: ~(02+04+03+18+01) = ~0x22 = DD
WRITE_2_TORQUE_ON = bytes.fromhex("FFFF0204031801DD")
# SYNC_WRITE at 28, 4 bytes, id 1 -> 10 00 00 00, id 3 -> 20 00 00 00:
# ~(FE+0E+83+1C+04+01+10+00+00+00+03+20+00+00+00) = ~0x1E3 -> ~0xE3 = 1C
SYNC_GOALS_1_3 = bytes.fromhex("FFFFFE0E831C04" "0110000000" "0320000000" "1C")


def test_the_host_s_writes_are_found_byte_by_byte_with_their_first_time() -> None:
    found = first_writes([Timed(1.0, WRITE_2_TORQUE_ON), Timed(2.0, SYNC_GOALS_1_3),
                          Timed(3.0, WRITE_2_TORQUE_ON)])
    assert found == {(2, 24): 1.0, **{(1, a): 2.0 for a in range(28, 32)},
                     **{(3, a): 2.0 for a in range(28, 32)}}


def test_a_register_is_taken_from_the_first_reply_before_the_host_wrote_it() -> None:
    shown = {"torque_enable": 1.0, "return_delay_time": 0.0, "present_position": 7.0,
             "id": 2.0}
    recorded = [Exchange(("read",), 0.5, "arm.J2", shown, 0.5005),
                Exchange(("read",), 1.5, "arm.J2", {**shown, "return_delay_time": 9.0}, 1.5005),
                Exchange(("read",), 1.6, "arm.J5", {"torque_enable": 0.0}, 1.6005)]
    # the host wrote J2's torque at 1.0: only the reply before says what it found
    values = start_values(recorded, [Timed(1.0, WRITE_2_TORQUE_ON)])
    assert values == {2: {"torque_enable": 1, "return_delay_time": 0}, 5: {"torque_enable": 0}}
    # a reply after the write says nothing of the start
    assert start_values(recorded[1:], [Timed(1.0, WRITE_2_TORQUE_ON)]) == {
        2: {"return_delay_time": 9}, 5: {"torque_enable": 0}}
    # written where they differ from what the node holds, torque last
    holds = {(2, "torque_enable"): 0, (2, "return_delay_time"): 250, (5, "torque_enable"): 0}
    planned = writes(values, lambda i, n: holds[(i, n)])
    assert [what for what, _ in planned] == ["J2 return_delay_time=0", "J2 torque_enable=1"]
    assert planned[1][1].encode() == WRITE_2_TORQUE_ON
    assert planned[0][1].encode() == bytes.fromhex("FFFF02040305" "00" "F1")  # ~0x0E


def _as_over_a_port(recording: Recorded) -> Recorded:
    """What the same session looks like recorded on a serial port: its clock not the
    emulator's, nothing known of the link's use before."""
    return replace(recording, emulated=False,
                   links={k: replace(v, earlier=[]) for k, v in recording.links.items()})


@pytest.fixture(scope="module")
def found_powered(tmp_path_factory: pytest.TempPathFactory) -> Recorded:
    """A session recorded after an earlier program turned the arm's torque on (and left the
    nodes' return delay at 0, as every Arm does), as if made over a port."""
    path = tmp_path_factory.mktemp("prelude") / "arm.mcap"
    forget_shared_emulators()
    try:
        with Arm.open(URL) as earlier:
            earlier.torque(True)
        with Arm.open(URL) as arm, ArmRecorder(arm, path):
            for _ in range(40):
                arm.cycle()
                arm.transport.sleep(0.01)
    finally:
        forget_shared_emulators()
    return _as_over_a_port(load(path))


def _replayed(recording: Recorded) -> dict[str, Channel]:
    emulator = session.build_emulator(recording)
    try:
        channels, _ = session.replay_channels(recording, emulator)
    finally:
        emulator.close()
    return over_a_port(channels, [])[0]


def test_a_port_recording_that_found_the_arm_powered_replays_from_that_state(
        found_powered: Recorded) -> None:
    emulator = session.build_emulator(found_powered)
    try:
        planned = [what for what, _ in session.start_writes(
            found_powered, session.recorded_exchanges(found_powered), emulator)]
    finally:
        emulator.close()
    names = ["J1", "J2", "J3", "J4", "J5", "J6", "J7"]
    # every node's return delay; the steppers' torque (the emulated servos power up with
    # theirs on already); nothing else, torque after the delay
    assert {f"{j} return_delay_time=0" for j in names} | {
        f"{j} torque_enable=1" for j in names[:4]} <= set(planned)
    assert set(planned) <= {f"{j} {r}" for j in names
                            for r in ("return_delay_time=0", "torque_enable=1")}
    assert planned.index("J2 return_delay_time=0") < planned.index("J2 torque_enable=1")
    channels = _replayed(found_powered)
    parted = sorted(n for n, c in channels.items() if not c.within
                    and n.rsplit(".", 1)[-1] in ("replied", "torque_enable", "status_flags"))
    assert parted == []
    assert not any(n.endswith(".reply_us") for n in channels)  # a port's latency: not compared


def test_without_the_rebuilt_state_the_same_replay_parts_at_its_first_exchanges(
        found_powered: Recorded, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(session, "start_writes", lambda *args: [])
    channels = _replayed(found_powered)
    parted = {n.rsplit(".", 1)[-1] for n, c in channels.items() if not c.within}
    # the first PING's reply, 0.5 ms late, collides with the next request: replies lost
    assert "replied" in parted, parted


def test_a_board_clock_over_a_port_compares_from_its_first_sample() -> None:
    clock = Channel("hand.finger1.fmcb.status.fmcb_time", 0.0, [0.0, 1.0],
                    [23_000_000.0, 23_010_000.0], [1_000_000.0, 1_010_000.0])
    latency = Channel("arm.J1.reply_us", 0.0, [0.0], [300.0], [160.0])
    out, notes = over_a_port({clock.name: clock, latency.name: latency}, [])
    assert list(out) == [clock.name] and out[clock.name].within and len(notes) == 2
    kept, _ = over_a_port({clock.name: clock, latency.name: latency}, [("reply_us", 200.0)])
    assert latency.name in kept  # asked for: compared
