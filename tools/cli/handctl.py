"""``handctl``: drive the hand from a terminal through the host library.

::

    handctl --port /dev/ttyACM0 ping                      # who answers (13 nodes)
    handctl --port emu://hand/palm --json status           # joints (rad), taxels, currents
    handctl --port P up [--finger 2]                      # power, boot, phalanges, autopoll
    handctl --port P power 2 full                          # finger 2 (or "all") off|low|full
    handctl --port P move --finger 1 --joints 0.2,0.5,0.3 [--effort 120] [--duration 3]
    handctl --port P move --hand 0,0.5,0.3,0,0.5,0.3,0,0.5,0.3,0,0.5,0.3
    handctl --port P record run.mcap --seconds 5 [--rate 50]
    handctl --port P home [--finger 3]                    # hall offsets from the accelerometers
    handctl --port P calibrate [--fingers 3] [--out PATH]  # the accelerometers' calibration file
    handctl --port P status --calibration none            # estimate without the calibration file
    handctl --port P grasp cylindrical 0.8 [--speed 1.0] [--until-contact] [--unhomed]
    handctl --port P grasp pinch 1.0 --fingers 0,3        # only some fingers
    handctl --port P grasp open 1.0                       # poses: open, relax, point
    handctl --port P watch                                # only read the hand: a browser view
    handctl --port P move … --view                        # any command: a browser view too

``--port`` takes a serial path or any transport URL (``socket://``, ``emu://hand/palm`` …);
``--timeout S`` sets the link budget (default by link kind, see :mod:`tools.cli.common`).
Errors print what to do next and exit non-zero (1: the robot or link, 2: the command line,
130: interrupted; Ctrl-C or SIGTERM holds every moving finger where it is, and says which).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from host.code_names import code_name
from host.errors import (
    HostError,
    NodeError,
    RecordingError,
    ReplyTimeout,
    RouteError,
    UsageError,
)
from host.estimation.calibration_file import default_path as calibration_path
from host.estimation.calibration_file import save_section, serial_of_uid
from host.estimation.closed_form import NoAccelerationError, UnobservableJointError, estimate
from host.estimation.ekf import fuse_snapshot
from host.hand.bring_up import BOOT_TIMEOUT_S
from host.hand.calibration import NO_CALIBRATION, calibrate_fingers
from host.hand.facade import Hand, MoveResult
from host.hand.homing import corrected, homed_on_robot
from host.hand.state import FingerState, HandState, NodeInfo
from host.hand.synergies import DEFAULT_SPEED_RAD_S, MAX_SPEED_RAD_S, SYNERGIES
from protocol.image import BoardType
from protocol.messages.boot_program import AUTOBOOT_WINDOW_US
from protocol.messages.common import TxnStatus
from protocol.robot import DEFAULT_HAND_LAYOUT, HAND_LAYOUTS, HOMING_WRIST_TILTS
from protocol.topology import FINGERS
from tools.cli.commands import Commands
from tools.cli.common import (
    EXIT_ROBOT,
    EXIT_USAGE,
    add_common_arguments,
    hand_timeouts,
    options_anywhere,
    run_cli,
    unwritable,
)
from tools.cli.numeric import finite, number_above, number_in
from tools.cli.output import guard_output
from tools.cli.view import WATCH_HELP, add_view_arguments, view_spec, watch, watch_arguments

__all__ = ["EXIT_ROBOT", "EXIT_USAGE", "main", "tilt_hints"]


def tilt_hints(fingers: Sequence[int]) -> list[str]:
    """What ``home`` adds for ``fingers`` refused for a joint axis near vertical: on the
    arm, the wrist tilt of :data:`~protocol.robot.HOMING_WRIST_TILTS` (J6, J7) that serves
    each, one line per tilt."""
    lines = []
    for (j6, j7), served in HOMING_WRIST_TILTS:
        these = [f for f in fingers if f in served]
        if these:
            lines.append("hint: gravity says nothing about a joint whose axis is vertical; on "
                         f"the arm, tilt the wrist first (`armctl --port ARM move --joints "
                         f"0,0,0,0,0,{j6:g},{j7:g}`), then run `handctl home` again for "
                         f"finger(s) {', '.join(map(str, these))}")
    return lines


def _floats(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip() != ""]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not comma-separated numbers") from None


def _finger_list(text: str) -> list[int]:
    """Comma-separated finger indices, each 0..3."""
    try:
        chosen = [int(v) for v in text.split(",") if v.strip() != ""]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not comma-separated finger "
                                         f"indices") from None
    if not chosen or any(not 0 <= k < FINGERS for k in chosen):
        raise argparse.ArgumentTypeError(f"{text}: give fingers 0..{FINGERS - 1}, e.g. 0,1,3")
    return chosen


#: handctl's sub-commands, in the order its help lists them (each declared below, with its
#: arguments beside its handler).
COMMANDS: Commands[Hand, []] = Commands()


def _emit(args: argparse.Namespace, data: Any, text: str) -> None:
    print(json.dumps(data) if args.json else text)


def _not_a_palm(board: int | None, port: str) -> str | None:
    """What to say when the node on ``port`` is a ``board`` other than a palm, else None."""
    if board is None or board == BoardType.PALM:
        return None
    name = code_name(BoardType, board, "board")
    return (f"the node on {port} is a {name} board, not a palm: a loose finger's cable? "
            f"handctl drives a whole hand through its palm; a loose finger is reached with "
            f"HandSession(open_transport(P), link=\"finger\") (docs/HOST.md)")


@COMMANDS.command("watch", WATCH_HELP, watch_arguments(default_rate=20.0))
def _cmd_watch(hand: Hand, args: argparse.Namespace) -> int:
    """Read the hand's state ``--rate`` times a second; the view draws it and its events."""
    s = hand.session
    reads = watch(hand.status, s.now, s.sleep, args.rate, args.seconds)
    _emit(args, {"states": reads}, f"{reads} states read")
    return 0


@COMMANDS.command("ping", "discover every node: program, versions")
def _cmd_ping(hand: Hand, args: argparse.Namespace) -> int:
    found = hand.discover()
    if (not_palm := _not_a_palm(found[0].board, args.port)) is not None:
        _emit(args, {"nodes": [found[0].to_dict()]}, _node_line(found[0]))
        raise NodeError(not_palm)
    lines = [_node_line(n) for n in found]
    unpowered = sorted({n.finger for n in found
                        if n.finger is not None and n.problem == "unpowered"})
    if unpowered:
        lines.append(f"hint: finger(s) {', '.join(map(str, unpowered))} unpowered: "
                     f"`handctl up` powers them, boots their boards and powers their "
                     f"phalanges")
    _emit(args, {"nodes": [n.to_dict() for n in found]}, "\n".join(lines))
    if not found[0].answered:
        raise ReplyTimeout(f"the palm does not answer on {args.port}: {found[0].problem}")
    return 0


def _node_line(n: NodeInfo) -> str:
    if not n.answered:
        return f"{n.where:15} -- {n.problem}"
    cat = "" if n.catalogue_matches else "  (different message catalogue: update firmware)"
    return f"{n.where:15} {n.running:11} v{n.fw_version}  uid {n.uid:#010x}{cat}"


def _calibration_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--calibration", metavar="PATH",
                   help="the accelerometers' calibration file (default: this robot's, "
                        "named by its palm's uid; 'none': their nominal mounting)")


def _use_calibration(hand: Hand, args: argparse.Namespace) -> None:
    """Load the calibration ``--calibration`` names (or this robot's) and say on stderr,
    in one line each, which one the estimates use and what is wrong with it."""
    chosen = hand.load_calibration(args.calibration)
    for line in [*chosen.warnings, chosen.summary()]:
        print(f"handctl: {line}" if line in chosen.warnings else line, file=sys.stderr)


@COMMANDS.command("status", "joints, taxels, currents, power of every finger",
                  _calibration_argument)
def _cmd_status(hand: Hand, args: argparse.Namespace) -> int:
    """Exit 1 when a finger that is powered does not answer (the advice fits what the link
    carried meanwhile: garbage, late replies, or nothing)."""
    _use_calibration(hand, args)
    before = _link_seen(hand)
    state = hand.status()
    seen = {k: v - before[k] for k, v in _link_seen(hand).items()}
    data = state.to_dict()
    data["link"] = seen
    for f, d in zip(state.fingers, data["fingers"], strict=True):
        d.update(_inertial(hand, f))
    problems = [f"finger {d['index']}: {d['accel_problem']}" for d in data["fingers"]
                if d.get("accel_problem")]
    _emit(args, data, "\n".join([_status_text(state, _no_reply_advice(seen)), *problems]))
    silent = [f.index for f in state.fingers if not f.present and f.problem != "unpowered"]
    if silent:
        print(f"handctl: finger(s) {', '.join(map(str, silent))} powered but not answering",
              file=sys.stderr)
        return EXIT_ROBOT
    return 0


def _link_seen(hand: Hand) -> dict[str, int]:
    """What the host's link has carried so far that a silent node can be blamed on."""
    decoder = hand.session.decoder.counters
    return {"bytes_discarded": decoder.bytes_discarded, "crc_failures": decoder.crc_failures,
            "stale_replies": hand.session.counters.stale_replies}


def _no_reply_advice(seen: dict[str, int]) -> str:
    """What to say of a finger whose status got no reply in time, given what the link
    carried meanwhile (``{k}``: the finger)."""
    if seen["bytes_discarded"] or seen["crc_failures"]:
        return (f": garbage on the line ({seen['bytes_discarded']} bytes discarded, "
                f"{seen['crc_failures']} bad CRCs): is another program writing to the port, "
                "or is its baud rate wrong?")
    if seen["stale_replies"]:
        return (f": {seen['stale_replies']} replies came after the link budget (a slow or "
                "busy machine): try --timeout 0.5")
    return ": nothing came back: booting, or off its pogo pins? `handctl up --finger {k}`"


def _inertial(hand: Hand, f: FingerState) -> dict[str, Any]:
    """``joints_accel`` (rad, None where unobservable), ``homed``, and once homed
    ``joints`` fusing the hall counts with the accelerometers."""
    if not f.present or not f.accels:
        return {"joints_accel": None, "homed": False}
    try:
        homed = homed_on_robot(hand.fingers[f.index])
    except HostError:
        homed = False
    accels = corrected(f.index, dict(f.accels), hand.calibration)
    try:
        found = estimate(accels)
    except (NoAccelerationError, UsageError) as exc:  # NoAccelerationError: phalanges unpowered
        return {"joints_accel": None, "homed": homed,
                "accel_problem": f"{exc}; power the phalanges: handctl up"
                if isinstance(exc, NoAccelerationError) else str(exc)}
    out: dict[str, Any] = {
        "joints_accel": [None if q is None else round(q, 6) for q in found.q],
        "homed": homed}
    if homed:
        out["joints"] = [round(float(q), 6) for q in fuse_snapshot(f.joints_hall, accels)]
    return out


#: What ``status`` adds for a finger whose fmcb did not answer, by why (``{k}``: finger).
_FINGER_ADVICE = {
    "unpowered": ": bring it up with `handctl up --finger {k}`",
    "link_down": ": it has left the palm (broken away); push it back on",
    "no_reply": ": booting, or off its pogo pins? `handctl up --finger {k}` waits for it",
}


def _status_text(state: HandState, no_reply: str = "") -> str:
    """``no_reply``: the advice for a finger whose status got no reply (``{k}``: finger)."""
    advice = {**_FINGER_ADVICE, "no reply": no_reply}
    lines = [f"palm: effort cap {state.effort_cap}/255, polling {state.poll_hz} Hz, "
             f"supply {state.bus_voltage_mv} mV"]
    for f in state.fingers:
        if not f.present:
            why = f" ({f.problem}{advice.get(f.problem or '', '').format(k=f.index)})"
            lines.append(f"finger {f.index}: power {f.power}, not answering"
                         + (why if f.problem else ""))
            continue
        q = ", ".join(f"{v:+.3f}" for v in f.joints)
        taxels = sum(len(v) for v in f.tactile.values())
        lines.append(f"finger {f.index}: power {f.power}, joints [{q}] rad, halls "
                     f"{f.joints_hall}, {taxels} taxels, supply {f.currents['supply']} mA, "
                     f"phalange bus {f.currents['phalange_bus']} mA"
                     + (f", logic {f.supply_v:.2f} V" if f.supply_v is not None else "")
                     + (", motors " + "/".join(f"{t:.1f}" for t in f.temperatures_c) + " °C"
                        if f.temperatures_c else ""))
    return "\n".join(lines)


def _up_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--finger", type=int, choices=range(FINGERS), metavar="N",
                   help="one finger, 0..3 (default: every finger)")
    p.add_argument("--boot-timeout", type=number_above(0), default=BOOT_TIMEOUT_S, metavar="S",
                   help=f"longest wait for a board to boot after its power is switched on "
                        f"(s, default {BOOT_TIMEOUT_S:g}; by the board's own clock while it "
                        f"answers from its bootloader)")


@COMMANDS.command("up", "bring the fingers up after power-on: power, boot, phalange power, "
                  "autopoll (about 10 s)", _up_arguments)
def _cmd_up(hand: Hand, args: argparse.Namespace) -> int:
    """Bring the hand (or ``--finger``) up; progress lines as it goes (on stderr with
    ``--json``, so stdout stays one JSON document)."""
    progress = sys.stderr if args.json else sys.stdout
    results = hand.bring_up("all" if args.finger is None else args.finger,
                            timeout=args.boot_timeout,
                            on_progress=lambda line: print(line, file=progress, flush=True))
    down = [where for r in results for where in r.down]
    down += [f"finger {r.finger} autopoll" for r in results
             if not r.autopoll and r.nodes and r.nodes[0].up]
    summary = (f"up: {sum(n.up for r in results for n in r.nodes)} of "
               f"{sum(len(r.nodes) for r in results)} finger boards run their application, "
               f"autopoll on for finger(s) "
               f"{', '.join(str(r.finger) for r in results if r.autopoll) or 'none'}")
    _emit(args, {"fingers": [r.to_dict() for r in results], "down": down}, summary)
    if not down:
        return 0
    problems = [f"  {n.where}: {n.problem}" for r in results for n in r.nodes if not n.up]
    problems += [f"  finger {r.finger} fmcb: {r.autopoll_problem}" for r in results
                 if r.autopoll_problem]
    print(f"handctl: not up: {', '.join(down)}\n" + "\n".join(problems), file=sys.stderr)
    return EXIT_ROBOT


def _power_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("finger", help="0..3 or all")
    p.add_argument("state", choices=("off", "low", "full"))


@COMMANDS.command("power", "switch finger power", _power_arguments)
def _cmd_power(hand: Hand, args: argparse.Namespace) -> int:
    finger: int | str = args.finger
    if finger != "all":
        try:
            finger = int(finger)
        except ValueError:
            raise UsageError(f"finger {args.finger!r}: give 0..3 or all") from None
    states = hand.power(finger, args.state)
    text = "power: " + ", ".join(f"finger {k} {s}" for k, s in enumerate(states))
    if args.state != "off":
        text += (f"\n(fingers switched on boot for about {AUTOBOOT_WINDOW_US / 1e6:g} s before "
                 "they answer; their phalanges need power too: `handctl up` does it all and "
                 "waits)")
    _emit(args, {"power": states}, text)
    return 0


def _move_arguments(p: argparse.ArgumentParser) -> None:
    group = p.add_mutually_exclusive_group(required=True)
    group.add_argument("--hand", type=_floats, metavar="Q0,…,Q11", help="12 joint targets")
    group.add_argument("--joints", type=_floats, metavar="Q0,Q1,Q2",
                       help="3 joint targets of --finger")
    p.add_argument("--finger", type=int, help="finger index for --joints")
    p.add_argument("--effort", type=int, help="per-joint effort cap, 0..255")
    p.add_argument("--duration", type=number_above(0), default=3.0,
                   help="seconds to wait for the move to settle (default 3)")
    p.add_argument("--clamp", action="store_true",
                   help="clamp targets beyond the joint limits instead of refusing")
    p.add_argument("--unhomed", action="store_true",
                   help="move fingers that were never homed (joint angles then mean "
                        "nothing)")


@COMMANDS.command("move", "move joints (rad) and wait until they settle", _move_arguments)
def _cmd_move(hand: Hand, args: argparse.Namespace) -> int:
    if args.clamp:
        hand.limits = hand.limits.with_action("clamp")
    if args.hand is not None:
        result = hand.move(args.hand, effort=args.effort, timeout=args.duration,
                           unhomed=args.unhomed)
    else:
        if args.finger is None:
            raise UsageError("--joints needs --finger N (0..3)")
        if not 0 <= args.finger < len(hand.fingers):
            raise UsageError(f"finger {args.finger}: the hand has fingers 0..3")
        result = hand.move_fingers({args.finger: args.joints}, effort=args.effort,
                                   timeout=args.duration, unhomed=args.unhomed)
    _emit(args, _move_dict(result), _move_text(result))
    if result.settled:
        return 0
    print(f"handctl: the move did not settle within {args.duration} s "
          f"(stalled fingers: {result.stalled or 'none'}); an obstacle, too little "
          f"--effort, or a longer --duration?{_slow_robot(result)}", file=sys.stderr)
    return EXIT_ROBOT


#: Below this :attr:`MoveResult.robot_rate` a move that did not settle says the robot's
#: clock ran slow.
SLOW_ROBOT_RATE = 0.8


def _slow_robot(result: MoveResult) -> str:
    """What a move that did not settle adds when the robot's clock ran slower than the
    link's: the emulator on a busy machine."""
    rate = result.robot_rate
    if rate is None or rate >= SLOW_ROBOT_RATE:
        return ""
    return (f"\nThe robot's clock ran at {rate:.0%} of this link's meanwhile (the emulator on "
            f"a busy machine runs slower than real time), so the move had only about "
            f"{result.elapsed_s * rate:.1f} s of robot time: give --duration "
            f"{result.elapsed_s / max(rate, 0.05):.0f} or more")


def _move_dict(r: MoveResult) -> dict[str, Any]:
    return {"settled": r.settled, "stalled": r.stalled, "elapsed_s": round(r.elapsed_s, 4),
            "robot_rate": None if r.robot_rate is None else round(r.robot_rate, 3),
            "fingers": {str(k): {"joints": list(s.joints), "error": list(r.errors[k])}
                        for k, s in r.states.items()}}


def _move_text(r: MoveResult) -> str:
    lines = [f"{'settled' if r.settled else 'not settled'} after {r.elapsed_s:.2f} s"]
    for k, s in r.states.items():
        q = ", ".join(f"{v:+.3f}" for v in s.joints)
        e = ", ".join(f"{v:+.3f}" for v in r.errors[k])
        lines.append(f"finger {k}: joints [{q}] rad, error [{e}] rad")
    return "\n".join(lines)


def _home_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--finger", type=int, help="one finger (default: every finger)")
    _calibration_argument(p)


@COMMANDS.command("home", "set the hall offsets from the accelerometers (no joint axis near "
                  "vertical)", _home_arguments)
def _cmd_home(hand: Hand, args: argparse.Namespace) -> int:
    _use_calibration(hand, args)
    try:
        results = hand.home(args.finger)
    except UnobservableJointError as exc:  # one finger asked for: an error, with the way out
        raise UsageError("\n".join([str(exc), *tilt_hints([args.finger])])) from exc
    lines = []
    for r in results:
        if r.homed and r.joints is not None:
            q = ", ".join(f"{v:+.3f}" for v in r.joints)
            lines.append(f"finger {r.finger}: homed at [{q}] rad")
        else:
            problem = str(r.problem).removeprefix(f"finger {r.finger}: ")
            lines.append(f"finger {r.finger}: not homed: {problem}")
    lines += tilt_hints([r.finger for r in results if r.unobservable])
    _emit(args, {"fingers": [r.to_dict() for r in results]}, "\n".join(lines))
    return 0 if all(r.homed for r in results) else EXIT_ROBOT


def _calibrate_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--fingers", type=_finger_list, metavar="K,…",
                   help="only these fingers, e.g. 3 (default: all four)")
    p.add_argument("--out", metavar="PATH",
                   help="the calibration file to write (default: this robot's, in "
                        "$LOWCOST_CALIBRATION_DIR or ~/.config/lowcost-hand/calibration)")
    p.add_argument("--replace-other-robot", action="store_true",
                   help="overwrite a file at --out that holds another robot's calibration")


@COMMANDS.command("calibrate", "fit the accelerometers' mounting, bias and scale from poses the "
                  "fingers take (they move!) and write the calibration file",
                  _calibrate_arguments)
def _cmd_calibrate(hand: Hand, args: argparse.Namespace) -> int:
    info = hand.palm.identify()
    if info.uid is None:
        raise NodeError(f"the palm did not say its uid: {info.problem}")
    serial = serial_of_uid(info.uid)
    if args.out is not None and args.out == NO_CALIBRATION:
        raise UsageError("--out none: give the calibration file's path")
    out = calibration_path(serial) if args.out is None else args.out
    fingers = args.fingers if args.fingers is not None else list(range(FINGERS))

    def progress(finger: int, done: int, total: int) -> None:
        end = "\n" if done == total else ""
        print(f"\rcalibrating finger {finger}: pose {done}/{total}", end=end, file=sys.stderr,
              flush=True)

    cal, fits = calibrate_fingers([hand.fingers[k] for k in fingers], progress)
    written = save_section(out, serial, "hand", cal.to_section(fits=fits,
                                                               firmware=info.fw_version),
                           replace_other_robot=args.replace_other_robot)
    lines = []
    for k, fit in sorted(fits.items()):
        boards = ", ".join(f"{b} tilt {np.degrees(np.linalg.norm(c.rotation_vector)):.2f}° "
                           f"bias [{', '.join(f'{v:+.0f}' for v in c.bias)}] mg"
                           for b, c in fit.boards.items())
        lines.append(f"finger {k}: {fit.poses} poses, residual {fit.rms_counts:.2f} mg; {boards}")
        lines.append(f"finger {k}: not observable from these poses (left at nominal): "
                     + (", ".join(fit.unobservable()) or "nothing"))
    lines.append(f"wrote {out} (robot {serial}, sections: {', '.join(written.sections)})")
    _emit(args, {"path": str(out), "robot_serial": serial,
                 "hand": written.sections["hand"]}, "\n".join(lines))
    return 0


def _grasp_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("name", help="grasp or pose name")
    p.add_argument("amount", type=finite("a number 0..1"),
                   help="0 (open / relaxed) .. 1 (closed / pose)")
    p.add_argument("--speed", type=number_in(0, MAX_SPEED_RAD_S, what="a speed (rad/s)"),
                   default=DEFAULT_SPEED_RAD_S,
                   help=f"blend speed of the joint moving most, rad/s "
                        f"(default {DEFAULT_SPEED_RAD_S})")
    p.add_argument("--fingers", type=_finger_list, metavar="K,…",
                   help="only these fingers, e.g. 0,1,3 (default: all four)")
    p.add_argument("--until-contact", action="store_true",
                   help="stop closing a finger when its taxels or effort say contact")
    p.add_argument("--effort", type=int, help="per-joint effort cap, 0..255")
    p.add_argument("--layout", choices=sorted(HAND_LAYOUTS), default=DEFAULT_HAND_LAYOUT,
                   help=f"the hand frame (default {DEFAULT_HAND_LAYOUT})")
    p.add_argument("--duration", type=number_above(0), default=3.0,
                   help="seconds to wait for the fingers to settle after the blend")
    p.add_argument("--unhomed", action="store_true",
                   help="move fingers that were never homed (joint angles then mean "
                        "nothing)")


@COMMANDS.command("grasp", "blend towards a grasp or pose (host.hand.grasp): "
                  + ", ".join(sorted(SYNERGIES)), _grasp_arguments)
def _cmd_grasp(hand: Hand, args: argparse.Namespace) -> int:
    hand.layout = args.layout
    try:
        result = hand.grasp(args.name, args.amount, speed=args.speed, effort=args.effort,
                            until_contact=args.until_contact, timeout=args.duration,
                            unhomed=args.unhomed, fingers=args.fingers)
    except RouteError as exc:  # one finger unreachable: the others could still grasp
        chosen = args.fingers or list(range(FINGERS))
        others = [k for k in chosen if k != exc.finger]
        if exc.finger is None or not others:
            raise
        raise RouteError(f"{exc}\nTo grasp with the others: --fingers "
                         f"{','.join(map(str, others))}", status=exc.status,
                         finger=exc.finger, hop=exc.hop) from exc
    move = result.move
    assert move is not None
    data = {"grasp": result.name, "amount": result.amount,
            "targets": {str(k): list(q) for k, q in result.targets.items()},
            "contacts": {str(k): why for k, why in result.contacts.items()},
            **_move_dict(move)}
    lines = [f"{result.name} {result.amount:g}: "
             f"{'settled' if move.settled else 'not settled'} after {result.elapsed_s:.2f} s"]
    for k, s in move.states.items():
        q = ", ".join(f"{v:+.3f}" for v in s.joints)
        t = ", ".join(f"{v:+.3f}" for v in result.targets[k])
        why = f", contact: {result.contacts[k]}" if k in result.contacts else ""
        lines.append(f"finger {k}: joints [{q}] rad, target [{t}] rad{why}")
    _emit(args, data, "\n".join(lines))
    if move.settled or result.contacts:
        return 0
    if slow := _slow_robot(move):
        print(f"handctl: {result.name} did not settle within {args.duration} s after the "
              f"blend.{slow}", file=sys.stderr)
    return EXIT_ROBOT


def _record_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file")
    p.add_argument("--seconds", type=number_above(0), required=True,
                   help="how long to record (s)")
    p.add_argument("--rate", type=number_above(0), default=50.0,
                   help="state rate (Hz, default 50)")


def _record_check(args: argparse.Namespace) -> None:
    """Refuse a recording file that cannot be written before the link opens."""
    if problem := unwritable(args.file):
        raise UsageError(f"cannot write the recording to {args.file}: {problem}")


@COMMANDS.command("record", "record frames and states to an MCAP file", _record_arguments,
                  check=_record_check)
def _cmd_record(hand: Hand, args: argparse.Namespace) -> int:
    from host.hand.recording import HandRecorder

    with HandRecorder(hand, args.file) as recorder:
        try:
            recorder.record(args.seconds, args.rate)
        except (UsageError, RecordingError):
            raise  # refused before it began; or the file itself failed: its message says so
        except (HostError, KeyboardInterrupt):
            recorder.close()  # a whole, readable file of what came before
            print(f"handctl: {args.file}: kept what was recorded before it stopped: "
                  f"{recorder.frames} frames, {recorder.states} states", file=sys.stderr)
            raise
    recorder.check()  # finishing the file (its summary) can fail too
    _emit(args, {"file": args.file, "frames": recorder.frames, "states": recorder.states},
          f"{args.file}: {recorder.frames} frames, {recorder.states} states")
    return 0


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="handctl", description=__doc__.split("\n\n")[0])
    add_common_arguments(p, what="the palm's port")
    add_view_arguments(p)
    COMMANDS.add_parsers(p.add_subparsers(dest="command", required=True))
    options_anywhere(p)  # before the sub-command or after it
    return p


def _run(args: argparse.Namespace) -> int:
    COMMANDS.check(args)
    with Hand.open(args.port, timeouts=hand_timeouts(args), view=view_spec(args)) as hand:
        try:
            return COMMANDS.run(hand, args)
        except NodeError as exc:
            # The link's node does not know a palm request: is it a palm at all?
            if exc.status == TxnStatus.UNKNOWN_TYPE:
                try:
                    board = hand.palm.request("identify", retries=0)["board"]
                except HostError:
                    board = None
                if (not_palm := _not_a_palm(board, args.port)) is not None:
                    raise NodeError(not_palm) from exc
            raise


@guard_output("handctl")
def main(argv: Sequence[str] | None = None) -> int:
    """Run handctl; returns the exit status."""
    # Phalanges unpowered for one finger's homing: the user's next step is `handctl up`
    # (exit 2, as a usage error, though the library no longer calls it one).
    return run_cli(_parser(), argv, _run, usage=(NoAccelerationError,))


if __name__ == "__main__":
    sys.exit(main())
