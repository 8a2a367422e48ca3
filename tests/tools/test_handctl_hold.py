"""handctl interrupted mid-motion (in process, simulation clock): the fingers are held where
they are, exit 130, one line saying which; judged on the finger plant's ground truth."""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest

from hil_emulator import inprocess
from hil_emulator.inprocess import forget_shared_emulators
from host.hand.facade import Hand
from tests.hil_emulator.emulator_process import HANG_GUARD_S
from tools.cli import handctl

URL = "emu://hand/palm?name=test-handctl-hold"


def test_ctrl_c_mid_move_holds_the_finger_where_it_is(
        capsys: pytest.CaptureFixture[str]) -> None:
    """Ctrl-C used to leave the fmcb driving on to the target."""
    forget_shared_emulators()
    try:
        with Hand.open(URL):
            pass  # the emulator comes up (hand ready), shared by name with handctl's
        emulator = next(iter(inprocess._shared.values()))
        plant = emulator.finger_plants[0]
        start = np.array(plant.joint_angles())

        def watch() -> None:  # Ctrl-C once the finger is on its way
            deadline = time.monotonic() + HANG_GUARD_S
            while time.monotonic() < deadline:
                if float(np.max(np.abs(np.array(plant.joint_angles()) - start))) > 0.15:
                    os.kill(os.getpid(), signal.SIGINT)
                    return
                time.sleep(0.002)

        thread = threading.Thread(target=watch, daemon=True)
        thread.start()
        code = handctl.main(["--port", URL, "move", "--finger", "0", "--joints", "0.2,1.2,1.0",
                             "--unhomed", "--duration", "10"])
        thread.join()
        at = np.array(plant.joint_angles())
        assert code == 130
        err = capsys.readouterr().err.strip()
        assert err == "handctl: interrupted; the hand: finger(s) 0 held where they were, " \
                      "motors on", err
        with Hand.open(URL) as hand:
            hand.session.sleep(1.0)
            state = hand.fingers[0].status()
        moved = np.abs(np.array(plant.joint_angles()) - at)
        assert float(moved.max()) < 0.05, moved  # held, not driven on to 1.2 rad
        assert state.targets_hall is not None
        assert max(abs(a - b) for a, b in zip(state.targets_hall, state.joints_hall,
                                              strict=True)) < 60
    finally:
        forget_shared_emulators()
