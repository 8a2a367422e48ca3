"""``python -m tools.demo --realtime``: the same script against a ``hil-emulator`` process
through its ptys, paced to the wall clock (the flashing step shares the palm port with the
demo's own hand link)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tools.build_compiled import ROOT


@pytest.mark.slow
@pytest.mark.timeout(1200)
def test_the_realtime_demo_flashes_through_the_ptys_and_reaches_the_mug(tmp_path: Path) -> None:
    """The real-time path through the ptys flashes (it failed every run while the demo held
    the palm port), homes, reaches and grasps, and ends with one verdict line.  The lift
    itself is not asserted here: on a busy two-core machine the pure-Python emulator runs
    slower than the wall clock that paces the host's arm loop, and the elastic arm may then
    latch a stall on the way down (the in-process demo test asserts the whole lift).  Ideal
    sensors: the path through the ptys is what this test checks, and the as-built hand's
    calibration would add five minutes of real time (the in-process test runs it)."""
    proc = subprocess.run([sys.executable, "-m", "tools.demo", "--realtime", "--sensors",
                           "ideal", "--out", str(tmp_path)], cwd=ROOT, capture_output=True, text=True,
                          timeout=1100, env={**os.environ, "PYTHONPATH": str(ROOT)})
    out = proc.stdout
    assert "Traceback" not in out + proc.stderr
    assert "firmware: 12 nodes now run" in out, out[-3000:]
    assert "another program" not in out
    for step in ("wire:", "firmware:", "homing:", "reach:", "grasp:"):
        assert f"] {step}" in out, out[-3000:]
    last = out.strip().splitlines()[-1]
    if proc.returncode == 0:
        assert last.startswith("demo: OK (mug lifted "), out[-3000:]
    else:
        assert proc.returncode == 1 and last.startswith("demo: FAILED ("), out[-3000:]
