"""The browser view in a real browser: headless Chromium opens the locally served page
during a short emulated session and the robot and its time series are drawn.

Slow (a browser, WebGL in software); skipped, saying why, where no Chromium is installed
(``apt-get install chromium``).  ``VIEW_SCREENSHOT=path`` keeps the screenshot (the one in
docs/ is made so).
"""

from __future__ import annotations

import os
import shutil
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rerun", reason="the view needs rerun-sdk (the 'view' extra)")
pytest.importorskip("websockets", reason="the browser is driven with websockets (the test extra)")

from host.arm.facade import Arm  # noqa: E402
from host.view.live import RobotView  # noqa: E402
from host.view.render import ARM_RGB, JOINT_RGB  # noqa: E402
from tests.tools.headless_browser import Browser, find_browser  # noqa: E402

BROWSER = find_browser()
pytestmark = [
    pytest.mark.slow,
    pytest.mark.process_wide("rerun serves its web viewer until the process ends"),
    pytest.mark.skipif(BROWSER is None, reason="no Chromium on this machine (apt-get install "
                                              "chromium): the browser test cannot run"),
]


def count_near(image: np.ndarray, rgb: tuple[int, int, int], tolerance: int = 40) -> int:
    """Pixels of ``image`` (H×W×3, 0..255) within ``tolerance`` of ``rgb`` on every channel."""
    return int(np.all(np.abs(image - np.array(rgb)) <= tolerance, axis=-1).sum())


def drawn(shot: Path) -> tuple[int, int]:
    """(arm pixels in the left part, joint-series pixels in the right part) of a screenshot."""
    from matplotlib.image import imread

    image = (imread(str(shot))[..., :3] * 255.0).astype(int)
    split = int(image.shape[1] * 0.55)
    arm = count_near(image[:, :split], ARM_RGB)
    series = sum(min(count_near(image[:, split:], rgb, 30), 400) for rgb in JOINT_RGB)
    return arm, series


def test_the_browser_draws_the_arm_and_its_time_series(tmp_path: Path) -> None:
    view = RobotView(web_port=0)
    arm = Arm.open("emu://arm/arm?name=view_browser", view=view)
    stop = threading.Event()

    def session() -> None:  # the arm swings J1, J2 and J4 while the page loads
        arm.torque(True)
        k = 0
        while not stop.is_set():
            swing = 0.4 * ((k // 150) % 2)
            arm.cycle(arm.make_positions([swing, 0.3 + swing, 0.0, 0.6, 0.2, 0.3, 0.0]))
            k += 1

    runner = threading.Thread(target=session, daemon=True)
    runner.start()
    shot = tmp_path / "view.png"
    try:
        assert BROWSER is not None
        with Browser(BROWSER) as browser:
            browser.open(view.address or "")
            found = (0, 0)
            deadline = time.monotonic() + 150  # WebGL in software on a busy machine
            while time.monotonic() < deadline:
                time.sleep(3)
                browser.screenshot(shot)
                found = drawn(shot)
                if found[0] > 200 and found[1] > 200:
                    break
            canvas = browser.evaluate(
                "(() => { const c = document.querySelector('canvas');"
                " return c ? [c.width, c.height] : null; })()")
    finally:
        stop.set()
        runner.join(timeout=30)
        arm.close()
        view.close()
    if os.environ.get("VIEW_SCREENSHOT"):
        shutil.copy(shot, os.environ["VIEW_SCREENSHOT"])
    assert canvas is not None and canvas[0] > 0 and canvas[1] > 0, "the page has no canvas"
    assert found[0] > 200, f"the arm is not drawn (orange pixels: {found[0]}; see {shot})"
    assert found[1] > 200, f"the joint series are not drawn ({found[1]} pixels; see {shot})"
    assert view.drawn > 0
