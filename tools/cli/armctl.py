"""armctl: the 7-DOF arm from a terminal (a thin command over :class:`host.arm.facade.Arm`).

::

    armctl --port /dev/ttyUSB0 ping                 # discover the seven joints
    armctl --port /dev/ttyUSB0 scan --ids 0-253     # every node that answers, at any ID
    armctl --port ./robot/arm --json status         # joints, motor angles, torques, slip
    armctl --port emu://arm/arm torque on
    armctl --port P move --joints 0 0.3 0 0.2 0 0 0 --duration 2
    armctl --port P record arm.mcap --seconds 5     # raw bytes + decoded states (MCAP)
    armctl --port P excite arm-excite.mcap          # chirp each joint, hold under gravity, recorded
    armctl --port P home                            # find every stepper joint's index mark
    armctl --port P moveto 0.3 0.0 -0.5 [--rpy R P Y]   # flange to x y z (m, base frame)
    armctl --port P calibrate [--out PATH] [--poses N]  # touch the calibration rig, fit, save
    armctl --port P waypoints record path.jsonl --seconds 10   # torque off, move by hand
    armctl --port P waypoints play path.jsonl
    armctl --port P clear                           # clear latched alarms (torque stays off)
    armctl --port P watch                           # only read the arm: a browser view
    armctl --port P move --joints … --view          # any command: draw it in a browser view

``torque on`` holds each joint whose torque was off where it is (not at a goal its node
kept from before: one sent while the torque was off, the arm moved by hand since) and exits
1 naming a joint whose node keeps its torque off (a latched alarm: ``armctl clear``).
``move``, ``moveto`` and ``waypoints play`` refuse (exit 2) to start while a joint's torque
is off, and ``move`` a goal outside a joint's range (the servos' always, the steppers' once
homed).
``move`` and ``moveto`` need a homed arm (``armctl home``; the nodes keep the index latch until
they lose power, so a later armctl picks it up); ``--unhomed`` moves in the nodes' frames
(angles from power-up) anyway.  ``moveto`` refuses (exit 2) a target where every IK solution
would have a stepper joint hold more than 70 % of its stall torque against gravity, naming
the joint (the hand's weight counted unless ``--no-hand``).  Every motion passes the arm's
gate first (:mod:`host.arm.gate`: finite numbers, ranges, speeds and accelerations, torque);
Ctrl-C or SIGTERM mid-motion holds the arm where it is (:meth:`host.arm.facade.Arm.hold`) and says
so on one line; a joint whose node latches an alarm on the way is named with its latch
(exit 1), the rest of the arm held.

``--port`` takes a serial path (1 Mbaud unless ``?baud=N``) or any transport URL
(``emu://arm/arm`` runs the emulator in this process); ``--timeout S`` is the adapter latency
allowed on top of each exchange's wire time (default 100 ms on a serial link, 0.2 ms in
process).  Opening sets every node's return delay to 0 for fast cycles unless
``--keep-return-delay``.  Errors say what to do next (:mod:`tools.cli.common`); exit status 1
for a robot or link problem, 2 for bad arguments, 3 when a move did not settle in time, 130
when interrupted.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TextIO

from host.arm.calibration import (
    ARM_SECTION,
    NO_CALIBRATION,
    ArmCalibrationChoice,
    arm_section,
    check,
)
from host.arm.facade import MOVE_DEFAULT_SPEED, Arm, host_watchdog_ms, off_goal, open_bus
from host.arm.gate import MOVE_STEPPER_SPEED_RAD_S, check_cartesian, check_finite, require_torque
from host.arm.homing import restore
from host.arm.rest import RestWatch
from host.arm.state import JOINT_IDS, JOINT_NAMES, N_JOINTS, ArmState
from host.arm.touches import DEFAULT_POSES, fit, gather
from host.errors import NodeError, RecordingError, UsageError
from host.estimation.calibration_file import default_path as calibration_path
from host.estimation.calibration_file import save_section
from host.scheduling import current
from protocol.control_tables import TABLES_BY_MODEL, StepperFlag
from protocol.dynamixel import MAX_ID
from tools.cli.commands import Commands
from tools.cli.common import (
    EXIT_OK,
    EXIT_ROBOT,
    EXIT_USAGE,
    add_common_arguments,
    options_anywhere,
    run_cli,
    unwritable,
)
from tools.cli.numeric import finite, number_above
from tools.cli.output import guard_output
from tools.cli.view import WATCH_HELP, add_view_arguments, view_spec, watch, watch_arguments

#: Exit status of a move that did not settle in time (the others: :mod:`tools.cli.common`).
EXIT_NOT_SETTLED = 3
__all__ = ["EXIT_NOT_SETTLED", "EXIT_OK", "EXIT_ROBOT", "EXIT_USAGE", "main", "make_parser"]


#: A time on the command line (s): a number > 0.
_TIME = number_above(0, what="a time (s)")


#: armctl's sub-commands, in the order its help lists them (each declared below, with its
#: arguments beside its handler); a handler gets the arm, the arguments and the output.
COMMANDS: Commands[Arm, [TextIO]] = Commands()


def _print(out: TextIO, as_json: bool, data: dict[str, Any], text: str) -> None:
    print(json.dumps(data) if as_json else text, file=out)


def _state_text(state: ArmState) -> str:
    lines = [f"{'joint':5s} {'angle rad':>10s} {'motor rad':>10s} {'torque Nm':>10s}  flags"]
    for s in state.steppers:
        flags = ",".join(f.name or "" for f in type(s.flags) if s.flags & f) or "-"
        lines.append(f"{JOINT_NAMES[s.joint]:5s} {s.angle:10.4f} {s.motor_angle:10.4f} "
                     f"{s.torque:10.3f}  {flags}")
    for v in state.servos:
        lines.append(f"{JOINT_NAMES[v.joint]:5s} {v.angle:10.4f} {'':10s} {'':10s}  "
                     f"load {v.load:+.2f}, {v.temperature:.0f} °C")
    if state.errors:
        lines.append("errors: " + "; ".join(f"{k}: {', '.join(v)}"
                                            for k, v in state.errors.items()))
    return "\n".join(lines)


@COMMANDS.command("watch", WATCH_HELP, watch_arguments(default_rate=50.0))
def cmd_watch(arm: Arm, args: argparse.Namespace, out: TextIO) -> int:
    """Read the arm's state (no commands) ``--rate`` times a second; the view draws it."""
    t = arm.transport
    cycles = watch(arm.state, t.now, t.sleep, args.rate, args.seconds)
    _print(out, args.json, {"cycles": cycles}, f"{cycles} states read")
    return EXIT_OK


@COMMANDS.command("ping", "discover the joints: ids, models, firmware")
def cmd_ping(arm: Arm, args: argparse.Namespace, out: TextIO) -> int:
    joints = [{"joint": j.name, "id": j.dxl_id, "kind": j.kind, "model": j.model_number,
               "firmware": j.firmware_version,
               **({"reduction": j.reduction, "steps_per_rev": j.steps_per_rev,
                   "microstepping": j.microstepping} if j.kind == "stepper" else {})}
              for j in arm.joints]
    text = "\n".join(f"{d['joint']}: id {d['id']}, {d['kind']}, model {d['model']}, "
                     f"firmware {d['firmware']}" for d in joints)
    _print(out, args.json, {"joints": joints}, text)
    return EXIT_OK


def _scan_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--ids", default="0-31", metavar="FIRST-LAST",
                   help="the IDs to ping (default 0-31; 0-253 takes a while: each absent "
                        "ID waits out the link budget)")


def _id_range(text: str) -> range:
    first, _, last = text.partition("-")
    try:
        lo, hi = int(first), int(last or first)
    except ValueError:
        raise UsageError(f"--ids takes FIRST-LAST (e.g. 0-31), got {text!r}") from None
    if not 0 <= lo <= hi <= MAX_ID:
        raise UsageError(f"--ids {text}: IDs are 0..{MAX_ID}, first <= last")
    return range(lo, hi + 1)


@COMMANDS.alone("scan", "ping every bus ID in a range and list the nodes that "
                "answer (a node at an unexpected ID, a wrong baud)", _scan_arguments)
def cmd_scan(args: argparse.Namespace, out: TextIO) -> int:
    ids = _id_range(args.ids)
    bus = open_bus(args.port, latency_s=args.link_timeout)
    try:
        nodes = []
        for dxl_id in bus.scan(ids):
            head = bus.read(dxl_id, 0, 3)
            model = int.from_bytes(head[:2], "little")
            table = TABLES_BY_MODEL.get(model)
            joint = JOINT_NAMES[JOINT_IDS.index(dxl_id)] if dxl_id in JOINT_IDS else None
            nodes.append({"id": dxl_id, "model": model, "firmware": head[2],
                          "model_name": table.name if table else None, "joint": joint})
    finally:
        bus.transport.close()
    missing = [f"{JOINT_NAMES[i]} (ID {d})" for i, d in enumerate(JOINT_IDS)
               if d in ids and d not in [n["id"] for n in nodes]]
    lines = [f"id {n['id']}: model {n['model']} ({n['model_name'] or 'unknown'}), firmware "
             f"{n['firmware']}" + (f", {n['joint']}" if n["joint"] else ", not an arm ID")
             for n in nodes] or [f"no node answers at IDs {ids.start}-{ids.stop - 1}"]
    if missing:
        lines.append("missing: " + ", ".join(missing))
    _print(out, args.json, {"ids": [ids.start, ids.stop - 1], "nodes": nodes,
                            "missing": missing}, "\n".join(lines))
    return EXIT_OK if nodes else EXIT_ROBOT


def _calibration_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--calibration", metavar="PATH",
                   help="the arm's calibration file (default: this arm's, named by its "
                        "serial, in $LOWCOST_CALIBRATION_DIR or "
                        "~/.config/lowcost-hand/calibration; 'none': the CAD model)")


def _use_calibration(arm: Arm, args: argparse.Namespace) -> ArmCalibrationChoice:
    """Load the arm calibration ``--calibration`` names (or this arm's) and say on stderr
    which the Cartesian moves use, and every warning (missing, another robot's, stale)."""
    chosen = arm.load_calibration(getattr(args, "calibration", None))
    for warning in chosen.warnings:
        print(f"armctl: warning: {warning}", file=sys.stderr)
    print(chosen.summary(), file=sys.stderr)
    return chosen


@COMMANDS.command("status", "one cycle's state of all joints", _calibration_argument)
def cmd_status(arm: Arm, args: argparse.Namespace, out: TextIO) -> int:
    homed = restore(arm)
    chosen = _use_calibration(arm, args)
    state = arm.state()
    enabled = arm.torque_enabled()
    off = [JOINT_NAMES[i] for i, on in enumerate(enabled) if not on]
    torque = "on" if not off else "off" if len(off) == N_JOINTS else f"off on {', '.join(off)}"
    _print(out, args.json, {**state.as_dict(), "homed": homed, "torque": list(enabled),
                            "serial": arm.serial, "calibration": chosen.to_dict()},
           _state_text(state) + f"\nhomed: {'yes' if homed else 'no (armctl home)'}"
           f"\ntorque: {torque}\nserial: {arm.serial or 'none'}\n{chosen.summary()}")
    return EXIT_OK


def _require_torque(arm: Arm, what: str) -> None:
    """Refuse ``what`` while a joint's torque is off: its goal would wait in the node, and
    the joint jump there whenever the torque came on (:func:`host.arm.gate.require_torque`
    names a latched alarm)."""
    require_torque(arm, what=what)


def _require_homed(arm: Arm, args: argparse.Namespace, what: str) -> None:
    if not restore(arm) and not args.unhomed:
        raise UsageError(f"the arm is not homed; home it first (armctl home) before {what}, "
                         "or pass --unhomed to use angles from power-up")


def _torque_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("state", choices=("on", "off"))
    p.add_argument("--keep-goals", action="store_true",
                   help="on: let each joint head for the goal its node has instead of "
                        "holding where it is")


@COMMANDS.command("torque", "enable or disable every joint's torque", _torque_arguments)
def cmd_torque(arm: Arm, args: argparse.Namespace, out: TextIO) -> int:
    on = args.state == "on"
    state = arm.torque(on, hold=on and not args.keep_goals)
    enabled = arm.torque_enabled()
    refused = [JOINT_NAMES[i] for i, e in enumerate(enabled) if e != on]
    _print(out, args.json, {"torque": args.state, "enabled": list(enabled), **state.as_dict()},
           f"torque {args.state}" + (f", except {', '.join(refused)}" if refused else ""))
    if refused:
        latched = "; ".join(f"{k}: {', '.join(v)}" for k, v in state.errors.items())
        print(f"armctl: the torque of {', '.join(refused)} stayed "
              f"{'off' if on else 'on'}" + (f" (latched: {latched})" if latched else "")
              + ": the node turned it off after an alarm; check the joint moves freely, then "
              "armctl clear and armctl torque on", file=sys.stderr)
        return EXIT_ROBOT
    return EXIT_OK


@COMMANDS.command("clear", "clear the joints' latched alarms (SLIP/STALLED, RX-64 "
                  "alarms); torque stays off: armctl torque on next")
def cmd_clear(arm: Arm, args: argparse.Namespace, out: TextIO) -> int:
    before = arm.state()
    latched = sorted({*before.errors, *(JOINT_NAMES[s.joint] for s in before.steppers
                                        if s.flags & (StepperFlag.SLIP | StepperFlag.STALLED))})
    arm.clear_errors()
    state = arm.state()
    text = ("no alarm was latched" if not latched else
            f"cleared {', '.join(latched)}; a stepper holds where it stopped, an RX-64's "
            "torque is off (armctl torque on)")
    _print(out, args.json, {"cleared": not state.errors, "latched": latched,
                            **state.as_dict()},
           text if not state.errors else "still latched: " + "; ".join(
               f"{k}: {', '.join(v)}" for k, v in state.errors.items()))
    if state.errors:
        print("armctl: an alarm is still there after clearing it: the fault is present now "
              "(overheated, supply voltage, a joint still held); fix it and clear again",
              file=sys.stderr)
        return EXIT_ROBOT
    return EXIT_OK


def _move_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--joints", nargs="+", required=True, metavar="RAD",
                   help="seven joint angles J1..J7 (rad), as seven values or one "
                        "comma-separated list")
    p.add_argument("--duration", type=_TIME, default=None, metavar="S",
                   help="take this long (s): speeds set so every joint arrives together")
    p.add_argument("--speed", type=number_above(0, what="a speed (rad/s)"), default=None,
                   metavar="RAD_S",
                   help="every joint at most this (rad/s), each on its own time (J1-J4 "
                        f"at most {MOVE_STEPPER_SPEED_RAD_S}); without --duration or --speed "
                        f"the furthest goes at {MOVE_DEFAULT_SPEED} and the others arrive "
                        "with it")
    p.add_argument("--timeout", type=_TIME, default=10.0, metavar="S",
                   help="give up waiting this long (s, default 10) after the joints should "
                        "have arrived")
    p.add_argument("--unhomed", action="store_true",
                   help="move although the arm is not homed (angles from power-up)")


@COMMANDS.command("move", "move all joints and wait until the move settles", _move_arguments)
def cmd_move(arm: Arm, args: argparse.Namespace, out: TextIO) -> int:
    goals = _joint_values(args.joints)
    check_finite(goals, "goal")
    if args.duration is not None and args.speed is not None:
        raise UsageError("give --duration or --speed, not both")
    _require_homed(arm, args, "move")
    _require_torque(arm, "move")
    rest = RestWatch()
    state, ok = arm.move(goals, duration=args.duration, speed=args.speed,
                         timeout=args.timeout, rest=rest)
    _print(out, args.json, {"settled": ok, **state.as_dict()},
           ("settled\n" if ok else "not settled\n") + _state_text(state))
    if not ok:
        why = off_goal(state, arm.motor_goals(goals), 0.02) or rest.why_not() or "?"
        print(f"armctl: the move did not settle within {args.timeout} s ({why}): is a joint "
              "blocked, or still swinging (armctl status; a longer --timeout)?",
              file=sys.stderr)
        return EXIT_NOT_SETTLED
    return EXIT_OK


def _joint_values(words: list[str]) -> list[float]:
    """Seven joint angles (rad) from ``0 0.3 0 …`` or ``0,0.3,0,…``."""
    parts = [p for w in words for p in w.split(",") if p.strip()]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise UsageError(f"--joints takes numbers (rad), got {' '.join(words)!r}") from None
    if len(values) != N_JOINTS:
        raise UsageError(f"--joints takes {N_JOINTS} angles J1..J7 (rad), got {len(values)}")
    return values


@COMMANDS.command("home", "find every stepper joint's encoder index (moves J1-J4 "
                  "slowly a little)")
def cmd_home(arm: Arm, args: argparse.Namespace, out: TextIO) -> int:
    calibration = arm.home()
    data = {"homed": True, "offsets": list(calibration.offsets),
            "index_encoder_counts": list(calibration.index_encoder_counts),
            "index_step_counts": list(calibration.index_step_counts)}
    text = "homed: " + ", ".join(f"{JOINT_NAMES[i]} {o:+.4f} rad"
                                 for i, o in enumerate(calibration.offsets[:4]))
    _print(out, args.json, data, text)
    return EXIT_OK


def _moveto_arguments(p: argparse.ArgumentParser) -> None:
    # three positionals, not nargs=3 with a tuple metavar: argparse's help crashes on that
    for axis in "xyz":
        p.add_argument(axis, type=finite("a position (m)"), metavar=axis.upper(),
                       help=f"flange {axis} (m, base frame)")
    p.add_argument("--rpy", nargs=3, type=finite("an angle (rad)"), default=None,
                   metavar="ANGLE",
                   help="flange orientation: roll pitch yaw (rad, fixed base axes)")
    p.add_argument("--unhomed", action="store_true",
                   help="move although the arm is not homed")
    p.add_argument("--timeout", type=_TIME, default=8.0, metavar="S",
                   help="settle time allowed after the path (s, default 8)")
    p.add_argument("--tolerance", type=number_above(0, what="a distance (mm)"),
                   default=2.0, metavar="MM",
                   help="reached when the flange is this close to the target (mm, "
                        "default 2)")
    p.add_argument("--no-hand", action="store_true",
                   help="no hand on the flange: leave its weight out of the check that "
                        "no stepper joint would hold near its stall torque")
    _calibration_argument(p)


@COMMANDS.command("moveto", "move the flange to X Y Z (m, base frame)", _moveto_arguments)
def cmd_moveto(arm: Arm, args: argparse.Namespace, out: TextIO) -> int:
    check_cartesian((args.x, args.y, args.z), args.rpy)
    _require_homed(arm, args, "moveto")
    _require_torque(arm, "moveto")
    _use_calibration(arm, args)
    result = arm.moveto((args.x, args.y, args.z), args.rpy, allow_unhomed=args.unhomed,
                        settle_timeout=args.timeout, hand=not args.no_hand,
                        tolerance_m=args.tolerance / 1000)
    data = {"reached": result.reached, "goals": list(result.goals),
            "position_error_m": result.position_error, **result.state.as_dict()}
    _print(out, args.json, data, f"{'reached' if result.reached else 'not reached'}: "
           f"{result.position_error * 1000:.1f} mm from the target\n"
           + _state_text(result.state))
    if not result.reached:
        print(f"armctl: the flange is {result.position_error * 1000:.1f} mm from the target "
              f"after {args.timeout} s (--tolerance {args.tolerance} mm): is a joint blocked or "
              "slipping (armctl status)?",
              file=sys.stderr)
        return EXIT_NOT_SETTLED
    return EXIT_OK


def _check_writable(path: str, what: str) -> None:
    """Refuse (before the arm does anything) an output file that cannot be written: a
    recording made first would be lost."""
    if problem := unwritable(path):
        raise UsageError(f"cannot write the {what} to {path}: {problem}")


def _waypoints_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("action", choices=("record", "play"))
    p.add_argument("file", help="waypoint file (JSON lines)")
    p.add_argument("--seconds", type=_TIME, default=10.0, metavar="S",
                   help="how long to record (s, default 10)")
    p.add_argument("--unhomed", action="store_true",
                   help="play although the arm is not homed")
    p.add_argument("--time-scale", type=number_above(0, what="a time scale"),
                   default=1.0, metavar="K",
                   help="play K times slower than recorded (default 1): a file "
                        "whose steps need more speed or acceleration than a joint "
                        "has is refused, and the message says what K would do")


@COMMANDS.command("waypoints", "record waypoints by hand, or play them", _waypoints_arguments)
def cmd_waypoints(arm: Arm, args: argparse.Namespace, out: TextIO) -> int:
    from host.arm.trajectory import Waypoint
    from host.arm.waypoints import load_waypoints, play_waypoints, record_waypoints, save_waypoints

    if args.action == "record":
        if not args.seconds > 0:
            raise UsageError("--seconds must be > 0")
        _check_writable(args.file, "waypoint file")
        restore(arm)
        points: list[Waypoint] = []
        try:
            record_waypoints(arm, args.seconds, kept=points)
        except BaseException:  # the link lost, Ctrl-C: keep what was recorded
            if points:
                save_waypoints(args.file, points)
                print(f"armctl: the {len(points)} waypoints recorded before this were saved "
                      f"to {args.file}", file=sys.stderr)
            raise
        save_waypoints(args.file, points)
        _print(out, args.json, {"file": args.file, "waypoints": len(points),
                                "homed": arm.homed},
               f"{len(points)} waypoints recorded to {args.file} (torque is off)")
        return EXIT_OK
    if not Path(args.file).exists():  # a device (/dev/null) is read like a file
        raise UsageError(f"no waypoint file {args.file} (armctl waypoints record "
                         f"{args.file} makes one)")
    if Path(args.file).is_dir():
        raise UsageError(f"{args.file} is a directory, not a waypoint file")
    points = load_waypoints(args.file)
    _require_homed(arm, args, "playing waypoints")
    _require_torque(arm, "playing waypoints")
    state = play_waypoints(arm, points, time_scale=args.time_scale)
    _print(out, args.json, {"file": args.file, "waypoints": len(points), **state.as_dict()},
           f"played {len(points)} waypoints from {args.file}")
    return EXIT_OK


def _record_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", help="output .mcap file")
    p.add_argument("--seconds", type=_TIME, required=True, metavar="S")
    p.add_argument("--rate", type=number_above(0, what="a rate (Hz)"), default=100.0,
                   metavar="HZ",
                   help="cycles per second (default 100)")


def _record_check(args: argparse.Namespace) -> None:
    """Before the arm is opened (and its return delay set)."""
    _check_writable(args.file, "recording")


@COMMANDS.command("record", "record raw bus bytes and decoded states (MCAP)", _record_arguments,
                  check=_record_check)
def cmd_record(arm: Arm, args: argparse.Namespace, out: TextIO) -> int:
    from host.arm.recording import record

    if not args.seconds > 0 or not args.rate > 0:
        raise UsageError("--seconds and --rate must be > 0")
    try:
        cycles = record(arm, args.file, seconds=args.seconds, rate_hz=args.rate)
    except RecordingError:
        raise  # the file itself failed: its message says what was kept
    except BaseException:  # the link lost, Ctrl-C: the file is finished all the same
        if Path(args.file).is_file():
            print(f"armctl: what was recorded before this is in {args.file} (a finished "
                  "MCAP file: handbus decode --dynamixel reads it)", file=sys.stderr)
        raise
    _print(out, args.json, {"file": args.file, "cycles": cycles},
           f"{cycles} cycles recorded to {args.file}")
    return EXIT_OK


def _joint_list(text: str) -> tuple[int, ...]:
    """An argparse type: ``J1,J3,J5`` (joint names, comma-separated) as joint indices."""
    names = [n.strip().upper() for n in text.split(",") if n.strip()]
    bad = [n for n in names if n not in JOINT_NAMES]
    if bad or not names:
        raise argparse.ArgumentTypeError(f"{text!r}: joint names among "
                                         f"{', '.join(JOINT_NAMES)}, comma-separated")
    return tuple(JOINT_NAMES.index(n) for n in dict.fromkeys(names))


def _joints_or_none(text: str) -> tuple[int, ...]:
    """An argparse type: :func:`_joint_list`, or ``none`` (no joints)."""
    return () if text.strip().lower() == "none" else _joint_list(text)


def _excite_arguments(p: argparse.ArgumentParser) -> None:
    from host.arm.excite import DEFAULT_PROBES, DEFAULT_RAMPS, Excitation

    plan = Excitation()
    p.add_argument("file", help="output .mcap file")
    p.add_argument("--joints", type=_joint_list, default=plan.joints, metavar="J1,J2,…",
                   help="the joints to chirp, in order (default all seven)")
    p.add_argument("--amplitude", type=number_above(0, what="an amplitude (rad)"),
                   default=plan.amplitude_rad, metavar="RAD",
                   help=f"largest chirp amplitude (rad, default {plan.amplitude_rad}); each "
                        "joint's is smaller where its speed, acceleration or range asks")
    p.add_argument("--chirp-seconds", type=_TIME, default=plan.chirp_s, metavar="S",
                   help=f"each joint's chirp (s, default {plan.chirp_s:g})")
    p.add_argument("--f0", type=number_above(0, what="a frequency (Hz)"),
                   default=plan.f0_hz, metavar="HZ",
                   help=f"the chirp's start frequency (Hz, default {plan.f0_hz:g})")
    p.add_argument("--f1", type=number_above(0, what="a frequency (Hz)"),
                   default=plan.f1_hz, metavar="HZ",
                   help=f"the chirp's end frequency (Hz, default {plan.f1_hz:g})")
    p.add_argument("--hold-seconds", type=number_above(0, inclusive=True, what="a time (s)"),
                   default=plan.hold_s, metavar="S",
                   help=f"each hold under gravity (s, default {plan.hold_s:g})")
    p.add_argument("--ramps", type=_joints_or_none, default=DEFAULT_RAMPS, metavar="J1,…",
                   help="the joints ramped slowly through zero speed, for their friction "
                        f"(default {','.join(JOINT_NAMES[j] for j in DEFAULT_RAMPS)}; none)")
    p.add_argument("--ramp-rad", type=number_above(0, what="an amplitude (rad)"),
                   default=plan.ramp_rad, metavar="RAD",
                   help=f"each ramp's excursion either way (rad, default {plan.ramp_rad:g})")
    p.add_argument("--ramp-speed", type=number_above(0, what="a speed (rad/s)"),
                   default=plan.ramp_speed_rad_s, metavar="RAD/S",
                   help=f"the ramps' speed (rad/s, default {plan.ramp_speed_rad_s:g})")
    p.add_argument("--probes", type=_joints_or_none, default=DEFAULT_PROBES, metavar="J4,…",
                   help="the steppers whose holding torque is probed, in order (default "
                        f"{','.join(JOINT_NAMES[j] for j in DEFAULT_PROBES)}; none)")
    p.add_argument("--probe-seconds", type=_TIME, default=plan.probe_s, metavar="S",
                   help=f"each holding probe's current ramp (s, default {plan.probe_s:g})")
    p.add_argument("--unhomed", action="store_true",
                   help="excite although the arm is not homed (stepper ranges unknown)")


@COMMANDS.command("excite", "chirp each joint, ramp, hold under gravity, probe the "
                  "steppers' holding torque, record it all (MCAP)",
                  _excite_arguments, check=_record_check)
def cmd_excite(arm: Arm, args: argparse.Namespace, out: TextIO) -> int:
    from host.arm.excite import Excitation, amplitude, excitation_path, excite
    from host.arm.gate import check_path
    from host.arm.recording import ArmRecorder

    _require_homed(arm, args, "exciting it")
    _require_torque(arm, "exciting it")
    plan = Excitation(joints=args.joints, amplitude_rad=args.amplitude,
                      chirp_s=args.chirp_seconds, f0_hz=args.f0, f1_hz=args.f1,
                      hold_s=args.hold_seconds, ramps=args.ramps, ramp_rad=args.ramp_rad,
                      ramp_speed_rad_s=args.ramp_speed, probes=args.probes,
                      probe_s=args.probe_seconds)
    start = arm.state().joints
    path = excitation_path(plan, start, arm.homed)
    check_path([w.t for w in path], [w.joints for w in path], start, homed=arm.homed)
    with ArmRecorder(arm, args.file) as recorder:
        recorder.check()
        state, duration, probes = excite(arm, plan)
        recorder.check()
    names = [JOINT_NAMES[j] for j in plan.joints]
    amplitudes = [amplitude(plan, j, start[j], arm.homed) for j in plan.joints]
    _print(out, args.json, {**state.as_dict(), "file": args.file, "excited": names,
                            "amplitudes_rad": amplitudes, "duration_s": duration,
                            "ramped": [JOINT_NAMES[j] for j in plan.ramps],
                            "probes": [r.as_dict() for r in probes],
                            "states": recorder.states},
           f"excited {', '.join(names)} ({duration:.1f} s of path"
           + "".join(f"; {JOINT_NAMES[r.joint]} "
                     + (f"slipped at {r.slipped_ma} mA under {r.load_nm:.2f} N·m"
                        if r.slipped_ma is not None else "held to the probe's end")
                     for r in probes)
           + f") and recorded it to {args.file}")
    return EXIT_OK


def make_parser() -> argparse.ArgumentParser:
    """armctl's command line."""
    parser = argparse.ArgumentParser(
        prog="armctl", description="armctl: the 7-DOF arm from a terminal (see docs/HOST.md)")
    add_common_arguments(parser, what="the arm bus adapter (1 Mbaud unless ?baud=N)",
                         timeout_default="100 ms on a serial link, 0.2 ms in process")
    parser.add_argument("--keep-return-delay", action="store_true",
                        help="leave the nodes' return delay (register 5) as it is")
    add_view_arguments(parser)
    COMMANDS.add_parsers(parser.add_subparsers(dest="command", required=True))
    options_anywhere(parser)  # before the sub-command or after it
    return parser


def _calibrate_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", metavar="PATH",
                   help="the calibration file to write (default: this arm's, named by its "
                        "serial, in $LOWCOST_CALIBRATION_DIR or "
                        "~/.config/lowcost-hand/calibration)")
    p.add_argument("--poses", type=_poses, default=DEFAULT_POSES, metavar="N",
                   help=f"board touches (the dimples in turn, the probe tilted another way "
                        f"at each; default {DEFAULT_POSES}, at least 6)")
    p.add_argument("--replace-other-robot", action="store_true",
                   help="overwrite a file at --out that holds another robot's calibration")


def _poses(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value < 6:
        raise argparse.ArgumentTypeError(f"{value}: the board needs at least 6 touches")
    return value


@COMMANDS.command("calibrate", "touch the calibration board, table and anchors with the "
                  "probe (it moves!), fit the arm's zeros and links, write the calibration "
                  "file", _calibrate_arguments)
def cmd_calibrate(arm: Arm, args: argparse.Namespace, out: TextIO) -> int:
    serial = arm.serial
    if serial is None:
        raise NodeError("the arm's stepper nodes hold no serial number (arm_serial 0): its "
                        "calibration file cannot be named; program the nodes' arm_serial")
    if args.out is not None and args.out == NO_CALIBRATION:
        raise UsageError("--out none: give the calibration file's path")
    path = calibration_path(serial) if args.out is None else Path(args.out)
    _require_torque(arm, "calibrating")
    if not restore(arm):
        print("armctl: homing first", file=sys.stderr)
        arm.home()
    arm.hand = False  # the probe is on the flange instead of the hand
    arm.geometry = None  # aim with the CAD model: a calibration starts from it

    def progress(what: str, done: int, total: int) -> None:
        end = "\n" if done == total else ""
        print(f"\rcalibrating: {what} touch {done}/{total}", end=end, file=sys.stderr,
              flush=True)

    gathered = gather(arm, args.poses, progress)
    fitted = fit(gathered.data)  # once more without a board touch the fit says is off
    result = fitted.result
    check(result)  # a fit gone astray is refused, never written
    touches = {**gathered.counts, "board": gathered.counts["board"] - fitted.dropped}
    missed = gathered.missed + fitted.dropped
    section = arm_section(result, firmware=arm.joints[0].firmware_version, touches=touches)
    written = save_section(path, serial, ARM_SECTION, section,
                           replace_other_robot=args.replace_other_robot)
    arm.geometry = result.geometry
    counts = ", ".join(f"{n} {k}" for k, n in touches.items())
    text = (f"touches: {counts} ({missed} missed)\n"
            f"board distances rms {result.board_rms_m[0] * 1000:.2f} -> "
            f"{result.board_rms_m[1] * 1000:.2f} mm, table planarity rms "
            f"{result.table_rms_m[0] * 1000:.2f} -> {result.table_rms_m[1] * 1000:.2f} mm\n"
            f"wrote {path} (robot {serial}, sections: {', '.join(written.sections)})")
    _print(out, args.json, {"path": str(path), "robot_serial": serial,
                            "missed": missed, "arm": written.sections[ARM_SECTION]},
           text)
    return EXIT_OK


@guard_output("armctl")
def main(argv: Sequence[str] | None = None, out: TextIO | None = None) -> int:
    """Run armctl, printing results to ``out`` (default stdout); returns the exit status."""
    stream = out or sys.stdout

    def body(args: argparse.Namespace) -> int:
        COMMANDS.check(args)
        if not COMMANDS[args.command].opens:
            return COMMANDS.run_alone(args, stream)
        arm = Arm.open(args.port, return_delay=None if args.keep_return_delay else 0,
                       latency_s=args.link_timeout, view=view_spec(args),
                       watchdog_ms=host_watchdog_ms(current()))  # real-time: 50 ms
        with arm:
            return COMMANDS.run(arm, args, stream)

    return run_cli(make_parser(), argv, body)


if __name__ == "__main__":
    sys.exit(main())
