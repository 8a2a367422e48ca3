"""Grasp synergies as data: roles from the layouts, spread signs, targets, the blend, contact."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from host.errors import UsageError
from host.hand.state import FingerState
from host.hand.synergies import (
    CONTACT_EFFORT,
    SYNERGIES,
    TACTILE_CONTACT_COUNTS,
    blend,
    contact,
    finger_roles,
    spread_signs,
    squeeze_target,
    synergy_targets,
)
from protocol.robot import FINGER_GEAR_RATIOS, HALL_STATES_PER_RAD, joint_to_motor


def test_roles_come_from_the_layouts() -> None:
    # The thumb (finger 3) stands up from the palm near finger 2's corner.
    assert finger_roles("four-finger-thumb") == ["finger", "finger", "index", "opposing"]
    # The opposed module faces the middle finger.
    assert finger_roles("three-plus-opposed") == ["finger", "index", "finger", "opposing"]
    assert finger_roles("two-by-two") == ["index", "finger", "opposing", "opposing"]


def test_spread_turns_outer_fingers_away_from_the_middle() -> None:
    # Fingers along +y, J0 about +z: +J0 swings the tip towards −x, so the finger at
    # x = −30 mm spreads with +J0, the one at +30 mm with −J0, the middle one not at all.
    assert spread_signs("four-finger-thumb")[:3] == [1.0, 0.0, -1.0]
    # Along −y, +J0 swings the tip towards +x: the pair at ±22 mm spreads with ∓J0... mirrored.
    assert spread_signs("two-by-two") == [1.0, -1.0, -1.0, 1.0]


def test_spherical_spreads_and_cylindrical_does_not() -> None:
    sph = synergy_targets("spherical", 1.0, "four-finger-thumb")
    assert sph[0][0] > 0.2 and sph[2][0] < -0.2 and sph[1][0] == 0.0
    cyl = synergy_targets("cylindrical", 1.0)
    assert all(q[0] == 0.0 for q in cyl.values())
    assert all(q[1] > 1.0 and q[2] > 0.8 for q in cyl.values())


@given(st.sampled_from(sorted(SYNERGIES)), st.floats(0.0, 1.0),
       st.sampled_from(["four-finger-thumb", "three-plus-opposed", "two-by-two"]))
def test_targets_are_linear_in_the_amount_and_inside_the_limits(name: str, amount: float,
                                                                layout: str) -> None:
    lo, hi = synergy_targets(name, 0.0, layout), synergy_targets(name, 1.0, layout)
    mid = synergy_targets(name, amount, layout)
    for k in range(4):
        expected = np.asarray(lo[k]) + amount * (np.asarray(hi[k]) - np.asarray(lo[k]))
        assert np.allclose(mid[k], expected)
        assert np.all(np.abs(mid[k]) <= 1.57)


def test_pinch_moves_only_the_index_and_the_opposing_finger() -> None:
    pinch = synergy_targets("pinch", 1.0, "four-finger-thumb")
    assert pinch[0] == pinch[1] == (0.0, 0.0, 0.0)
    assert pinch[2][1] > 0.5 and pinch[3][1] > 0.5


def test_an_unknown_grasp_lists_the_names() -> None:
    with pytest.raises(UsageError, match="unknown grasp 'fist'; choose one of cylindrical, "
                                         "open, pinch, point, prismatic, relax, spherical"):
        synergy_targets("fist", 0.5)


def test_an_amount_outside_0_1_is_refused() -> None:
    with pytest.raises(UsageError, match="give a value in 0..1"):
        synergy_targets("open", 1.5)


@given(st.lists(st.floats(-1.5, 1.5), min_size=3, max_size=3),
       st.lists(st.floats(-1.5, 1.5), min_size=3, max_size=3),
       st.floats(0.1, 5.0), st.floats(0.0, 0.5), st.floats(0.001, 0.1))
def test_the_blend_never_moves_a_joint_faster_than_the_speed(
        a: list[float], b: list[float], speed: float, t: float, dt: float) -> None:
    step = np.abs(blend(a, b, speed, t + dt) - blend(a, b, speed, t))
    assert np.all(step <= speed * dt + 1e-9)
    assert np.allclose(blend(a, b, speed, 100.0), b)
    assert np.allclose(blend(a, b, speed, 0.0), a)


def _state(taxel: int = 2000, joints_hall: tuple[int, int, int] = (0, 0, 0),
           effort: int = 0) -> FingerState:
    s = FingerState(0, present=True, joints_hall=list(joints_hall), effort=[effort, effort, 0])
    s.tactile = {"proximal": [2000] * 6, "distal": [taxel] + [2000] * 11}
    return s


def test_a_taxel_rise_means_contact() -> None:
    base = _state()
    assert contact(_state(2000 + TACTILE_CONTACT_COUNTS - 1), base, (0, 0, 0)) is None
    assert "distal taxels" in (contact(_state(2000 + TACTILE_CONTACT_COUNTS), base,
                                       (0, 0, 0)) or "")


def test_a_blocked_flexion_joint_pushing_hard_means_contact() -> None:
    base = _state()
    blocked = _state(effort=CONTACT_EFFORT)
    # Lagging 0.5 rad on J1, not moving, pushing: contact.
    assert "J1 blocked" in (contact(blocked, base, (0.0, 0.5, 0.0), previous=blocked) or "")
    # The same lag while the joint still moves (accelerating after a start): no contact.
    moving = _state(joints_hall=(2000, 2000, 0), effort=CONTACT_EFFORT)
    assert contact(blocked, base, (0.0, 0.5, 0.0), previous=moving) is None
    # Lagging without pushing: no contact.
    assert contact(_state(), base, (0.0, 0.5, 0.0), previous=_state()) is None


@given(st.tuples(*(st.floats(-1.0, 1.0) for _ in range(3))), st.floats(0.0, 0.5))
def test_a_squeeze_advances_only_the_proximal_flexion_motor(q: tuple[float, float, float],
                                                            amount: float) -> None:
    before = np.asarray(joint_to_motor(q))
    after = np.asarray(joint_to_motor(squeeze_target(q, amount)))
    advance = amount * FINGER_GEAR_RATIOS[1] * HALL_STATES_PER_RAD
    np.testing.assert_allclose(after - before, [0.0, advance, 0.0], atol=1e-6)
    # In joints: J1 on by the amount, J2 where it was, J0 back by g1/g0 of it (motor 0 stays).
    target = squeeze_target(q, amount)
    assert target[1] == pytest.approx(q[1] + amount)
    assert target[2] == pytest.approx(q[2])
    assert target[0] == pytest.approx(q[0] - amount * FINGER_GEAR_RATIOS[1]
                                      / FINGER_GEAR_RATIOS[0])
