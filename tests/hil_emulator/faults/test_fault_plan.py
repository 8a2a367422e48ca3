"""Fault plans (``hil_emulator/faults/plan.py``) and the injector that runs them
(``injector.py``): parameters checked by key, timelines from a seed and their replay, and
repeats of a fault."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hil_emulator.errors import FaultPlanError
from hil_emulator.faults import parse_plan
from protocol.dynamixel import make_ping
from tests.ground_truth import arm_rig_of
from tests.hil_emulator.faults.probes import MS, FaultyEmulator, arm_ping_answered


def test_parameters_are_checked_and_errors_name_the_key() -> None:
    with pytest.raises(FaultPlanError, match=r"faults\[0\]\.params\.finger.*not a int"):
        parse_plan([{"fault": "break_away", "params": {"finger": "two"}}])
    with pytest.raises(FaultPlanError, match=r"faults\[1\]\.params\.colour"):
        parse_plan([{"fault": "node_reset"}, {"fault": "node_reset", "params": {"colour": 1}}])
    with pytest.raises(FaultPlanError, match=r"faults\[0\]: unknown fault 'gremlin'"):
        parse_plan([{"fault": "gremlin"}])
    with pytest.raises(FaultPlanError, match=r"faults\[0\]: axis 'w' is not x, y, z"):
        parse_plan([{"fault": "sensor_fault", "params": {"mode": "misaligned", "axis": "w"}}])
    with pytest.raises(FaultPlanError, match=r"faults\[0\]\.params\.side"):
        parse_plan([{"fault": "baud_mismatch", "params": {"side": "both"}}])
    with pytest.raises(FaultPlanError, match=r"faults\[0\]\.when: unknown key"):
        parse_plan([{"fault": "node_reset", "when": 3}])
    with pytest.raises(FaultPlanError, match=r"faults\[0\]\.every_s"):
        parse_plan([{"fault": "line_cut", "count": 3}])
    with pytest.raises(FaultPlanError, match=r"faults\[0\]\.duration_s"):
        parse_plan([{"fault": "line_cut", "count": 2, "every_s": 0.1, "duration_s": 0.2}])
    with pytest.raises(FaultPlanError, match=r"faults\[0\]\.after_flash_bytes"):
        parse_plan([{"fault": "node_power_cut", "after_flash_bytes": 10}])
    with pytest.raises(FaultPlanError, match=r"faults\[0\]: rate 2.0 is not a probability"):
        parse_plan([{"fault": "bus_bit_errors", "params": {"rate": 2.0}}])


def _plan() -> list[dict[str, object]]:
    return [{"fault": "bus_frame_loss", "params": {"bus": "arm", "probability": 0.3},
             "at_s": 0.01, "duration_s": 0.02, "every_s": 0.05, "count": 3, "jitter_s": 0.01},
            {"fault": "stuck_driver", "params": {"bus": "arm"}, "at_s": 0.2,
             "duration_s": 0.005}]


def _run(seed: int, replay: list[dict[str, object]] | None = None
         ) -> tuple[list[dict[str, object]], bytes]:
    emu = FaultyEmulator("arm", seed=seed, physics=False)
    if replay is None:
        emu.faults.load(parse_plan(_plan()))
    else:
        emu.faults.replay(replay)  # type: ignore[arg-type]
    replies = bytearray()
    for _ in range(120):
        arm_rig_of(emu).send_from_host(make_ping(6).encode())
        emu.step(2 * MS)
        replies += arm_rig_of(emu).take_host_bytes()
    return emu.faults.timeline_dicts(), bytes(replies)


def test_same_seed_and_plan_same_timeline_and_run_and_a_timeline_replays() -> None:
    timeline, replies = _run(11)
    assert _run(11) == (timeline, replies)
    assert [e["action"] for e in timeline].count("apply") == 4
    other, _ = _run(12)
    assert [e["t_us"] for e in other] != [e["t_us"] for e in timeline]  # jitter from the seed
    replayed = _run(11, replay=json.loads(json.dumps(timeline)))
    assert replayed == (timeline, replies)


def test_rngs_differ_by_entry_and_occurrence() -> None:
    emu = FaultyEmulator("arm", seed=3, physics=False)
    draws = {(e, k): emu.faults._rng(e, k).random() for e in range(2) for k in range(2)}
    assert len(set(draws.values())) == 4
    assert np.isclose(emu.faults._rng(1, 1).random(), draws[(1, 1)])


def test_overlapping_repeats_of_a_fault_are_cleared_before_applied_again() -> None:
    """A repeat that starts while the last one is still applied (a fault that stays until
    cleared, repeated) clears it first: each apply has its clear, and clearing the fault
    once leaves nothing of it (two stacked applies would leave frames lost for good)."""
    emu = FaultyEmulator("arm", seed=3, physics=False)
    try:
        emu.faults.load(parse_plan([
            {"fault": "bus_frame_loss", "params": {"bus": "arm", "probability": 1.0},
             "at_s": 0.01, "every_s": 0.02, "count": 2}]))
        emu.step(50 * MS)
        timeline = [(e["action"], e["occurrence"], e["t_us"])
                    for e in emu.faults.timeline_dicts()]
        assert timeline == [("apply", 0, 10_000), ("clear", 0, 30_000),
                            ("apply", 1, 30_000)]
        assert not arm_ping_answered(emu)  # the repeat is applied
        emu.faults.clear_all()
        assert emu.faults.active == []
        assert arm_ping_answered(emu)  # and nothing of the fault is left
    finally:
        emu.close()
