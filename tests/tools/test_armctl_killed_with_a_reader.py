"""``kill -9`` of ``armctl move`` mid-move while another process READs the seven joints
over the same arm port every 20 ms (:mod:`tests.tools.joint_reader`), through the ptys of a
``hil-emulator --config full --ready`` subprocess: the host set the stepper nodes'
``watchdog_feed`` to goals only, so the reader's READs do not keep its stale goals driving
the arm.  Judged on the plant's ground truth (the emulator's ``truth``), on its clock."""

from __future__ import annotations

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
    ROOT,
    running_emulator,
    wait_simulated,
)
from tests.tools.test_armctl_killed import GOAL, armctl, truth_raw

#: The move: from the homed pose out to GOAL in 6 s.
START = ["0", "0.3", "0", "0.4", "0", "0", "0"]
#: Bounds (the plant's truth, from the first sample after the kill): driving on beyond
#: what the move carries in HORIZON_S at the kill's speed, falling back, and coming to rest
#: (every joint under REST_SPEED).
RUN_ON_DEG = 2.0
FALL_DEG = 2.0
HORIZON_S = 0.5
REST_S = 1.2
REST_SPEED = 0.02  # rad/s
#: How long (wall s) the reader polls before the kill.
READ_BEFORE_S = 0.15
_ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def kill_mid_move(info: dict[str, Any], delay_s: float, watch_s: float = 2.5) -> dict[str, Any]:
    """Start ``armctl move`` to GOAL (6 s) with a reader polling, ``kill -9`` it ``delay_s``
    (wall) after the start, and judge the next ``watch_s`` simulated seconds on the
    plant's truth; the figures, ``"mid_move"`` False when the kill missed the move."""
    port = info["arm"]
    reader = subprocess.Popen([sys.executable, "-m", "tests.tools.joint_reader", port],
                              cwd=ROOT, env=_ENV, stdin=subprocess.PIPE,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, text=True)
    try:
        move = subprocess.Popen(
            [sys.executable, "-m", "tools.cli.armctl", "--port", port, "move", "--joints",
             *GOAL, "--duration", "6"], cwd=ROOT, env=_ENV, stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL)
        time.sleep(delay_s)
        assert reader.stdin is not None
        reader.stdin.write("go\n")
        reader.stdin.flush()
        time.sleep(READ_BEFORE_S)  # the reader's READs flowing when the host dies
        move.send_signal(signal.SIGKILL)
        killed = move.wait() == -signal.SIGKILL  # not exited by itself first
        raw = [truth_raw(info)]
        while raw[-1]["t_us"] - raw[0]["t_us"] < watch_s * 1e6:
            time.sleep(0.01)
            raw.append(truth_raw(info))
    finally:
        reader.send_signal(signal.SIGKILL)
        reader.wait()
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
    return {"mid_move": killed and any(abs(v) > REST_SPEED for v in v0[:4]),
            "run_on_deg": max(run_on), "back_deg": max(back), "rest_s": rest_s,
            "still_moving": bool(moving) and moving[-1] == rows[-1]["t_us"],
            "latched": latched, "flags": {k: n["status_flags"] for k, n in rows[-1]["nodes"].items()}}




def held(figures: dict[str, Any]) -> bool:
    """The Done-when bounds."""
    return (figures["run_on_deg"] <= RUN_ON_DEG and figures["back_deg"] <= FALL_DEG
            and not figures["latched"] and not figures["still_moving"]
            and figures["rest_s"] <= REST_S)


def back_to_start(port: str) -> None:
    """The move back to START (its own clean session; exit 0 or 3, not settled)."""
    subprocess.run([sys.executable, "-m", "tools.cli.armctl", "--port", port, "clear"],
                   cwd=ROOT, env=_ENV, capture_output=True, timeout=120)
    assert armctl(port, "move", "--joints", *START, "--duration", "5")[0] in (0, 3)


@pytest.mark.slow
def test_armctl_killed_mid_move_with_a_reader_on_the_bus_leaves_the_arm_held() -> None:
    with running_emulator("--config", "full", "--ready", "--can", "none") as info:
        port = info["arm"]
        assert armctl(port, "torque", "on")[0] == 0
        assert armctl(port, "home")[0] == 0
        assert armctl(port, "move", "--joints", *START, "--duration", "3")[0] in (0, 3)
        rng = random.Random(41)
        for _ in range(4):  # until a kill lands mid-move (start-up is slow on a busy machine)
            figures = kill_mid_move(info, 2.0 + rng.uniform(0.3, 4.0))
            if figures["mid_move"]:
                break
            back_to_start(port)
        else:
            pytest.fail("no kill landed mid-move")
        assert held(figures), figures


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
