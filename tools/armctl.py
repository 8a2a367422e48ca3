"""armctl: the 7-DOF arm from a terminal (a thin command over :class:`host.arm.Arm`).

::

    armctl --port /dev/ttyUSB0 ping                 # discover the seven joints
    armctl --port ./robot/arm --json status         # joints, motor angles, torques, slip
    armctl --port emu://arm/arm torque on
    armctl --port P move --joints 0 0.3 0 0.2 0 0 0 --duration 2
    armctl --port P record arm.mcap --seconds 5     # raw bytes + decoded states (MCAP)

``--port`` takes a serial path (1 Mbaud unless ``?baud=N``) or any transport URL
(``emu://arm/arm`` runs the emulator in this process).  Opening sets every node's return
delay to 0 for fast cycles unless ``--keep-return-delay``.  Errors are one line on standard
error saying what to do next; exit status 1 for a robot or link problem, 2 for bad
arguments, 3 when a move did not settle in time.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from typing import Any, TextIO

from host.arm import Arm
from host.arm_state import JOINT_NAMES, N_JOINTS, ArmState
from host.errors import HostError, ReplyTimeout, TransportError, UsageError

#: Exit statuses.
EXIT_OK, EXIT_ROBOT, EXIT_USAGE, EXIT_NOT_SETTLED = 0, 1, 2, 3


def add_port_argument(parser: argparse.ArgumentParser) -> None:
    """``--port``: a serial path or a transport URL."""
    parser.add_argument("--port", required=True, metavar="P",
                        help="serial port path (1 Mbaud unless ?baud=N) or transport URL "
                             "(emu://arm/arm, socket://host:port, ...)")


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="armctl", description=__doc__.split("\n\n")[0])
    add_port_argument(parser)
    parser.add_argument("--json", action="store_true", help="print JSON instead of text")
    parser.add_argument("--keep-return-delay", action="store_true",
                        help="leave the nodes' return delay (register 5) as it is")
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("ping", help="discover the joints: ids, models, firmware")
    sub.add_parser("status", help="one cycle's state of all joints")
    torque = sub.add_parser("torque", help="enable or disable every joint's torque")
    torque.add_argument("state", choices=("on", "off"))
    move = sub.add_parser("move", help="move all joints and wait until the move settles")
    move.add_argument("--joints", nargs=N_JOINTS, type=float, required=True, metavar="RAD",
                      help="seven joint angles J1..J7 (rad)")
    move.add_argument("--duration", type=float, default=None, metavar="S",
                      help="take this long (s): speeds set so every joint arrives together")
    move.add_argument("--timeout", type=float, default=10.0, metavar="S",
                      help="give up waiting after this long (s, default 10)")
    record = sub.add_parser("record", help="record raw bus bytes and decoded states (MCAP)")
    record.add_argument("file", help="output .mcap file")
    record.add_argument("--seconds", type=float, required=True, metavar="S")
    record.add_argument("--rate", type=float, default=100.0, metavar="HZ",
                        help="cycles per second (default 100)")
    return parser


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


def cmd_status(arm: Arm, args: argparse.Namespace, out: TextIO) -> int:
    state = arm.state()
    _print(out, args.json, state.as_dict(), _state_text(state))
    return EXIT_OK


def cmd_torque(arm: Arm, args: argparse.Namespace, out: TextIO) -> int:
    state = arm.torque(args.state == "on")
    _print(out, args.json, {"torque": args.state, **state.as_dict()}, f"torque {args.state}")
    return EXIT_OK


def cmd_move(arm: Arm, args: argparse.Namespace, out: TextIO) -> int:
    state, ok = arm.move(args.joints, duration=args.duration, timeout=args.timeout)
    _print(out, args.json, {"settled": ok, **state.as_dict()},
           ("settled\n" if ok else "not settled\n") + _state_text(state))
    if not ok:
        print(f"armctl: the move did not settle within {args.timeout} s: is torque on "
              "(armctl torque on)? is a joint blocked or slipping (armctl status)?",
              file=sys.stderr)
        return EXIT_NOT_SETTLED
    return EXIT_OK


def cmd_record(arm: Arm, args: argparse.Namespace, out: TextIO) -> int:
    from host.arm_recording import record

    if not args.seconds > 0 or not args.rate > 0:
        raise UsageError("--seconds and --rate must be > 0")
    cycles = record(arm, args.file, seconds=args.seconds, rate_hz=args.rate)
    _print(out, args.json, {"file": args.file, "cycles": cycles},
           f"{cycles} cycles recorded to {args.file}")
    return EXIT_OK


COMMANDS = {"ping": cmd_ping, "status": cmd_status, "torque": cmd_torque, "move": cmd_move,
            "record": cmd_record}


def main(argv: Sequence[str] | None = None, out: TextIO | None = None) -> int:
    out = out or sys.stdout
    parser = make_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    try:
        arm = Arm.open(args.port, return_delay=None if args.keep_return_delay else 0)
    except TransportError as exc:
        print(f"armctl: {exc}; check the path (ls /dev/ttyUSB*), "
              "permissions (dialout group) or that hil-emulator is running", file=sys.stderr)
        return EXIT_ROBOT
    except ReplyTimeout as exc:
        print(f"armctl: {exc}; check the arm's power and cabling, and the baud rate "
              "(?baud=N)", file=sys.stderr)
        return EXIT_ROBOT
    except UsageError as exc:
        print(f"armctl: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except HostError as exc:
        print(f"armctl: {exc}", file=sys.stderr)
        return EXIT_ROBOT
    try:
        with arm:
            return COMMANDS[args.command](arm, args, out)
    except UsageError as exc:
        print(f"armctl: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except ReplyTimeout as exc:
        print(f"armctl: {exc}; the arm stopped answering: check power and the cable",
              file=sys.stderr)
        return EXIT_ROBOT
    except (HostError, OSError) as exc:
        print(f"armctl: {exc}", file=sys.stderr)
        return EXIT_ROBOT


if __name__ == "__main__":
    sys.exit(main())
