"""``hil-bench experiments``: each of the dissertation's measurements on the emulator, with
its tolerance, so a change that breaks fidelity fails here; and the table, report and exit
code.  The experiments run the emulator in process through the host library (tens of
seconds each: marked slow)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

import tools.experiments.dissertation as bench
from tools.experiments.outcome import Outcome, Row


def values(outcome: Outcome) -> dict[str, float | None]:
    """Each row's value by the start of its quantity."""
    return {r.quantity: r.value for r in outcome.rows}


def assert_rows_pass(outcome: Outcome) -> None:
    failed = [r for r in outcome.rows if r.passed is False]
    assert not failed, "\n" + bench.table(outcome.rows)


# ----------------------------------------------------------------------------- fast


def _fake() -> list[Outcome]:
    return [
        Outcome("a", [Row("payload", "2.0 kg", "2.01 kg", "±10 %", True, value=2.01)]),
        Outcome("b", [Row("coupled mode", "—", "2.4 Hz", "—", None, "single-joint model")]),
        Outcome("steps", [], {"shoulder": {"target": 10.0, "window": 6.0,
                                           "closed": ([0.0, 1.0, 6.0], [0.0, 9.0, 10.0])},
                              "elbow": {"target": 15.0, "window": 3.0,
                                        "open": ([0.0, 3.0], [0.0, 13.0])},
                              "wrist yaw": {"target": 10.0, "window": 0.5,
                                            "closed": ([0.0, 0.5], [0.0, 10.0])}}),
    ]


def test_within_is_relative() -> None:
    assert bench.within(2.19, 2.0) and not bench.within(2.21, 2.0)
    assert bench.within(1.45, 1.5, rel=0.05) and not bench.within(1.4, 1.5, rel=0.05)


def test_table_names_not_comparable_rows_and_their_reason() -> None:
    text = bench.table([r for o in _fake() for r in o.rows])
    lines = text.splitlines()
    assert lines[0].split() == ["quantity", "dissertation", "emulator", "tolerance", "pass"]
    assert "payload" in lines[2] and lines[2].endswith("yes")
    assert lines[3].endswith("n/c")
    assert "coupled mode: single-joint model" in text


@pytest.mark.slow
def test_main_exits_0_only_when_every_row_passes_or_is_not_comparable(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
        tmp_path: Path) -> None:
    fake = _fake()
    monkeypatch.setattr(bench, "EXPERIMENTS", {o.name: (lambda _seed, o=o: o) for o in fake})
    assert bench.main(["--json", "--report", str(tmp_path)]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["passed"] for r in rows] == [True, None]
    report = (tmp_path / "experiments.md").read_text(encoding="utf-8")
    assert "| payload | 2.0 kg | 2.01 kg | ±10 % | yes |" in report
    assert "not comparable: single-joint model" in report
    assert (tmp_path / "steps.png").stat().st_size > 1000 and "![steps.png]" in report
    failing = Outcome("c", [Row("speed", "1.5 m/s", "3.8 m/s", "±10 %", False)])
    monkeypatch.setattr(bench, "EXPERIMENTS", {"c": lambda _seed: failing})
    assert bench.main([]) == 1


def test_ringing_frequency_of_a_decaying_sine() -> None:
    import numpy as np

    t = np.arange(0, 1.5, 0.0015)
    x = 0.3 + 0.05 * np.exp(-t) * np.cos(2 * np.pi * 5.1 * t)
    assert bench._ringing_frequency(t, x) == pytest.approx(5.1, rel=0.01)


# ----------------------------------------------------------------------------- the arm


@pytest.mark.slow
def test_arm_lifts_to_horizontal_without_tripping_its_nodes() -> None:
    assert_rows_pass(bench.lift_unloaded())


@pytest.mark.slow
def test_a_real_stall_still_trips_the_node() -> None:
    assert_rows_pass(bench.stall_still_trips())


@pytest.mark.slow
def test_holding_torque_is_1_6_times_the_moving_maximum() -> None:
    outcome = bench.holding_ratio()
    assert_rows_pass(outcome)
    ratio = values(outcome)["holding / maximum moving torque (§5.3.2)"]
    assert ratio is not None and ratio == pytest.approx(1.6, rel=0.1)


@pytest.mark.slow
def test_payload_is_2_kg_and_the_shoulder_slips_first() -> None:
    outcome = bench.payload()
    assert_rows_pass(outcome)
    (kg,) = [r.value for r in outcome.rows if r.value is not None]
    assert kg == pytest.approx(2.0, rel=0.1)


@pytest.mark.slow
def test_max_speed_is_1_5_m_per_s_at_the_maximum_step_rate() -> None:
    outcome = bench.max_speed()
    assert_rows_pass(outcome)
    (speed,) = [r.value for r in outcome.rows]
    assert speed == pytest.approx(1.5, rel=0.1)


@pytest.mark.slow
def test_base_stepper_commands_0_52_mm_at_the_end_effector() -> None:
    outcome = bench.base_step()
    assert_rows_pass(outcome)
    step, count = (r.value for r in outcome.rows)
    assert step == pytest.approx(0.52, rel=0.1) and count == pytest.approx(0.64, rel=0.1)


@pytest.mark.slow
def test_elbow_rings_at_5_1_hz_with_the_upper_arm_held() -> None:
    outcome = bench.elbow_frequency()
    assert_rows_pass(outcome)
    held = outcome.rows[0].value
    assert held is not None and held == pytest.approx(5.1, rel=0.1)
    assert outcome.rows[1].passed is None and outcome.rows[1].note


@pytest.mark.slow
def test_step_responses_reach_their_targets_within_the_figures_windows() -> None:
    outcome = bench.step_responses()
    assert_rows_pass(outcome)
    assert set(outcome.series) == {"shoulder", "elbow", "wrist yaw"}


@pytest.mark.slow
def test_repeatability_is_nonzero_and_within_3_mm() -> None:
    outcome = bench.repeatability()
    assert_rows_pass(outcome)
    spread = outcome.rows[0].value
    assert spread is not None and 0.0 < spread <= 3.0


# ----------------------------------------------------------------------------- the hand


@pytest.mark.slow
def test_finger_joints_settle_within_half_a_degree() -> None:
    outcome = bench.finger_deadband()
    assert_rows_pass(outcome)
    worst = outcome.rows[0].value
    assert worst is not None and worst <= 0.5 and not math.isnan(worst)


@pytest.mark.slow
def test_a_2_g_coin_is_far_above_the_tactile_noise_floor() -> None:
    outcome = bench.tactile_coin()
    assert_rows_pass(outcome)
    snr = outcome.rows[0].value
    assert snr is not None and snr >= 10.0
