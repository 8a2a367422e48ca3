"""The calibration's model and fit on synthetic readings (no emulator): recovery where the
readings determine the parameters, the priors where they do not, the file's section."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from host.errors import UsageError
from host.estimation import hand_calibration as hc
from host.estimation.finger_gravity import axis_rotation

_small = st.floats(-1.0, 1.0)


def _params(draw: st.DrawFn) -> np.ndarray:
    """A board's 12 parameters within about two of their priors' σ."""
    sizes = np.repeat([hc.PRIORS[g] for g in ("rotation", "scale", "cross", "bias")], 3)
    return np.array([draw(_small) for _ in range(12)]) * 2.0 * sizes


@st.composite
def boards(draw: st.DrawFn) -> np.ndarray:
    return _params(draw)


def _sphere(n: int, seed: int = 0) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, 3))
    out: np.ndarray = v / np.linalg.norm(v, axis=1, keepdims=True)
    return out


@settings(deadline=None, max_examples=25)
@given(p=boards())
def test_a_board_seen_from_every_direction_is_recovered(p: np.ndarray) -> None:
    up = _sphere(40)
    readings = up @ hc.board_matrix(p).T + p[9:12]
    fit = hc.fit_board(readings, up)
    # the priors pull by (noise σ / prior σ)² / N: far below a count here
    assert np.abs(fit.matrix() - hc.board_matrix(p)).max() < 0.05
    assert np.abs(fit.bias - p[9:12]).max() < 0.05
    # and the correction gives back the directions (counts, 1000 per g)
    assert np.abs(np.array([fit.correct(r) for r in readings]) - 1000 * up).max() < 0.1


@settings(deadline=None, max_examples=25)
@given(p=boards())
def test_correct_undoes_the_model(p: np.ndarray) -> None:
    cal = hc.BoardCalibration(p[0:3], p[3:6], p[6:9], p[9:12])
    up = _sphere(5, 1)
    for u in up:
        assert cal.correct(cal.matrix() @ u + cal.bias) == pytest.approx(1000 * u, abs=1e-6)


def test_a_board_seen_from_one_direction_keeps_its_priors() -> None:
    up = np.tile([0.0, 0.0, 1.0], (10, 1))
    fit = hc.fit_board(up * 1000.0 + [15.0, 0.0, 0.0], up)
    # x's bias explains the reading as well as a tilt would: shared, both within the prior
    assert 0.0 < fit.bias[0] < 15.0
    assert max(fit.sigma["scale"][:2]) == pytest.approx(hc.PRIORS["scale"], rel=0.01)


@st.composite
def calibrations(draw: st.DrawFn) -> hc.HandCalibration:
    keys = draw(st.lists(st.sampled_from([hc.board_key(f, b) for f in range(4)
                                          for b in ("fmcb", "f2", "f3")]), unique=True,
                         max_size=4))
    out = {}
    for k in keys:
        p = _params(draw)
        out[k] = hc.BoardCalibration(p[0:3], p[3:6], p[6:9], p[9:12])
    return hc.HandCalibration(out, "x")


@settings(deadline=None, max_examples=30)
@given(cal=calibrations())
def test_the_section_round_trips(cal: hc.HandCalibration) -> None:
    again = hc.HandCalibration.from_section(cal.to_section(), "x")
    assert set(again.boards) == set(cal.boards)
    for k, board in cal.boards.items():
        assert np.array_equal(again.boards[k].params(), board.params())


def test_a_section_of_another_method_is_refused() -> None:
    with pytest.raises(UsageError, match="method"):
        hc.HandCalibration.from_section({"method": "other", "boards": {}}, "f.json")
    with pytest.raises(UsageError, match="3 finite"):
        hc.HandCalibration.from_section({"method": hc.METHOD, "boards": {"finger0.f2": {
            "rotation_vector_rad": [0, 0], "scale": [0, 0, 0], "cross": [0, 0, 0],
            "bias_counts": [0, 0, 0]}}}, "f.json")


def _finger_samples(planted: dict[str, np.ndarray], offsets: np.ndarray,
                    up_f0: np.ndarray) -> list[hc.FingerSample]:
    samples = []
    for j0 in (-0.7, 0.0, 0.7):
        for j1, j2 in ((-0.3, 0.1), (0.0, 0.8), (0.0, 1.4), (0.45, 0.1), (0.45, 0.8),
                       (0.9, 0.1), (0.9, 0.8)):
            q = np.array([j0, j1, j2])
            seg = hc._segment_up(q, up_f0)
            readings = {b: (hc.board_matrix(p) @ seg[b] + p[9:12]).tolist()
                        for b, p in planted.items()}
            samples.append(hc.FingerSample(tuple(q - offsets), readings))
    return samples


def test_a_finger_fit_finds_the_hall_offsets_and_names_the_unobservable() -> None:
    rng = np.random.default_rng(3)
    planted = {}
    for b in ("fmcb", "f2", "f3"):
        p = rng.normal(size=12) * np.repeat([hc.PRIORS[g] for g in ("rotation", "scale",
                                                                   "cross", "bias")], 3)
        p[1] = 0.0  # no tilt about y: the one the halls' offsets cannot tell apart
        planted[b] = p
    offsets = np.array([0.05, -0.04, 0.03])
    up_f0 = axis_rotation([0.0, 1.0, 0.0], 1.2) @ np.array([0.0, 0.0, 1.0])
    fit = hc.fit_finger(_finger_samples(planted, offsets, up_f0), offsets_guess=[0, 0, 0],
                        up_guess={0: up_f0 + [0.05, 0.0, 0.0]})
    assert fit.rms_counts < 0.5
    assert fit.offsets[1:] == pytest.approx(offsets[1:], abs=np.radians(0.1))
    for b in ("f2", "f3"):
        assert np.abs(fit.boards[b].bias - planted[b][9:12]).max() < 1.0
    assert {"f2.rotation[y]", "f3.rotation[y]"} <= set(fit.unobservable())
    assert "f2.bias[x]" not in fit.unobservable()


def test_a_finger_fit_needs_six_poses() -> None:
    with pytest.raises(UsageError, match="6 poses"):
        hc.fit_finger([], offsets_guess=[0, 0, 0], up_guess={0: [0, 0, 1]})
