"""``hil-emulator``: the emulated hand and arm behind virtual serial ports.

    hil-emulator [--config full|hand|arm|loose-finger] [--link-dir DIR]
                 [--realtime | --fast] [--seed N] [--viewer] [--layout NAME]
                 [--can slcan|none] [--no-physics] [--ready] [--sleep] [--duration S] [--stats]
                 [--faults FILE] [--control PATH] [--scene none|mug|calibration]
                 [--sensors ideal|realistic] [--profile FILE] [--priority realtime|normal]
                 [--arm-adapters N]

Prints exactly one JSON line on standard output once its ports are ready (keys ``palm``,
``arm``, ``fingers`` — a list —, ``arm_adapters`` — the arm bus's adapters, a list whose
first is ``arm`` — and ``can`` where the configuration has them, and ``config``,
``seed``, ``sensors``, ``links``, and ``scene`` when one was asked for), then runs until SIGINT or SIGTERM (or ``--duration`` seconds of wall
time) and exits 0, removing its links.  Diagnostics go to standard error, among them a
line when the real-time loop falls more than 5 ms behind the wall clock (a busy machine)
and one when it is on time again.

``--faults FILE`` loads a fault plan (TOML ``[[faults]]`` tables, see docs/HIL_BENCH.md;
times count from the moment the ports are ready) and prints the timeline on exit with
``--stats``.  A separate process injects faults while it runs through the control socket
(JSON lines, :mod:`hil_emulator.faults.control`): ``DIR/control`` with ``--link-dir DIR``,
or ``--control PATH``; its path is the ``control`` key of the JSON line.

In real time the thread that paces the simulation asks for real-time scheduling
(``SCHED_RR`` at a modest priority) where it is allowed (root, ``CAP_SYS_NICE``, an
``rtprio`` limit) and says on standard error which scheduling it got; ``--priority normal``
does not ask.  Real time sleeps between events (it used to keep a core busy polling unless ``--sleep``
was given); ``--sleep`` is still accepted and changes nothing.  ``--stats`` prints, on
exit, one line ``hil-emulator stats: {JSON}`` to standard error: simulated time, delivery
lateness (``null`` when nothing was delivered), episodes of lateness, ``scheduling`` (the
pacing thread's policy in real time: ``SCHED_RR`` or ``SCHED_OTHER``), ``stop_ms`` (wall
time from SIGINT/SIGTERM or the end of ``--duration`` to the loop's end), per port the
bytes in and out, host input lost to overrun and the longest input queue, and with a
``--scene`` its objects' ground truth (``scene``: the mug's start and present height,
highest lift, tilt; :meth:`~hil_emulator.emulator.Emulator.scene_stats`).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from types import FrameType
from typing import Any

from hil_emulator.emulator import Emulator, has_display
from hil_emulator.errors import EmulatorError
from hil_emulator.faults import FaultInjector, load_plan
from hil_emulator.faults.control import ControlChannel
from hil_emulator.imperfections import DEFAULT_SENSORS, SENSOR_MODES
from hil_emulator.inprocess import bring_up
from hil_emulator.robot import CONFIGS
from hil_emulator.scene_model import SCENES
from host.scheduling import PRIORITIES
from tools.cli.numeric import number_above, read_negative_numbers
from tools.cli.output import guard_output


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hil-emulator",
        description="Emulate the hand and the arm (firmware, buses, MuJoCo physics) behind "
                    "virtual serial ports.")
    parser.add_argument("--config", choices=CONFIGS, default="full",
                        help="what is on the bench (default: full = hand on the arm)")
    parser.add_argument("--link-dir", metavar="DIR",
                        help="make stable symlinks DIR/palm, DIR/arm, DIR/can, DIR/finger0")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--realtime", dest="realtime", action="store_true", default=True,
                      help="pace the simulation to the wall clock (default)")
    pace.add_argument("--fast", dest="realtime", action="store_false",
                      help="run the simulation as fast as the CPU allows")
    parser.add_argument("--ready", action="store_true",
                        help="before naming the ports, bring the hand up as a host would "
                             "(fingers and phalanges powered and booted, autopoll on), in "
                             "simulated time; the arm stays torque-off")
    parser.add_argument("--priority", choices=PRIORITIES, default="realtime",
                        help="real time: ask for real-time scheduling of the simulation "
                             "thread where allowed (default), or run normally")
    parser.add_argument("--sleep", action="store_true",
                        help="accepted for compatibility; real time always sleeps between "
                             "events now")
    parser.add_argument("--seed", type=int, default=0, metavar="N",
                        help="seed of every random draw (noise, faults): same seed, same run")
    parser.add_argument("--viewer", action="store_true",
                        help="open MuJoCo's viewer (needs a display)")
    parser.add_argument("--layout", default=None, metavar="NAME",
                        help="hand layout (default: four-finger-thumb)")
    parser.add_argument("--can", choices=("slcan", "none"), default="slcan",
                        help="the palm's CAN link: an SLCAN adapter on a pty (default) or none")
    parser.add_argument("--scene", choices=SCENES, default="none",
                        help="things in front of the arm: mug = a table with a coffee mug "
                             "on it, within the hand's reach (full and arm configurations)")
    parser.add_argument("--sensors", choices=SENSOR_MODES, default=DEFAULT_SENSORS,
                        help="realistic (default): sensors as imperfect as the real parts "
                             "and a laser-cut build's geometry, drawn from --seed per board; "
                             "ideal: exact sensors on the nominal geometry")
    parser.add_argument("--profile", metavar="FILE",
                        help="a robot profile (JSON): this robot's physical parameters, "
                             "e.g. written by hil-bench fit (docs/EMULATOR.md)")
    parser.add_argument("--arm-adapters", type=int, default=1, metavar="N",
                        help="USB-RS-485 adapters on the arm's one bus, each a port (arm, "
                             "arm2, ...): another program on its own adapter (default 1)")
    parser.add_argument("--no-physics", dest="physics", action="store_false",
                        help="firmware and buses only, no MuJoCo plant")
    parser.add_argument("--duration", type=number_above(0, what="a time in seconds"),
                        default=None, metavar="S",
                        help="stop by itself after S seconds of wall time")
    parser.add_argument("--faults", metavar="FILE",
                        help="load a fault plan (TOML [[faults]]) when the ports are ready")
    parser.add_argument("--control", metavar="PATH",
                        help="fault control socket (default: DIR/control with --link-dir)")
    parser.add_argument("--stats", action="store_true",
                        help="on exit, print delivery lateness, simulated time and port "
                             "counters (overruns) to stderr as JSON")
    return parser


def _viewer(emulator: Emulator) -> tuple[Callable[[], None] | None, Any]:
    """Open a passive viewer; returns (sync callback, handle) or (None, None)."""
    if emulator.plant is None:
        return None, None
    import mujoco.viewer

    handle = mujoco.viewer.launch_passive(emulator.plant.model, emulator.plant.data)
    return handle.sync, handle


@guard_output("hil-emulator")
def main(argv: Sequence[str] | None = None) -> int:
    args = read_negative_numbers(build_parser()).parse_args(argv)
    stop = threading.Event()
    stop_asked: list[float] = []  # monotonic time (s) of the first stop request

    def request_stop() -> None:
        if not stop_asked:
            stop_asked.append(time.monotonic())
        stop.set()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        request_stop()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    try:
        plan = load_plan(args.faults) if args.faults else []
        emulator = Emulator(args.config, seed=args.seed, layout=args.layout,
                            physics=args.physics, can=args.can, scene=args.scene,
                            sensors=args.sensors, profile=args.profile,
                            arm_adapters=args.arm_adapters)
    except EmulatorError as exc:
        print(f"hil-emulator: {exc}", file=sys.stderr)
        return 2
    faults = FaultInjector(emulator)  # the plan's and the control channel's
    with emulator:
        try:
            if args.ready:
                bring_up(emulator)
            ports: dict[str, object] = {**emulator.open_ports(args.link_dir)}
            ports["ready"] = bool(args.ready)
            control = args.control or (os.path.join(args.link_dir, "control")
                                       if args.link_dir else None)
            if control is not None:
                emulator.add_port(ControlChannel(emulator, control, faults))
                ports["control"] = control
            faults.load(plan)
            ports["faults"] = len(plan)
        except EmulatorError as exc:
            print(f"hil-emulator: {exc}", file=sys.stderr)
            return 1
        pacer = emulator.pacer
        pacer.on_late = lambda text: print(f"hil-emulator: {text}", file=sys.stderr,
                                           flush=True)
        pacer.on_notice = pacer.on_late
        on_idle: Callable[[], None] | None = None
        handle: Any = None
        if args.viewer:
            if has_display():
                on_idle, handle = _viewer(emulator)
                ports["viewer"] = handle is not None
            else:
                ports["viewer"] = False
                print("hil-emulator: --viewer: no display here (DISPLAY is not set); "
                      "running without the viewer", file=sys.stderr)
        print(json.dumps(ports), flush=True)
        if args.duration is not None:
            timer = threading.Timer(args.duration, request_stop)
            timer.daemon = True
            timer.start()
        try:
            emulator.run(stop, realtime=args.realtime, on_idle=on_idle,
                         priority=args.priority)
        finally:
            stop_ms = (time.monotonic() - stop_asked[0]) * 1e3 if stop_asked else None
            if handle is not None:
                handle.close()
            if args.stats:
                stats: dict[str, Any] = {
                    "sim_s": emulator.scheduler.now_us() / 1e6, **emulator.lateness_stats(),
                    "stop_ms": stop_ms,
                    "scheduling": pacer.scheduling.policy if pacer.scheduling else None,
                    "ports": emulator.link_stats(),
                    "fault_timeline": faults.timeline_dicts()}
                if emulator.scene_parts:
                    stats["scene"] = emulator.scene_stats()
                print(f"hil-emulator stats: {json.dumps(stats)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
