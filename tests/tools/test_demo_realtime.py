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
def test_the_realtime_demo_flashes_through_the_ptys_and_lifts_the_mug(tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "tools.demo", "--realtime", "--out",
                           str(tmp_path)], cwd=ROOT, capture_output=True, text=True,
                          timeout=1100, env={**os.environ, "PYTHONPATH": str(ROOT)})
    out = proc.stdout
    assert "Traceback" not in out + proc.stderr
    # The flashing step, which failed every run while the demo held the palm port.
    assert "firmware: 12 nodes now run" in out, out[-3000:]
    assert "another program" not in out
    last = out.strip().splitlines()[-1]
    assert proc.returncode == 0 and last.startswith("demo: OK (mug lifted "), out[-3000:]
    for step in ("wire:", "firmware:", "homing:", "reach:", "grasp:", "lift:", "park:"):
        assert f"] {step}" in out
