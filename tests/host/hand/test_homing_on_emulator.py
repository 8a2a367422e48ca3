"""Inertial estimation and homing end to end on the emulated hand (simulation clock).

The hand stands palm up, so fingers 0-2 have J0 vertical (never observable) and the thumb
(finger 3, standing up from the palm) has every axis observable for |J0| < 70°.  Ground
truth is the plant's MuJoCo joint angles.  One emulator for the module, with ideal sensors:
these tests hold the estimator to its own accuracy (within 1°); the robot as built, its
accelerometers uncalibrated, homes too but reads degrees off (the last test).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from host.errors import FingerMovingError, NotHomedError
from host.estimation.closed_form import UnobservableJointError
from host.hand.facade import Hand
from host.hand.homing import home_finger, inertial_estimate
from tests.ground_truth import finger_joints, planted_of
from tools.cli.handctl import main

URL = "emu://hand/palm?name=estimation-tests&sensors=ideal"
THUMB = 3


def _random_pose(rng: np.random.Generator) -> tuple[float, float, float]:
    return (float(rng.uniform(-0.8, 0.8)), float(rng.uniform(-0.2, 1.2)),
            float(rng.uniform(-0.2, 1.2)))


def test_moves_are_refused_until_the_finger_is_homed(hand: Hand) -> None:
    with pytest.raises(NotHomedError, match=r"finger\(s\) \[1\] not homed") as caught:
        hand.fingers[1].command((0.1, 0.2, 0.3))
    assert caught.value.fingers == [1]
    hand.fingers[1].idle()  # idling is always allowed


@pytest.mark.slow
def test_inertial_estimate_matches_the_plant_at_random_poses(hand: Hand) -> None:
    rng = np.random.default_rng(11)
    thumb = hand.fingers[THUMB]
    for _ in range(2):
        thumb.move(_random_pose(rng), effort=200, timeout=2.0, unhomed=True)
        thumb.idle()
        hand.session.sleep(0.2)
        found = inertial_estimate(thumb)
        truth = finger_joints(hand)[THUMB]
        assert found.observable
        err = np.degrees(np.abs(np.asarray(found.q, dtype=float) - truth))
        assert np.all(err < 1.0), (found.q, truth)


def test_homing_a_finger_with_a_vertical_axis_is_refused_naming_the_joint(hand: Hand) -> None:
    with pytest.raises(UnobservableJointError, match=r"finger 0: J0 \(abduction\) is "
                                                     r"unobservable"):
        hand.home(0)
    assert not hand.fingers[0].homed


@pytest.mark.slow
def test_homing_from_a_random_pose_makes_the_joints_read_true(hand: Hand) -> None:
    thumb = hand.fingers[THUMB]
    thumb.move((0.45, 0.8, 0.35), effort=200, timeout=2.0, unhomed=True)
    thumb.idle()
    hand.session.sleep(0.2)
    result = home_finger(thumb)
    assert result.homed and thumb.homed
    joints = np.asarray(thumb.status().joints)
    err = np.degrees(np.abs(joints - finger_joints(hand)[THUMB]))
    assert np.all(err < 1.0), err
    moved = thumb.move((0.1, 0.3, 0.2), effort=200, timeout=2.0)  # no override needed now
    assert moved.settled


def test_handctl_home_and_status_report_inertial_joints(
        hand: Hand, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--port", URL, "--json", "home", "--finger", "0"]) == 2
    assert "J0 (abduction)" in capsys.readouterr().err
    # the last test left the thumb holding a target; with the fmcb's 2-count deadband it
    # creeps for a while after the host's settle test: idle it first, as handctl says
    hand.fingers[THUMB].idle()
    hand.session.sleep(0.2)
    assert main(["--port", URL, "--json", "home", "--finger", str(THUMB)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["fingers"][0]["homed"] and len(out["fingers"][0]["offsets"]) == 3
    assert main(["--port", URL, "--json", "status"]) == 0
    status = json.loads(capsys.readouterr().out)
    thumb, first = status["fingers"][THUMB], status["fingers"][0]
    assert thumb["homed"] and not first["homed"]
    assert first["joints_accel"][0] is None and first["joints_accel"][1] is not None
    truth = finger_joints(hand)[THUMB]
    for key in ("joints", "joints_accel"):
        assert max(abs(math.degrees(a - b)) for a, b in zip(thumb[key], truth,
                                                           strict=True)) < 1.0
    assert {"joints_hall", "tactile", "currents"} <= set(thumb)


def test_handctl_home_of_every_finger_says_how_to_make_vertical_axes_observable(
        hand: Hand, capsys: pytest.CaptureFixture[str]) -> None:
    """Palm up, fingers 0-2 have J0 vertical: ``home`` refuses them, names J0 in JSON, and
    says (text) to tilt the wrist with ``armctl`` first; one finger asked for: exit 2, the
    same advice on stderr."""
    assert main(["--port", URL, "--json", "home"]) == 1
    fingers = json.loads(capsys.readouterr().out)["fingers"]
    assert [f["unobservable"] for f in fingers[:3]] == [[0], [0], [0]]
    assert not any(f["homed"] for f in fingers[:3])
    main(["--port", URL, "home"])
    out = capsys.readouterr().out
    assert "finger 1: not homed: J0 (abduction) is unobservable" in out
    hint = [line for line in out.splitlines() if line.startswith("hint:")]
    assert len(hint) == 1 and "armctl --port ARM move --joints 0,0,0,0,0,0.4,0.9" in hint[0]
    assert hint[0].endswith("for finger(s) 0, 1, 2")
    assert main(["--port", URL, "home", "--finger", "2"]) == 2
    err = capsys.readouterr().err
    assert "J0 (abduction) is unobservable" in err and "armctl --port ARM move" in err
    assert "Traceback" not in err


@pytest.mark.slow
def test_homing_waits_for_a_finger_still_moving_to_come_to_rest(hand: Hand) -> None:
    """A finger still swinging when homing starts (here: its motors idled mid-move; on the
    arm, the wrist servos hunting after a move) is read again until it is still, instead of
    refused at the first reading."""
    thumb = hand.fingers[THUMB]
    thumb.move((0.45, 0.8, 0.35), effort=200, timeout=2.0, unhomed=True)
    thumb.idle()
    hand.session.sleep(0.5)
    thumb.command((0.0, 0.2, 0.1), effort=200, unhomed=True)
    hand.session.sleep(0.15)
    thumb.idle()  # it falls on from here for a quarter of a second
    result = home_finger(thumb)
    assert result.homed
    joints = np.asarray(thumb.status().joints)
    err = np.degrees(np.abs(joints - finger_joints(hand)[THUMB]))
    assert np.all(err < 1.0), err


@pytest.mark.slow
def test_homing_refuses_a_finger_that_keeps_moving_for_the_whole_wait(hand: Hand) -> None:
    thumb = hand.fingers[THUMB]
    start = hand.session.now()
    thumb.command((0.45, 0.8, 0.35), effort=200, unhomed=True)  # driven on while read
    try:
        with pytest.raises(FingerMovingError, match=r"finger 3 moved while being read .* "
                                                    r"for 0.5 s; let it come to rest"):
            home_finger(thumb, wait_s=0.5)
        assert hand.session.now() - start >= 0.5
    finally:
        thumb.idle()


def test_the_robot_as_built_homes_a_few_degrees_off() -> None:
    """Realistic sensors (the default): homing from the accelerometers still homes the
    thumb, and its joints then read within 5° of the plant (uncalibrated chips: offsets,
    scale errors and mounting tilts of an LSM303DLH on a laser-cut finger; 1.9, 0.5 and
    3.7° on this seed), and not within the 0.5° the ideal chips give: the imperfections
    reach the host.  The status right after homing already says so."""
    with Hand.open("emu://hand/palm?name=estimation-realistic") as hand:
        assert planted_of(hand).accels["finger3.f2"].tilt_deg() > 0.0
        thumb = hand.fingers[THUMB]
        thumb.move((0.45, 0.8, 0.35), effort=200, timeout=2.0, unhomed=True)
        thumb.idle()
        hand.session.sleep(0.2)
        result = home_finger(thumb)
        assert result.homed and thumb.homed
        err = np.degrees(np.abs(np.asarray(thumb.status().joints) - finger_joints(hand)[THUMB]))
        assert np.all(err < 5.0), err
        assert np.max(err) > 0.5, err
