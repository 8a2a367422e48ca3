"""The host library end to end on the emulated hand in this process (simulation clock).

All tests share one emulator (``emu://hand/palm?name=host-tests``, brought up once); each
uses its own finger: 1 moves, 2 is switched off, 3 breaks away.
"""

from __future__ import annotations

import pytest

from host.errors import RouteError
from host.hand.facade import FALLBACK_DEADBAND_HALL, Hand
from host.hand.session import FingerEvent
from protocol.messages.palm import RouteStatus
from tests.ground_truth import emulator_of

URL = "emu://hand/palm?name=host-tests"


def test_discovery_finds_all_thirteen_nodes_running_their_applications(hand: Hand) -> None:
    found = hand.discover()
    assert [n.where for n in found[:4]] == ["palm", "finger 0 fmcb", "finger 0 f2",
                                             "finger 0 f3"]
    assert len(found) == 13 and all(n.answered for n in found)
    assert all(n.running == "application" and n.catalogue_matches for n in found)
    assert [n.board for n in found] == [1] + [2, 3, 4] * 4
    assert len({n.uid for n in found}) == 13


def test_a_finger_moves_toward_its_joint_targets(hand: Hand) -> None:
    finger = hand.fingers[1]
    target = (0.3, 0.6, 0.4)
    before = finger.status().joints
    result = finger.move(target, effort=200, timeout=4.0, unhomed=True)
    after = result.states[1].joints
    assert result.settled
    for q_before, q_after, goal in zip(before, after, target, strict=True):
        assert abs(goal - q_after) < 0.15  # within the fmcb's 50-count deadband
        assert abs(goal - q_after) < abs(goal - q_before) / 2
    assert hand.status().fingers[1].joints == pytest.approx(after, abs=0.02)


def test_the_settle_tolerance_is_the_fmcbs_deadband_read_once(hand: Hand) -> None:
    finger = hand.fingers[1]  # moved above: its deadband was read then
    before = hand.session.counters.requests
    assert finger.deadband() == 2  # the firmware's default parameter
    assert hand.session.counters.requests == before  # kept, not asked again
    finger.params.set("deadband", 80)
    assert finger.deadband() == 80
    assert finger.params.get("deadband") == 80  # the board has it too
    finger.params.restore_defaults()
    assert finger.deadband() == 2


def test_a_palm_polled_stream_gives_the_palm_back_its_poll_rate(hand: Hand) -> None:
    """``fingers=False`` has the palm poll the fingers at the stream's rate while it runs;
    when it ends (or is closed early) the palm polls as before."""
    before = hand.status(fingers=False).poll_hz
    rates = [s.poll_hz for s in hand.states(25.0, seconds=0.1, fingers=False)]
    assert rates and all(r == 25 for r in rates)
    assert hand.status(fingers=False).poll_hz == before
    stream = hand.states(30.0, fingers=False)  # forever, closed after one state
    assert next(stream).poll_hz == 30
    stream.close()
    assert hand.status(fingers=False).poll_hz == before


def test_a_finger_switched_off_reports_an_event_and_refuses_commands(hand: Hand) -> None:
    assert hand.power(2, "off")[2] == "off"
    event = hand.next_event(timeout=0.1)
    assert event is not None and (event.finger, event.event) == (2, "unpowered")
    with pytest.raises(RouteError) as caught:
        hand.fingers[2].command((0.1, 0.1, 0.1), unhomed=True)
    assert caught.value.status == RouteStatus.UNPOWERED and caught.value.finger == 2
    assert hand.fingers[2].deadband() == FALLBACK_DEADBAND_HALL  # it cannot be asked
    state = hand.status()
    assert state.fingers[2].power == "off" and not state.fingers[2].present


def test_a_finger_that_breaks_away_is_reported_lost_and_its_routes_fail(hand: Hand) -> None:
    seen: list[FingerEvent] = []
    hand.subscribe(seen.append)
    hand.set_poll_rate(100)
    hand.session.sleep(0.05)
    emulator_of(hand).break_away(3)
    hand.session.sleep(0.1)  # three missed polls at 100 Hz: 30 ms
    assert [(e.finger, e.event) for e in seen] == [(3, "lost")]
    with pytest.raises(RouteError) as caught:
        hand.fingers[3].motor.request("fmcb.status")
    assert caught.value.status == RouteStatus.LINK_DOWN
    assert "broken away" in str(caught.value)
    assert hand.fingers[0].status().present  # the others carry on
