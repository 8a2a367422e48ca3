"""``kill -9`` of ``armctl move`` at ten random moments of a 6 s move while another program
on its own USB–RS-485 adapter (``hil-emulator --arm-adapters 2``) READs all seven joints
every 20 ms for the whole run (:mod:`tests.tools.joint_reader`, normal priority), through
the ptys of one ``hil-emulator --config full --ready`` subprocess: the host set the stepper
nodes' ``watchdog_feed`` to goals only, so the reader's READs do not keep its stale goals
driving the arm, and the host rides out the collisions the reader's traffic causes.
Judged on the plant's ground truth (the emulator's ``truth``), on its clock."""

from __future__ import annotations

import json
import math
import os
import random
import signal
import subprocess
import sys
import time
from typing import Any

import dynamixel_sdk as sdk
import pytest

from protocol.control_tables import STEPPER_TABLE, StepperFlag
from tests.hil_emulator.emulator_process import (
    HANG_GUARD_S,
    ROOT,
    running_emulator,
    wait_simulated,
)
from tests.tools.test_armctl_killed import GOAL, armctl, truth_raw

#: The move: from START out to GOAL in MOVE_S.
START = ["0", "0.3", "0", "0.4", "0", "0", "0"]
MOVE_S = 6.0
#: Kills that must land mid-move, and the attempts allowed for them (a kill that lands
#: before the move starts or after it ends is not counted).
KILLS = 10
ATTEMPTS = KILLS + 6
#: Bounds (the plant's truth, from the first sample after the kill): driving on beyond
#: what the move carries in HORIZON_S at the kill's speed, falling back, and coming to rest
#: (every joint under REST_SPEED).
RUN_ON_DEG = 2.0
FALL_DEG = 2.0
HORIZON_S = 0.5
REST_S = 1.2
REST_SPEED = 0.02  # rad/s
#: A stepper joint this fast (rad/s) says the move has started.
MOVING_SPEED = 0.05
_ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def _until_moving(info: dict[str, Any], move: subprocess.Popen[bytes]) -> dict[str, Any]:
    """The truth at the first sample with a stepper joint moving (None: armctl ended)."""
    guard = time.monotonic() + HANG_GUARD_S
    while time.monotonic() < guard and move.poll() is None:
        raw = truth_raw(info)
        if any(abs(v) > MOVING_SPEED for v in raw["arm"]["velocities"][:4]):
            return raw
        time.sleep(0.01)
    return {}


def kill_mid_move(info: dict[str, Any], port: str, after_s: float,
                  watch_s: float = 2.5) -> dict[str, Any]:
    """Start ``armctl move`` to GOAL, ``kill -9`` it ``after_s`` of simulated time after its
    joints start moving, and judge the next ``watch_s`` simulated seconds on the plant's
    truth; the figures, ``"mid_move"`` False when the kill missed the move."""
    move = subprocess.Popen(
        [sys.executable, "-m", "tools.cli.armctl", "--port", port, "move", "--joints",
         *GOAL, "--duration", str(MOVE_S)], cwd=ROOT, env=_ENV, stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL)
    try:
        started = _until_moving(info, move)
        while started and truth_raw(info)["t_us"] - started["t_us"] < after_s * 1e6:
            time.sleep(0.005)
    finally:
        move.send_signal(signal.SIGKILL)
        killed = move.wait() == -signal.SIGKILL  # not exited by itself first
    raw = [truth_raw(info)]
    while raw[-1]["t_us"] - raw[0]["t_us"] < watch_s * 1e6:
        time.sleep(0.01)
        raw.append(truth_raw(info))
    rows = [{**r["arm"], "t_us": r["t_us"]} for r in raw]
    first = rows[0]
    q0, v0 = first["joints"], first["velocities"]
    run_on = [0.0] * 7
    back = [0.0] * 7
    for r in rows:
        for j in range(7):
            d = r["joints"][j] - q0[j]
            way = 1.0 if v0[j] > REST_SPEED else -1.0 if v0[j] < -REST_SPEED else 0.0
            if way:
                run_on[j] = max(run_on[j], math.degrees(way * d) - math.degrees(
                    abs(v0[j]) * HORIZON_S))
                back[j] = max(back[j], -math.degrees(way * d))
            else:
                back[j] = max(back[j], abs(math.degrees(d)))
    moving = [r["t_us"] for r in rows if any(abs(v) >= REST_SPEED for v in r["velocities"])]
    rest_s = ((moving[-1] - rows[0]["t_us"]) / 1e6 if moving else 0.0)
    latches = int(StepperFlag.SLIP | StepperFlag.STALLED)
    latched = sorted({k for r in rows for k, n in r["nodes"].items()
                      if n["status_flags"] & latches or n["alarms"] or not n["torque_enable"]})
    return {"after_s": round(after_s, 3), "exit_before_kill": not killed,
            "mid_move": bool(started) and killed and any(abs(v) > REST_SPEED for v in v0[:4]),
            "run_on_deg": round(max(run_on), 3), "back_deg": round(max(back), 3),
            "rest_s": round(rest_s, 3),
            "still_moving": bool(moving) and moving[-1] == rows[-1]["t_us"],
            "latched": latched,
            "flags": {k: n["status_flags"] for k, n in rows[-1]["nodes"].items()}}


def held(figures: dict[str, Any]) -> bool:
    """The Done-when bounds."""
    return (figures["run_on_deg"] <= RUN_ON_DEG and figures["back_deg"] <= FALL_DEG
            and not figures["latched"] and not figures["still_moving"]
            and figures["rest_s"] <= REST_S)


def set_up(port: str, *args: str) -> None:
    """``armctl ARGS`` before the kills (not what is judged), tried twice: on a machine
    overloaded by other work the first ``torque on`` once exited 1; the error is kept in
    the message."""
    for _ in range(2):
        done = subprocess.run([sys.executable, "-m", "tools.cli.armctl", "--port", port,
                               *args], cwd=ROOT, env=_ENV, capture_output=True, text=True,
                              timeout=180)
        if done.returncode == 0:
            return
    raise AssertionError(f"armctl {' '.join(args)} failed twice: {done.stderr}")


def back_to_start(port: str) -> None:
    """The move back to START (its own clean session; exit 0 or 3, not settled).  Not what
    is judged: on a machine busy with other tests the 5 s move back from near the stops
    twice latched J4 STALLED (the node held, exit 1); then the latch is cleared and the move
    made again over 10 s."""
    for duration in ("5", "10"):
        subprocess.run([sys.executable, "-m", "tools.cli.armctl", "--port", port, "clear"],
                       cwd=ROOT, env=_ENV, capture_output=True, timeout=120)
        back = subprocess.run([sys.executable, "-m", "tools.cli.armctl", "--port", port,
                               "move", "--joints", *START, "--duration", duration], cwd=ROOT,
                              env=_ENV, capture_output=True, text=True, timeout=120)
        if back.returncode in (0, 3):
            return
    raise AssertionError(f"the move back to the start failed twice: {back.stderr}")


def start_reader(port: str) -> subprocess.Popen[str]:
    """The joint reader on ``port``, its port open."""
    reader = subprocess.Popen([sys.executable, "-m", "tests.tools.joint_reader", port],
                              cwd=ROOT, env=_ENV, stdout=subprocess.PIPE,
                              stderr=subprocess.DEVNULL, text=True)
    assert reader.stdout is not None and reader.stdout.readline().strip() == "reading"
    return reader


def stop_reader(reader: subprocess.Popen[str]) -> dict[str, Any]:
    """Stop the reader; what it counted."""
    reader.send_signal(signal.SIGTERM)
    out, _ = reader.communicate(timeout=HANG_GUARD_S)
    return dict(json.loads(out.strip().splitlines()[-1]))


@pytest.mark.slow
def test_armctl_killed_at_ten_moments_with_a_reader_on_the_bus_leaves_the_arm_held() -> None:
    with running_emulator("--config", "full", "--ready", "--can", "none",
                          "--arm-adapters", "2") as info:
        port, reader_port = info["arm_adapters"]
        assert port == info["arm"]
        reader = start_reader(reader_port)  # for the whole run, homing and moves too
        try:
            set_up(port, "torque", "on")
            set_up(port, "home")
            back_to_start(port)
            rng = random.Random(41)
            runs = []
            for _ in range(ATTEMPTS):
                runs.append(kill_mid_move(info, port, rng.uniform(0.0, MOVE_S - 0.3)))
                if sum(r["mid_move"] for r in runs) == KILLS:
                    break
                back_to_start(port)
        finally:
            reads = stop_reader(reader)
        print(json.dumps({"runs": runs, "reader": reads}))  # the figures (pytest -s)
        kills = [r for r in runs if r["mid_move"]]
        assert len(kills) == KILLS, runs
        assert [r for r in kills if not held(r)] == [], (kills, reads)
        # The reader read the whole time: its polls kept their period, and it got answers.
        assert reads["answered"] > reads["reads"] / 2, reads


@pytest.mark.slow
def test_the_stock_sdk_write_once_then_poll_move_reaches_its_goal_after_armctl() -> None:
    """After an ``armctl`` session closed cleanly (it gave the nodes back the default
    ``watchdog_feed``), a plain dynamixel-sdk program writes J1's goal once and polls it:
    its READs keep the move going to the goal, longer than the watchdog's timeout."""
    with running_emulator("--config", "full", "--ready", "--can", "none") as info:
        port = info["arm"]
        assert armctl(port, "torque", "on")[0] == 0
        handler = sdk.PortHandler(port)
        assert handler.openPort() and handler.setBaudRate(1_000_000)
        try:
            packets = sdk.PacketHandler(1.0)
            feed = STEPPER_TABLE["watchdog_feed"]
            for dxl_id in range(1, 5):
                value, result, _ = packets.read1ByteTxRx(handler, dxl_id, feed.address)
                assert result == sdk.COMM_SUCCESS and value == 0, (dxl_id, value)
            at = STEPPER_TABLE["present_position"].address
            start, result, _ = packets.read4ByteTxRx(handler, 1, at)
            assert result == sdk.COMM_SUCCESS
            start = start - (1 << 32) if start & 0x8000_0000 else start
            goal = start + 2000  # 72°: seconds at the node's speed, far over its watchdog
            speed = STEPPER_TABLE["velocity_limit"]
            assert packets.write4ByteTxRx(handler, 1, speed.address, 1000)[0] == sdk.COMM_SUCCESS
            result, _ = packets.write4ByteTxRx(handler, 1, STEPPER_TABLE["goal_position"].address,
                                               goal & 0xFFFF_FFFF)
            assert result == sdk.COMM_SUCCESS
            deadline = time.monotonic() + 120
            present = start
            while time.monotonic() < deadline:
                value, result, _ = packets.read4ByteTxRx(handler, 1, at)
                if result == sdk.COMM_SUCCESS:
                    present = value - (1 << 32) if value & 0x8000_0000 else value
                    if abs(present - goal) <= 40:
                        break
                time.sleep(0.02)
            assert abs(present - goal) <= 40, (start, present, goal)
        finally:
            handler.closePort()
        wait_simulated(info, 0.1)
