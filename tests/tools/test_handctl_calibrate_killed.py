"""``kill -9`` of ``handctl calibrate`` while it pushes a finger onto its stops, through the
ptys of a ``hil-emulator --config hand --ready`` subprocess: the fmcb widened its joint
limits for the push at the host's word, and puts back the limits it had by itself once
the host is quiet for :data:`~protocol.robot.FINGER_LIMIT_LEASE_MS` (the emulator's
``truth``, on its clock)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from protocol.robot import FINGER_JOINT_LIMITS, FINGER_LIMIT_LEASE_MS
from tests.hil_emulator.emulator_process import HANG_GUARD_S, ROOT, running_emulator
from tests.tools.test_armctl_killed import truth_raw

#: Truth is read this often (wall s).
POLL_S = 0.05
#: How long after the lease the fmcb may take to put the limits back (s): its check period
#: and the truth's polling.
LEASE_SLACK_S = 0.2


def _finger0(raw: dict[str, Any]) -> dict[str, Any]:
    return dict(raw["hand"]["fingers"][0])


def _widened(finger: dict[str, Any]) -> bool:
    return any(lo < nominal_lo - 1e-3 or hi > nominal_hi + 1e-3
               for (lo, hi), (nominal_lo, nominal_hi)
               in zip(finger["joint_limits"], FINGER_JOINT_LIMITS, strict=True))


@pytest.mark.slow
def test_handctl_calibrate_killed_mid_push_leaves_the_fingers_limits_back(tmp_path: Path
                                                                          ) -> None:
    with running_emulator("--config", "hand", "--ready", "--can", "none") as info:
        calibrate = subprocess.Popen(
            [sys.executable, "-m", "tools.cli.handctl", "--port", info["palm"], "calibrate",
             "--fingers", "0", "--out", str(tmp_path / "calibration.json")],
            cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)},
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            guard = time.monotonic() + 20 * HANG_GUARD_S
            while not _widened(_finger0(truth_raw(info))):  # the poses first, then the stops
                assert calibrate.poll() is None, "calibrate ended before touching a stop"
                assert time.monotonic() < guard, "the limits were never widened"
                time.sleep(POLL_S)
            time.sleep(1.0)  # into the first touch: moving to its start pose or pushing
        finally:
            calibrate.send_signal(signal.SIGKILL)
            calibrate.wait()
        killed = truth_raw(info)
        assert _widened(_finger0(killed)) and _finger0(killed)["limit_lease"]
        while _widened(now := _finger0(raw := truth_raw(info))):
            assert raw["t_us"] - killed["t_us"] < 2 * FINGER_LIMIT_LEASE_MS * 1000
            time.sleep(POLL_S)
        back_s = (raw["t_us"] - killed["t_us"]) / 1e6
        assert not now["limit_lease"]
        assert [v for pair in now["joint_limits"] for v in pair] == pytest.approx(
            [v for pair in FINGER_JOINT_LIMITS for v in pair], abs=1e-6)
        print(f"limits back {back_s:.3f} s after the kill")  # the report's figure (-s)
        assert back_s <= FINGER_LIMIT_LEASE_MS / 1000 + LEASE_SLACK_S, back_s
