"""Faults of a node's firmware and sensors (``hil_emulator/faults/nodes.py``): each effect
observable, and gone once cleared."""

from __future__ import annotations

import pytest

from firmware_py.sim.virtual_sensors import VirtualSensors
from tests.ground_truth import hand_rig_of
from tests.hil_emulator.faults.probes import MS, FaultyEmulator, answers, host_of


def test_node_hang_reset_and_reset_storm(hand: FaultyEmulator) -> None:
    host = host_of(hand)
    fmcb = hand_rig_of(hand).fingers[2].fmcb
    entry = hand.faults.inject("node_hang", {"node": "finger2.fmcb"})
    assert not answers(host.fingers[2].motor)
    hand.faults.clear(entry)
    assert fmcb.in_bootloader
    resets = fmcb.resets
    hand.faults.inject("node_reset", {"node": "finger2.fmcb"})
    assert fmcb.resets == resets + 1
    hand.faults.inject("reset_storm", {"node": "finger2.fmcb", "resets": 4,
                                       "period_us": 10_000})
    hand.step(50 * MS)
    assert fmcb.resets == resets + 5


def test_a_sensor_stuck_biased_or_noisy_and_restored(hand: FaultyEmulator) -> None:
    assert hand.hand is not None
    sensors = hand.hand.fingers[0].f2.hal.sensors
    assert isinstance(sensors, VirtualSensors)
    true = sensors.read("strain")
    assert isinstance(true, int)
    for params, check in (({"mode": "stuck", "value": 1234}, lambda v: v == 1234),
                          ({"mode": "biased", "bias": 300}, lambda v: v == true + 300),
                          ({"mode": "noisy", "sigma": 50.0}, lambda v: v != true)):
        entry = hand.faults.inject("sensor_fault", {"node": "finger0.f2", "channel": "strain",
                                                    **params})
        assert "strain" in sensors.faults
        assert any(check(sensors.read("strain")) for _ in range(5)), params
        hand.faults.clear(entry)
        assert not sensors.faults and sensors.read("strain") == true
    with pytest.raises(Exception, match="no sensor channel"):
        hand.faults.inject("sensor_fault", {"node": "finger0.f2", "channel": "pressure"})


def test_a_misaligned_accelerometer_reads_the_vector_rotated_and_is_restored(hand: FaultyEmulator
                                                                            ) -> None:
    assert hand.hand is not None
    sensors = hand.hand.fingers[1].f3.hal.sensors
    assert isinstance(sensors, VirtualSensors)
    sensors.set_accel(0, 0, 1000)  # 1 g along its z axis
    entry = hand.faults.inject("sensor_fault", {"node": "finger1.f3", "channel": "accel",
                                                "mode": "misaligned", "angle_deg": 90.0,
                                                "axis": "x"})
    assert sensors.read("accel") == (0, -1000, 0)  # z turns to −y about x
    hand.faults.clear(entry)
    entry = hand.faults.inject("sensor_fault", {"node": "finger1.f3", "channel": "accel",
                                                "mode": "misaligned", "angle_deg": 10.0,
                                                "axis": "0,1,0"})
    x, y, z = sensors.read("accel")  # type: ignore[misc]
    assert (x, y, z) == (174, 0, 985)  # 1000·(sin 10°, 0, cos 10°): the magnitude kept
    hand.faults.clear(entry)
    assert sensors.read("accel") == (0, 0, 1000)
    with pytest.raises(Exception, match="not a three-axis vector"):
        hand.faults.inject("sensor_fault", {"node": "finger0.f2", "channel": "strain",
                                            "mode": "misaligned"})
