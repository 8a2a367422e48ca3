"""The fault registry (``hil_emulator/faults/base.py``): every fault declares an entry point, a
summary and typed defaults, and every fault of the catalogue is implemented."""

from __future__ import annotations

from hil_emulator.faults import FAULTS, NOT_YET_IMPLEMENTED, catalogue, make_fault


def test_every_fault_declares_an_entry_point_a_summary_and_typed_defaults() -> None:
    assert len(FAULTS) >= 25
    for name, cls in FAULTS.items():
        assert cls.summary and cls.entry_point, name
        fault = cls()  # every parameter has a default
        assert make_fault(name, fault.params()).params() == fault.params()
    listed = {f["name"]: f for f in catalogue()}
    assert all(not listed[n]["implemented"] for n in NOT_YET_IMPLEMENTED)


def test_every_fault_of_the_catalogue_is_implemented() -> None:
    assert not NOT_YET_IMPLEMENTED
    assert {"spring_drift", "serial_driver_stuck", "baud_mismatch",
            "duplicate_servo_id"} <= set(FAULTS)
    assert all(f["implemented"] for f in catalogue())
