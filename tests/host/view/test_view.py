"""The live view (host.view.live): what it draws, from which clock, at what cost to the loop.

The view writes a rerun file here (``save=``) and the tests read it back with rerun's own
reader: the data the browser page would get.  The browser itself: tests/tools/
test_view_browser.py.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest

rr = pytest.importorskip("rerun", reason="the view needs rerun-sdk (the 'view' extra)")

from hil_emulator.faults.control import ControlChannel  # noqa: E402
from hil_emulator.inprocess import forget_shared_emulators  # noqa: E402
from host.arm.facade import Arm  # noqa: E402
from host.arm.kinematics import forward  # noqa: E402
from host.arm.recording import ArmRecorder  # noqa: E402
from host.view.geometry import (  # noqa: E402
    arm_skeleton,
    finger_skeleton,
    palm_on_flange,
)
from host.view.live import RobotView  # noqa: E402
from protocol.robot import FINGER_LINK_LENGTHS_M, HAND_LAYOUTS  # noqa: E402
from tests.ground_truth import emulator_of  # noqa: E402
from tools.cli import robot_view  # noqa: E402

ROOT = Path(__file__).resolve().parents[3]


def rows(path: Path, entity: str) -> list[tuple[float, Any]]:
    """(time s, value) of every temporal row of ``entity`` in the rerun file ``path``:
    the scalars of a time series, the text of a text log, the strips of lines."""
    out = []
    for chunk in rr.chunk.RrdReader(str(path)).stream():
        if chunk.entity_path != entity:
            continue
        batch = chunk.to_record_batch()
        if "time" not in batch.schema.names:
            continue
        times = [t / 1e9 for t in batch.column("time").cast("int64").to_pylist()]
        column = next(n for n in ("TextLog:text", "Scalars:scalars", "LineStrips3D:strips")
                      if n in batch.schema.names)
        out += [(round(t, 6), v[0] if column == "TextLog:text" else v)
                for t, v in zip(times, batch.column(column).to_pylist(), strict=True)]
    return sorted(out, key=lambda r: r[0])


@pytest.fixture()
def arm():
    with Arm.open("emu://arm/arm?name=test_view") as arm:
        arm.torque(True)
        yield arm
    forget_shared_emulators()


# --- geometry from protocol.robot ----------------------------------------------------------
def test_the_arm_skeleton_ends_at_the_flange_of_the_forward_kinematics() -> None:
    q = [0.3, -0.4, 0.2, 0.9, -0.1, 0.5, 0.2]
    points, (tip, rotation) = arm_skeleton(q)
    assert points.shape == (9, 3)
    assert np.allclose(points[-1], forward(q).position)
    assert np.allclose(rotation, forward(q).rotation)
    assert np.allclose(arm_skeleton([0.0] * 7)[0][-1], (0.0, 0.0, -0.68))


def test_a_straight_finger_reaches_its_link_lengths_along_its_mount() -> None:
    mount = HAND_LAYOUTS["four-finger-thumb"].mounts[1]
    points = finger_skeleton("four-finger-thumb", 1, [0.0, 0.0, 0.0])
    assert np.allclose(points[1], mount.position_m)
    assert np.allclose(points[-1] - points[1],
                       sum(FINGER_LINK_LENGTHS_M) * mount.rotation()[:, 0])
    bent = finger_skeleton("four-finger-thumb", 1, [0.0, 1.0, 0.0])
    assert bent[-1][2] > points[-1][2] + 0.05  # flexion curls towards the pads (+z)


def test_the_hand_hangs_below_the_flange_of_the_hanging_arm() -> None:
    _, flange = arm_skeleton([0.0] * 7)
    palm_at, _ = palm_on_flange(flange)
    tip = finger_skeleton("four-finger-thumb", 1, [0, 0, 0], palm_on_flange(flange))[-1]
    assert palm_at[2] < flange[0][2]
    assert tip[1] > palm_at[1] + 0.05  # the fingers extend along the flange's +y


# --- what is drawn -------------------------------------------------------------------------
def test_the_view_draws_the_arm_on_the_links_clock_at_its_rate(arm: Arm, tmp_path: Path
                                                                 ) -> None:
    rrd = tmp_path / "arm.rrd"
    with RobotView(serve=False, save=rrd, max_rate_hz=20.0) as view:
        arm.watch(view)
        states = [arm.cycle() for _ in range(300)]
    drawn = rows(rrd, "/arm/joints")
    counters = rows(rrd, "/arm/bus")
    assert view.dropped == 0 and view.offered == len(drawn) + len(counters)
    assert [t for t, _ in counters] == [states[0].t, *(t for t, _ in counters[1:])]
    assert all(b - a >= 1.0 for (a, _), (b, _) in zip(counters, counters[1:], strict=False))
    span = states[-1].t - states[0].t
    assert abs(len(drawn) - span * 20.0) <= 2  # 20 a second of simulated time, not 300
    by_t = {s.t: s for s in states}
    for t, values in drawn:
        assert values[:7] == pytest.approx(by_t[t].joints)  # each drawn at its own time
        assert values[7:11] == pytest.approx([s.goal for s in by_t[t].steppers])
    assert rows(rrd, "/world/arm") and rows(rrd, "/arm/torque_nm") and rows(rrd, "/arm/bus")


def test_a_full_queue_drops_states_and_never_waits(tmp_path: Path) -> None:
    view = RobotView(serve=False, save=tmp_path / "x.rrd", queue_size=2, max_rate_hz=1e9)
    release = threading.Event()
    drawing = view.renderer.message

    def slow(topic: str, t: float, payload: Mapping[str, Any]) -> None:  # the logging thread is stuck
        release.wait(30)
        drawing(topic, t, payload)

    view.renderer.message = slow  # type: ignore[method-assign]  # the test stalls this instance's
    for k in range(20):
        view.sample("/arm/bus/stats", float(k), {"requests": k})
    assert view.offered == 20
    assert view.dropped >= 20 - 4  # the queue holds 2, the thread took at most one batch
    release.set()
    view.close()
    assert view.drawn == view.offered - view.dropped


def test_an_injected_fault_appears_as_an_alarm_when_it_acts(arm: Arm, tmp_path: Path) -> None:
    """servo_overheat through the control channel's request handling: J5's OVERHEATING
    alarm comes over the wire in its status packets and is drawn at that time."""
    rrd = tmp_path / "fault.rrd"
    emulator = emulator_of(arm)
    control = ControlChannel(emulator, str(tmp_path / "control"))
    with RobotView(serve=False, save=rrd, max_rate_hz=1000.0, queue_size=4096) as view:
        arm.watch(view)
        for _ in range(50):
            arm.cycle()
        answer = control.handle_line(json.dumps({
            "op": "inject", "fault": "servo_overheat",
            "params": {"servo": 5, "temperature_c": 95}, "at_s": 0.1}).encode())
        assert answer["ok"], answer
        injected_at = answer["t_us"] / 1e6 + 0.1
        first = None
        for _ in range(400):
            state = arm.cycle()
            if first is None and "J5" in state.errors:
                first = state.t
    control.close()
    assert first is not None and first >= injected_at
    alarms = rows(rrd, "/alarms")
    assert [text for _, text in alarms] == ["J5: OVERHEATING"]
    assert alarms[0][0] == pytest.approx(first)


def test_a_recording_replays_as_it_was_drawn_live(arm: Arm, tmp_path: Path) -> None:
    live, replayed, mcap = tmp_path / "live.rrd", tmp_path / "replay.rrd", tmp_path / "a.mcap"
    with RobotView(serve=False, save=live, max_rate_hz=1e6, queue_size=4096) as view, \
            ArmRecorder(arm, mcap):
        arm.watch(view)
        for k in range(120):
            arm.cycle(arm.make_positions([0.0, 0.2 * (k > 60), 0, 0.4, 0, 0, 0]))
    assert view.dropped == 0
    assert robot_view.main(["replay", str(mcap), "--save", str(replayed)]) == 0
    for entity in ("/arm/joints", "/arm/torque_nm", "/world/arm"):
        assert rows(replayed, entity) == rows(live, entity), entity


def test_replay_refuses_a_file_that_is_not_a_recording(tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]
                                                       ) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file at all")
    assert robot_view.main(["replay", str(bad), "--save", str(tmp_path / "x.rrd")]) == 1
    assert "not an MCAP recording" in capsys.readouterr().err
    assert robot_view.main(["replay", str(tmp_path / "absent.mcap")]) == 2


# --- lazily imported -----------------------------------------------------------------------
def test_plain_host_use_never_imports_rerun() -> None:
    code = ("import sys, host.arm.facade, host.hand.facade, host.view.live, tools.cli.armctl, "
            "tools.cli.handctl; "
            "print('rerun' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, check=True).stdout
    assert out.strip() == "False"


@pytest.mark.process_wide("rerun serves its web viewer until the process ends")
def test_the_view_tour_draws_the_arm_and_the_hand_in_one_view() -> None:
    from tools.examples import view_tour

    try:
        seen = view_tour.main(web_port=0)
    finally:
        forget_shared_emulators()
    assert str(seen["address"]).startswith("http://127.0.0.1:")
    assert seen["drawn"] and seen["dropped"] == 0


def test_the_hand_is_drawn_on_the_flange_where_the_arm_moves(arm: Arm, tmp_path: Path
                                                              ) -> None:
    from host.hand.state import FingerState, HandState

    rrd = tmp_path / "hand.rrd"
    hand = HandState(0.5, [FingerState(k) for k in range(4)])
    hand.fingers[2].joints_hall = [0, 300, 200]
    with RobotView(serve=False, save=rrd) as view:
        first = arm.cycle()
        view.renderer.message("/arm/state", 0.4, first.as_dict())
        view.renderer.message("/hand/state", 0.5, hand.to_dict())
        moved = [0.5, 0.2, 0.1, 0.3, 0.0, 0.4, 0.2]
        view.renderer.message("/arm/state", 0.6, {**first.as_dict(), "joints": moved})
    places = []
    for chunk in rr.chunk.RrdReader(str(rrd)).stream():
        if chunk.entity_path == "/world/hand":
            batch = chunk.to_record_batch()
            places += [row[0] for row in batch.column("Transform3D:translation").to_pylist()]
    expected = [palm_on_flange(arm_skeleton(q)[1])[0] for q in (first.joints, moved)]
    assert np.allclose(places, expected, atol=1e-5)  # placed when drawn, moved with the arm
    fingers = rows(rrd, "/world/hand/fingers")
    assert len(fingers) == 1 and len(fingers[0][1]) == 4  # four fingers, in the palm frame
    bent = finger_skeleton("four-finger-thumb", 2, hand.fingers[2].joints)
    assert np.allclose(fingers[0][1][2], bent, atol=1e-5)  # float32 in rerun


def test_a_breakaway_injected_on_the_control_channel_shows_as_the_fingers_alarm(
        tmp_path: Path) -> None:
    """The palm's finger event comes over the wire and is drawn at its time; the finger's
    next status says why it is gone, as an alarm, until it is back."""
    from host.hand.facade import Hand

    rrd = tmp_path / "hand.rrd"
    try:
        with RobotView(serve=False, save=rrd, max_rate_hz=1000.0) as view, \
                Hand.open("emu://hand/palm?name=test_view_hand", view=view) as hand:
            emulator = emulator_of(hand)
            control = ControlChannel(emulator, str(tmp_path / "control"))
            hand.set_poll_rate(100)
            hand.session.sleep(0.05)
            answer = control.handle_line(json.dumps({
                "op": "inject", "fault": "break_away", "params": {"finger": 3}}).encode())
            assert answer["ok"], answer
            hand.session.sleep(0.1)
            gone = hand.status()
            control.close()
    finally:
        forget_shared_emulators()
    alarms = rows(rrd, "/alarms")
    texts = [text for _, text in alarms]
    assert texts[0] == "finger 3: lost"
    assert alarms[0][0] >= answer["t_us"] / 1e6
    problem = gone.fingers[3].problem
    assert problem and f"finger 3: {problem}" in texts
