"""``armctl excite`` and ``handctl excite``: documented excitations, every motion through the
gate, recorded to MCAP, and replayed exactly against the emulator that answered them."""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hil_emulator.inprocess import forget_shared_emulators
from host.arm.excite import SPEED_SHARE, Excitation, excitation_path
from host.arm.gate import MOVE_SPEED_LIMITS, check_path, path_rates
from host.errors import UsageError
from host.hand.excite import CLOSURES, FingerExcitation, moves
from protocol.robot import ARM_JOINT_ACCEL_LIMITS, ARM_JOINT_LIMITS
from tools.cli import armctl, handctl
from tools.cli.mcap_capture import read_recording
from tools.hil_bench.replay.session import replay

ARM_URL = "emu://arm/arm?seed=2&name=test-excite"
HAND_URL = "emu://hand/palm?seed=2&name=test-excite"


def _armctl(*args: str) -> tuple[int, str]:
    out = io.StringIO()
    return armctl.main(["--port", ARM_URL, *args], out=out), out.getvalue()


@pytest.fixture(scope="module")
def arm_excite(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    path = tmp_path_factory.mktemp("excite") / "arm-excite.mcap"
    forget_shared_emulators()
    try:
        assert _armctl("torque", "on")[0] == 0
        assert _armctl("home")[0] == 0
        code, text = _armctl("--json", "excite", str(path), "--joints", "J2,J6",
                             "--chirp-seconds", "2", "--hold-seconds", "0.3",
                             "--ramps", "J4", "--ramp-rad", "0.05", "--probes", "J4",
                             "--probe-seconds", "1.5")
        assert code == 0, text
    finally:
        forget_shared_emulators()
    return path, json.loads(text)


def test_armctl_excite_chirps_the_joints_asked_and_records_it(
        arm_excite: tuple[Path, dict]) -> None:
    path, summary = arm_excite
    assert summary["excited"] == ["J2", "J6"] and summary["duration_s"] > 4.0
    assert not summary["errors"]  # no alarm latched on the way
    states = [json.loads(m.data) for m in read_recording(path).messages
              if m.channel == "/arm/state"]
    j2 = [s["joints"][1] for s in states]
    j1 = [s["joints"][0] for s in states]
    assert max(j2) - min(j2) > 0.3  # the chirp and the holds moved the shoulder
    assert max(j1) - min(j1) < 0.02  # a joint not chirped stayed where it was
    assert summary["ramped"] == ["J4"]


def test_the_holding_probe_lowers_the_current_until_the_rotor_slips_and_stops_there(
        arm_excite: tuple[Path, dict]) -> None:
    _path, summary = arm_excite
    (probe,) = summary["probes"]
    assert probe["joint"] == "J4" and probe["load_nm"] > 0.5
    # the nominal elbow holds 0.86 N·m/A × 13 at the joint: it lets go where that meets
    # the load, half-way down a ramp from twice the load to half of it
    assert probe["to_ma"] < probe["slipped_ma"] < probe["from_ma"]
    holding = 0.86 * 13 * probe["slipped_ma"] / 1000
    assert abs(holding - probe["load_nm"]) < 0.1 * probe["load_nm"]
    assert not summary["errors"]  # the latch cleared, the current back


@pytest.mark.slow
def test_an_excitation_replays_exactly_against_the_emulator_that_answered(
        arm_excite: tuple[Path, dict]) -> None:
    result = replay(arm_excite[0])
    assert result.within, result.failing
    assert result.recording.duration_s > 4.0


def test_armctl_excite_refuses_an_arm_not_homed_or_without_torque(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    forget_shared_emulators()
    try:
        assert _armctl("excite", str(tmp_path / "a.mcap"))[0] == 2
        assert "not homed" in capsys.readouterr().err
        assert _armctl("excite", str(tmp_path / "b.mcap"), "--unhomed")[0] == 2
        assert "torque" in capsys.readouterr().err
        assert _armctl("excite", str(tmp_path / "c.mcap"), "--joints", "J9")[0] == 2
    finally:
        forget_shared_emulators()
    assert not (tmp_path / "a.mcap").exists() and not (tmp_path / "b.mcap").exists()


_INSIDE = [st.floats(lo + 0.06, hi - 0.06) for lo, hi in ARM_JOINT_LIMITS]


@given(st.tuples(*_INSIDE), st.floats(0.05, 1.0), st.floats(0.3, 3.0))
def test_every_excitation_path_passes_the_gate_within_its_share_of_the_limits(
        start: tuple[float, ...], amplitude: float, f1: float) -> None:
    plan = Excitation(amplitude_rad=amplitude, chirp_s=2.0, f0_hz=0.2, f1_hz=f1, hold_s=0.2,
                      holds=())
    try:
        path = excitation_path(plan, start, homed=True)
    except UsageError as exc:  # a joint at its range's edge: refused, never clamped
        assert "range's edge" in str(exc)
        return
    times = [w.t for w in path]
    points = np.array([w.joints for w in path])
    check_path(times, points, start, homed=True)
    speeds, _accels = path_rates(times, points)
    assert np.all(speeds.max(axis=0) <= np.array(MOVE_SPEED_LIMITS) * SPEED_SHARE * 1.05)
    for j, (lo, hi) in enumerate(ARM_JOINT_LIMITS):
        assert lo < points[:, j].min() and points[:, j].max() < hi
    assert path[-1].joints == pytest.approx(start)
    assert max(ARM_JOINT_ACCEL_LIMITS) > 0 and math.isfinite(times[-1])


def test_the_finger_excitation_closes_each_finger_and_opens_it_again() -> None:
    plan = FingerExcitation(fingers=(0, 2), efforts=(150, 255))
    planned = moves(plan)
    assert len(planned) == 2 * 2 * 2 * len(CLOSURES)
    assert [m[0] for m in planned[:2]] == [0, 0] and planned[-1][0] == 2
    assert all(pose == (0.0, 0.0, 0.0) for _f, _e, pose in planned[1::2])
    with pytest.raises(UsageError):
        FingerExcitation(fingers=(4,))


@pytest.mark.slow
def test_handctl_excite_records_closures_that_replay_exactly(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "hand-excite.mcap"
    forget_shared_emulators()
    try:
        assert handctl.main(["--port", HAND_URL, "--json", "excite", str(path), "--fingers",
                             "1", "--efforts", "255", "--unhomed"]) == 0
    finally:
        forget_shared_emulators()
    summary = json.loads(capsys.readouterr().out)
    assert summary["moves"] == 2 * len(CLOSURES) and summary["unsettled"] == 0
    result = replay(path)
    assert result.within, result.failing
    halls = result.channels["hand.finger1.fmcb.status.hall_pos[1]"].recorded
    assert max(halls) - min(halls) > 100  # the finger closed and opened
