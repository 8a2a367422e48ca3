"""``python -m tools.demo --realtime``: the demo against a ``hil-emulator`` subprocess
through its ptys, paced to the wall clock: the thirteen hand MCUs identified and the arm's
joints pinged with dynamixel-sdk over the wire first, then the same steps as in process
(:mod:`tools.demo.script`), and at the end how well the emulator kept the wall clock.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

from host.arm.facade import Arm, host_watchdog_ms
from host.hand.facade import Hand
from host.scheduling import HOST_RT_PRIORITY, priority_for
from tools.build_compiled import ROOT
from tools.demo.plan import DEMO_SENSORS
from tools.demo.script import Demo, judge, open_watch, run_session, write_run_report
from tools.errors import DemoFailed


@contextlib.contextmanager
def emulator_process(link_dir: Path, seed: int, sensors: str = DEMO_SENSORS,
                     profile: Path | None = None
                     ) -> Iterator[tuple[dict[str, Any], subprocess.Popen[str]]]:
    extra = [] if profile is None else ["--profile", str(profile.resolve())]
    proc = subprocess.Popen(
        [sys.executable, "-m", "tools.cli.serve_emulator", "--config", "full", "--scene", "mug",
         "--ready", "--stats", "--seed", str(seed), "--sensors", sensors,
         "--link-dir", str(link_dir), *extra],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        if not line:
            err = proc.stderr.read() if proc.stderr else ""
            raise DemoFailed("emulator", f"hil-emulator did not start: {err.strip()[-300:]}")
        yield json.loads(line), proc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()


def _final_stats(proc: subprocess.Popen[str]) -> dict[str, Any]:
    err = proc.stderr.read() if proc.stderr else ""
    for line in err.splitlines():
        if line.startswith("hil-emulator stats: "):
            return dict(json.loads(line.split(": ", 1)[1]))
    return {}


def _lateness(stats: Mapping[str, Any]) -> str:
    """How well the emulator kept the wall clock, from its ``--stats`` (one phrase): a
    late robot is the first suspect when an elastic joint stalls in real time."""
    if stats.get("p99_ms") is None:
        return "reported no lateness"
    return (f"{stats.get('scheduling', '?')}, late by {stats['p99_ms']:.2f} ms at the 99th "
            f"percentile, {stats['max_ms']:.1f} ms at most, {stats.get('slipped_s', 0.0):.2f} s "
            "slipped behind the wall clock")


def over_the_wire(ports: Mapping[str, Any], say: Callable[[str], None]) -> None:
    """Identify the thirteen hand MCUs; ping the arm's seven joints with dynamixel-sdk."""
    from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

    from protocol.topology import ARM_BUS_BAUD, ARM_JOINTS

    with Hand.open(ports["palm"]) as hand:
        nodes = hand.discover()
        answered = [n for n in nodes if n.answered]
        say(f"{len(answered)} of {len(nodes)} hand MCUs answered over the pty")
        if len(answered) != len(nodes):
            raise DemoFailed("wire", "not every hand MCU answered: "
                             + ", ".join(f"{n.where}: {n.problem}" for n in nodes
                                         if not n.answered))
    port = PortHandler(ports["arm"])
    if not (port.openPort() and port.setBaudRate(ARM_BUS_BAUD)):
        raise DemoFailed("wire", f"cannot open the arm port {ports['arm']}")
    try:
        sdk = PacketHandler(1.0)
        models = []
        for joint in ARM_JOINTS:
            model, result = 0, -1
            for _ in range(6):  # the SDK's own timeout is tight for a pty on a busy machine
                try:
                    model, result, _ = sdk.ping(port, joint.dxl_id)
                except IndexError:  # the SDK indexes a reply it did not get
                    continue
                if result == COMM_SUCCESS:
                    break
            if result != COMM_SUCCESS:
                why = sdk.getTxRxResult(result) if result != -1 else "no reply"
                raise DemoFailed("wire", f"arm id {joint.dxl_id} did not answer dynamixel-sdk's "
                                         f"ping ({why})")
            models.append(f"{joint.dxl_id}:{model:#06x}")
        say(f"dynamixel-sdk pinged the arm's 7 joints ({' '.join(models)})")
    finally:
        port.closePort()


def run_realtime(out: Path, seed: int, view_port: int | None = None,
                 sensors: str = DEMO_SENSORS, profile: Path | None = None,
                 arm_calibration: str | None = None) -> tuple[bool, str]:
    wall0 = time.monotonic()
    link_dir = Path(tempfile.mkdtemp(prefix="demo-links-"))
    try:
        print("[wall    0.0 s] emulator: starting hil-emulator --config full --scene mug "
              "--ready (the hand brought up in simulated time first)", flush=True)
        with emulator_process(link_dir, seed, sensors, profile) as (ports, proc):
            def say(text: str) -> None:
                print(f"[wall {time.monotonic() - wall0:6.1f} s] wire: {text}", flush=True)

            say(f"ports {ports['palm']} (palm), {ports['arm']} (arm)")
            over_the_wire(ports, say)
            hand = Hand.open(ports["palm"])
            arm = Arm.open(ports["arm"])
            view = open_watch(hand, arm, view_port)

            def reopen_hand() -> Hand:  # the view follows the hand opened again
                reopened = Hand.open(ports["palm"])
                reopened.watch(view)
                return reopened

            demo = Demo(hand, arm, out, palm_port=ports["palm"], reopen_hand=reopen_hand)
            demo.calibrate = sensors != "ideal"
            demo.arm_calibration = arm_calibration
            demo.wall0 = wall0
            try:
                # steady host cycles on a busy machine, below the emulator's own priority
                with priority_for("realtime", HOST_RT_PRIORITY) as got:
                    say(got.describe("the demo's control loop"))
                    arm.set_watchdog(host_watchdog_ms(got))
                    run_session(demo, out)
            finally:
                demo.hand.close()
                arm.close()
                if view is not None:
                    view.close()
                proc.send_signal(signal.SIGINT)
                proc.wait(timeout=20)
                stats = _final_stats(proc)
                print(f"[wall {time.monotonic() - wall0:6.1f} s] emulator: "
                      f"{_lateness(stats)}", flush=True)
                summary = stats.get("scene", {}).get("mug")
                demo.log.result["mug"] = summary or {}
                write_run_report(demo, out)
        if not summary:
            raise DemoFailed("report", "hil-emulator reported no ground truth of the mug")
        return judge(summary)
    finally:
        shutil.rmtree(link_dir, ignore_errors=True)


