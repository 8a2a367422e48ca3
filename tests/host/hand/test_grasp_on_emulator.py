"""Grasps end to end on the emulated hand (the ``hand`` stand, palm up, an object on the
palm), in process on the simulation clock.  Ground truth: the plant's joint angles.

Fingers 0-2 stand with J0 vertical and cannot be homed from their accelerometers, so the
grasps here run ``unhomed``; refusal before homing is checked separately.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from host.errors import NotHomedError, UsageError
from host.hand.facade import Hand
from host.hand.grasp import SQUEEZE_ROUNDS, squeeze
from host.hand.synergies import synergy_targets
from tests.ground_truth import emulator_of, finger_joints
from tools.cli.handctl import main

URL = "emu://hand/palm?name=grasp-tests"


def test_a_grasp_is_refused_before_homing(hand: Hand) -> None:
    before = finger_joints(hand)
    with pytest.raises(NotHomedError, match=r"not homed"):
        hand.grasp("cylindrical", 0.8)
    hand.session.sleep(0.1)
    assert np.allclose(finger_joints(hand), before, atol=0.01)  # nothing moved


@pytest.mark.parametrize("fingers", [[7], [0, -1]])
def test_a_finger_the_hand_does_not_have_is_a_usage_error(hand: Hand,
                                                          fingers: list[int]) -> None:
    with pytest.raises(UsageError, match=r"a hand has fingers 0\.\.3"):
        hand.grasp("cylindrical", 0.8, fingers=fingers, unhomed=True)


@pytest.mark.slow
def test_cylindrical_closes_every_finger_then_open_opens(hand: Hand) -> None:
    before = finger_joints(hand)
    result = hand.grasp("cylindrical", 0.8, speed=1.5, unhomed=True)
    closed = finger_joints(hand)
    targets = synergy_targets("cylindrical", 0.8)
    for k in range(4):
        # J1 and J2 flex (the closing direction) by most of the way to their targets.
        moved = closed[k, 1:] - before[k, 1:]
        assert np.all(moved > 0.5), (k, closed[k], before[k])
        assert np.all(np.abs(closed[k, 1:] - np.asarray(targets[k][1:])) < 0.15), k
    assert result.move is not None and result.move.settled
    # The blend is rate-limited: 0.8 · 1.35 rad at 1.5 rad/s takes ≥ 0.72 s.
    assert result.elapsed_s >= 0.72
    hand.grasp("open", 1.0, speed=2.0, unhomed=True)
    opened = finger_joints(hand)
    assert np.all(opened[:, 1:] < closed[:, 1:] - 0.5)
    assert np.all(np.abs(opened[:, 1:]) < 0.1)


def test_handctl_grasp_refuses_unhomed_and_names_unknown_grasps(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--port", URL, "grasp", "pinch", "0.5"]) == 2  # NotHomedError is usage
    err = capsys.readouterr().err
    assert "not homed" in err and "(handctl: --unhomed)" in err
    assert main(["--port", URL, "grasp", "fist", "0.5", "--unhomed"]) == 2
    err = capsys.readouterr().err
    assert "unknown grasp 'fist'" in err and "cylindrical" in err and "point" in err


@pytest.mark.parametrize("speed", ["1e6", "nan", "inf", "0", "-1e-3"])
def test_a_grasp_speed_that_is_absurd_or_not_finite_is_a_usage_error(
        speed: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--port", URL, "grasp", "open", "1", "--speed", speed, "--unhomed"]) == 2
    assert f"argument --speed: {speed}: give a speed (rad/s) > 0 and <= 170" in \
        capsys.readouterr().err


def test_the_library_refuses_an_absurd_grasp_speed_too(hand: Hand) -> None:
    for speed in (1e6, float("nan")):
        with pytest.raises(UsageError, match="give a speed > 0 and <= 170"):
            hand.grasp("open", 1.0, speed=speed, unhomed=True)


@pytest.mark.slow
def test_handctl_grasp_moves_and_reports_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--port", URL, "--json", "grasp", "pinch", "1.0", "--speed", "2",
                 "--unhomed"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["grasp"] == "pinch" and out["settled"]
    index, thumb = out["fingers"]["2"], out["fingers"]["3"]
    assert index["joints"][1] > 0.7 and thumb["joints"][1] > 0.7
    assert abs(out["fingers"]["0"]["joints"][1]) < 0.1  # the others stay open


@pytest.mark.slow
def test_until_contact_stops_a_finger_whose_taxels_are_pressed(hand: Hand) -> None:
    # Something meets finger 1's proximal pad as the grasp starts (the plant pushes the pad,
    # as an object would): a cylindrical grasp until contact stops that finger at once and
    # closes the others.
    emulator = emulator_of(hand)
    hand.grasp("open", 1.0, speed=2.0, unhomed=True)
    before = finger_joints(hand)
    pressed: list[float] = []

    def touch(t: float, states: object) -> None:
        if not pressed:
            pressed.append(t)
        elif len(pressed) == 1:  # after the baseline reading: the pad is pushed now
            emulator.finger_plants[1].press("F2", 3.0)
            pressed.append(t)

    try:
        result = hand.grasp("cylindrical", 1.0, speed=2.0, unhomed=True, until_contact=True,
                            on_states=touch)
    finally:
        emulator.finger_plants[1].press("F2", 0.0)
    after = finger_joints(hand)
    targets = synergy_targets("cylindrical", 1.0)
    assert 1 in result.contacts, "the pressed pad went unnoticed"
    for k in range(4):
        if k in result.contacts:
            assert "taxels" in result.contacts[k] or "blocked" in result.contacts[k]
            assert after[k, 1] < targets[k][1] - 0.3, k  # stopped short
        else:
            assert after[k, 1] - before[k, 1] > 0.8, k   # closed
    hand.grasp("open", 1.0, speed=2.0, unhomed=True)


@pytest.mark.slow
def test_a_squeeze_closes_j1_and_keeps_the_spread(hand: Hand) -> None:
    # Nothing stops finger 0: each round closes J1 by the squeeze (motor 1 alone), which
    # turns J0 with it while motor 0 holds; the next round turns J0 back.  At the end J1 is
    # far closed and J0 where it started.
    hand.move_fingers({0: (0.0, 0.4, 0.2)}, unhomed=True)
    before = finger_joints(hand)[0]
    targets = squeeze(hand, [0], 0.3, effort=255)
    after = finger_joints(hand)[0]
    assert SQUEEZE_ROUNDS >= 3
    assert after[1] - before[1] > 0.8, (before, after)
    assert abs(after[0] - before[0]) < 0.05, (before, after)
    assert targets[0][1] <= hand.limits.upper[0][1]
    hand.grasp("open", 1.0, speed=2.0, unhomed=True)
