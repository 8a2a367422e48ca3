"""Hypothesis examples are never timed: a loaded machine must not fail a property test."""

from __future__ import annotations

import time

from hypothesis import given, settings
from hypothesis import strategies as st


def test_the_loaded_profile_has_no_deadline() -> None:
    assert settings().deadline is None


@settings(max_examples=3)  # a decorator without a deadline of its own inherits the profile
@given(st.integers())
def test_an_example_slower_than_hypothesis_default_deadline_passes(value: int) -> None:
    time.sleep(0.25)  # beyond hypothesis' default 200 ms deadline, as on a busy machine
    assert isinstance(value, int)
