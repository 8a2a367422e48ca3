"""The plant's plain-float conversions give exactly what the numpy formulas they replaced gave.

The slow sensor refresh converts its channels with Python floats (:class:`LinearCounts`),
rounds with :func:`rint` and takes its noise from a :class:`NormalStream`: the traffic
digest depends on every count being the same integer as before, in both builds.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from hil_emulator.hand.sensors import DEFAULT_TACTILE, LinearCounts, NormalStream
from hil_emulator.plant import rint

FINITE = st.floats(min_value=-1e12, max_value=1e12, allow_nan=False)


@settings(deadline=None)
@given(FINITE)
def test_rint_is_round_half_to_even(value: float) -> None:
    assert rint(value) == round(value) == int(np.rint(value))


def test_rint_rounds_exact_halves_to_even_on_both_sides_of_zero() -> None:
    halves = [-3.5, -2.5, -1.5, -0.5, 0.5, 1.5, 2.5, 3.5, 2.0**52 + 1.0, -(2.0**52) - 1.0]
    assert [rint(v) for v in halves] == [-4, -2, -2, 0, 0, 2, 2, 4, 2**52 + 1, -(2**52) - 1]
    for bad in (math.nan, math.inf):
        try:
            rint(bad)
        except (ValueError, OverflowError):
            continue
        raise AssertionError(f"rint({bad}) returned instead of raising as round() does")


def _numpy_counts(conversion: LinearCounts, raw: np.ndarray, noise: np.ndarray) -> list[int]:
    """The vectorised formula the plant used before (clamp, then rint into int64)."""
    def per_element(field: int) -> np.ndarray:
        return np.concatenate([np.full(run[0], run[field]) for run in conversion.runs])
    value = raw * per_element(1)
    value += per_element(2)
    value += noise * per_element(3)
    np.maximum(value, per_element(4), out=value)
    np.minimum(value, per_element(5), out=value)
    out: list[int] = np.rint(value).astype(np.int64).tolist()
    return out


FINGER = LinearCounts.imu([("accel", 2.0), ("mag", 2.0)] * 3).join(
    LinearCounts.taxels(DEFAULT_TACTILE, 6)).join(LinearCounts.taxels(DEFAULT_TACTILE, 12))


def test_equal_taxel_runs_are_merged() -> None:
    assert [run[0] for run in FINGER.runs] == [3] * 6 + [18]
    assert FINGER.size == 36


@settings(deadline=None, max_examples=200)
@given(st.data())
def test_counts_equal_the_numpy_formula_clamps_included(data: st.DataObject) -> None:
    size = FINGER.size
    # IMU readings up to 40 m/s² (beyond the ±2 g clamp) and gauss; taxel compression 0..1.
    raw = data.draw(st.lists(st.floats(-40.0, 40.0), min_size=size, max_size=size))
    raw[18:] = [abs(v) / 40.0 for v in raw[18:]]
    head = data.draw(st.sampled_from([size, 18, 7, 0]))  # the rest reads 0
    noise = data.draw(st.lists(st.floats(-6.0, 6.0), min_size=size + 5, max_size=size + 5))
    at = data.draw(st.integers(0, 5))
    full = np.array(raw[:head] + [0.0] * (size - head))
    expected = _numpy_counts(FINGER, full, np.array(noise[at:at + size]))
    assert FINGER.counts(raw[:head], noise, at) == expected
    # Both ways, whichever this build takes (run by run compiled, flat from source).
    assert FINGER._counts_by_run(raw[:head], noise, at) == expected
    assert FINGER._counts_flat(raw[:head], noise, at) == expected


def test_counts_clamp_and_read_nan_as_the_low_bound() -> None:
    accel = LinearCounts.imu([("accel", 0.0)])
    assert accel.counts([1e3, -1e3, math.nan], [0.0] * 3) == [2000, -2000, -2000]
    for way in (accel._counts_by_run, accel._counts_flat):
        assert way([1e3, -1e3, math.nan], [0.0] * 3, 0) == [2000, -2000, -2000]


@settings(deadline=None)
@given(st.lists(st.integers(1, 300), min_size=1, max_size=40), st.integers(0, 2**32))
def test_a_normal_stream_hands_out_the_generator_s_own_sequence(sizes: list[int],
                                                                 seed: int) -> None:
    stream = NormalStream(np.random.default_rng(seed), block=256)
    taken: list[float] = []
    for n in sizes:
        buffer, at = stream.take(n)
        taken += buffer[at:at + n]
    assert taken == np.random.default_rng(seed).standard_normal(sum(sizes)).tolist()
