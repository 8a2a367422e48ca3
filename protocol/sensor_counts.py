"""Raw ADC counts of the finger status and their engineering units.

The original fmcb put its ADC readings on the wire unconverted (``fmcb.status`` and
``fmcb.temperatures``: bus voltage, phalange-bus current, motor temperatures) and left the
conversion to the host; original messages keep that meaning here.  The fmcb samples with a
12-bit ADC on a 3.3 V reference:

* logic supply: through a 100 kΩ / 10 kΩ divider, V = counts / 4095 · 3.3 V · 11 (the
  original host's conversion);
* phalange-bus current: a sense amplifier of 2.7 V/A, I = counts / 4095 · 3.3 V / 2.7 V/A
  (the original host's conversion);
* motor temperatures: a linear analog sensor, 500 mV at 0 °C and 10 mV/°C.  The original
  host printed these counts without converting them, so this sensor law is this project's
  declaration.

The firmware turns what its sensors measure into counts with the ``*_counts`` functions (its
ADC); the host turns counts back into units with the others.  Counts saturate at 0..4095.
"""

from __future__ import annotations

from typing import Final

#: Largest reading of the 12-bit ADC (counts).
ADC_MAX: Final = 4095
#: ADC reference voltage (V).
ADC_VREF_V: Final = 3.3
#: Supply divider ratio (100 kΩ over 10 kΩ): supply volts per ADC volt.
SUPPLY_DIVIDER: Final = (100.0 + 10.0) / 10.0
#: Phalange-bus current sense gain (V/A).
PB_SENSE_V_PER_A: Final = 2.7
#: Temperature sensor: output at 0 °C (V) and slope (V/°C).
TEMP_V_AT_0C: Final = 0.5
TEMP_V_PER_C: Final = 0.010


def _counts(volts: float) -> int:
    counts = round(volts / ADC_VREF_V * ADC_MAX)
    return 0 if counts < 0 else ADC_MAX if counts > ADC_MAX else counts  # min/max: calls


def _volts(counts: int) -> float:
    return counts / ADC_MAX * ADC_VREF_V


def supply_volts(counts: int) -> float:
    """Logic supply voltage (V) from its ADC reading (counts)."""
    return _volts(counts) * SUPPLY_DIVIDER


def supply_counts(volts: float) -> int:
    """ADC reading (counts) of a logic supply of ``volts`` (V)."""
    return _counts(volts / SUPPLY_DIVIDER)


def pb_current_amps(counts: int) -> float:
    """Phalange-bus current (A) from its ADC reading (counts)."""
    return _volts(counts) / PB_SENSE_V_PER_A


def pb_current_counts(amps: float) -> int:
    """ADC reading (counts) of a phalange-bus current of ``amps`` (A)."""
    return _counts(amps * PB_SENSE_V_PER_A)


def temperature_c(counts: int) -> float:
    """Motor temperature (°C) from its ADC reading (counts)."""
    return (_volts(counts) - TEMP_V_AT_0C) / TEMP_V_PER_C


def temperature_counts(celsius: float) -> int:
    """ADC reading (counts) of a motor temperature of ``celsius`` (°C)."""
    return _counts(TEMP_V_AT_0C + celsius * TEMP_V_PER_C)
