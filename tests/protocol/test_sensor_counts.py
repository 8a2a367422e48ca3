"""ADC counts of the finger status ↔ engineering units (protocol.sensor_counts)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocol.sensor_counts import (
    ADC_MAX,
    pb_current_amps,
    pb_current_counts,
    supply_counts,
    supply_volts,
    temperature_c,
    temperature_counts,
)


def test_the_original_hosts_conversions_by_hand() -> None:
    # Full scale: 3.3 V at the ADC; the supply through ×11, the current through 2.7 V/A.
    assert supply_volts(ADC_MAX) == pytest.approx(36.3)
    assert supply_volts(2482) == pytest.approx(2482 / 4095 * 3.3 * 11)  # ≈ 22.0 V
    assert pb_current_amps(ADC_MAX) == pytest.approx(3.3 / 2.7)
    assert pb_current_amps(670) == pytest.approx(0.19997, abs=1e-5)  # the 0.2 A breaker
    assert temperature_c(round(0.5 / 3.3 * 4095)) == pytest.approx(0.0, abs=0.05)
    assert temperature_c(931) == pytest.approx(25.03, abs=0.01)


def test_counts_saturate_at_the_adc_range() -> None:
    assert supply_counts(100.0) == ADC_MAX and supply_counts(-1.0) == 0
    assert pb_current_counts(5.0) == ADC_MAX
    assert temperature_counts(-80.0) == 0


@given(st.integers(0, ADC_MAX))
def test_units_and_counts_round_trip(counts: int) -> None:
    assert supply_counts(supply_volts(counts)) == counts
    assert pb_current_counts(pb_current_amps(counts)) == counts
    assert temperature_counts(temperature_c(counts)) == counts
