"""``make demo``: the robot brought up over the wire, on the built-in emulator.

Starts ``hil-emulator --config full`` (the hand on the arm's wrist) in its own process and,
as a host would over its serial ports:

1. waits for the palm's application and identifies it;
2. powers the four fingers, identifies each fmcb, powers their phalanges, identifies each
   f2 and f3 through the palm (thirteen hand microcontrollers in all);
3. moves finger 1 (joint targets through ``fmcb.control``) and reads its hall counts back
   as joint angles;
4. on the arm port, with the stock dynamixel-sdk: pings IDs 1–7, enables torque, moves the
   shoulder pan and the wrist, and reads the present positions back through the physics.

Every reply is printed as it comes back; a node that does not answer is reported and the
demo goes on with the others.  Exit status 0 only if every node answered and the joints
moved; otherwise the last line is ``demo: FAILED ...`` and the status 1 (never a traceback).
"""

from __future__ import annotations

import functools
import json
import math
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from protocol.control_tables import RX64_TABLE, STEPPER_TABLE
from protocol.image import BoardType
from protocol.robot import motor_to_joint, rad_to_encoder_counts
from protocol.topology import ARM_BUS_BAUD, ARM_JOINTS, FINGERS, HOP_ADDRESS, STEPPER_IDS, Hop
from tools.hand_port import HandPort, ReplyTimeout

ROOT = Path(__file__).resolve().parents[1]
FINGER_TARGET = (0.0, 0.4, 0.3)  # rad, J1 J2 J3 of finger 1
#: Joint 1: +10° in joint encoder counts (278); servo 6: −50 position units.
ARM_MOVES = {1: rad_to_encoder_counts(math.radians(10.0)), 6: -50}


def say(text: str) -> None:
    print(text, flush=True)


def until(what: Callable[[], dict[str, Any]], timeout_s: float) -> dict[str, Any]:
    """Ask until the node's application (not its bootloader) answers."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            reply = what()
            if reply.get("running", 1):
                return reply
        except ReplyTimeout:
            if time.monotonic() > deadline:
                raise
        if time.monotonic() > deadline:
            raise ReplyTimeout("the application did not start")
        time.sleep(0.1)


def describe(reply: dict[str, Any]) -> str:
    version = reply["fw_version"]
    return (f"{BoardType(reply['board']).name.lower():5s} uid {reply['uid']:#06x}  "
            f"firmware {version['major']}.{version['minor']}.{version['patch']}  "
            f"up {reply['uptime_us'] / 1e6:.2f} s")


def ask(label: str, what: Callable[[], dict[str, Any]], timeout_s: float = 10
        ) -> dict[str, Any] | None:
    """:func:`until`, printing the reply, or that ``label`` did not answer (None)."""
    try:
        reply = until(what, timeout_s)
    except ReplyTimeout:
        say(f"{label} did not answer within {timeout_s:g} s")
        return None
    say(f"{label} {describe(reply)}")
    return reply


def hand_session(palm_path: str) -> int:
    answered = 0
    with HandPort(palm_path) as hand:
        if ask("palm        ", lambda: hand.request("identify", timeout_s=0.2)) is None:
            say("hand: the palm did not answer; nothing else to ask")
            return 1
        answered += 1
        states = hand.request("palm.finger_power", finger=0xFF, state=2, stagger_ms=5)
        say(f"finger power on: {states}")
        for k in range(FINGERS):
            if ask(f"finger {k} fmcb", functools.partial(hand.route, k, 0, "identify")):
                answered += 1
                hand.route(k, Hop.FMCB, "fmcb.phalange_power", on=1)
        for k in range(FINGERS):
            for hop, name in ((Hop.F2, "f2"), (Hop.F3, "f3")):
                if ask(f"finger {k} {name}  ",
                       functools.partial(hand.route, k, hop, "identify")):
                    answered += 1
        _move_finger(hand)
        counts = hand.route(1, 0, "fmcb.hall_counts", raw=0)
        joints = motor_to_joint(counts["counts"])
        say(f"finger 1 joints after the move: {[round(q, 3) for q in joints]} rad "
            f"(target {list(FINGER_TARGET)})")
        moved = abs(joints[1] - FINGER_TARGET[1]) < 0.15
    say(f"hand: {answered} of 13 microcontrollers answered; finger moved: {moved}")
    return 0 if answered == 13 and moved else 1


def _move_finger(hand: HandPort) -> None:
    """``fmcb.control`` has no reply: route it with a zero timeout and let it act."""
    from protocol.messages import CATALOGUE

    inner = CATALOGUE["fmcb.control"].request_frame(
        HOP_ADDRESS[Hop.FMCB], {"mode": 2, "args": {"target": FINGER_TARGET}})
    reply = hand.request("palm.route", finger=1, hop=Hop.FMCB, timeout_ms=0, frame=inner)
    say(f"finger 1 fmcb.control joint targets {list(FINGER_TARGET)} rad: route status "
        f"{reply['status']}")
    time.sleep(2.0)


def arm_session(arm_path: str) -> int:
    from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

    port = PortHandler(arm_path)
    if not (port.openPort() and port.setBaudRate(ARM_BUS_BAUD)):
        say(f"cannot open the arm port {arm_path}")
        return 1
    sdk = PacketHandler(1.0)
    ok = 0
    try:
        start: dict[int, int] = {}
        for joint in ARM_JOINTS:
            dxl_id = joint.dxl_id
            table = STEPPER_TABLE if joint.is_stepper else RX64_TABLE
            model, result, error = sdk.ping(port, dxl_id)
            if result != COMM_SUCCESS:
                say(f"arm id {dxl_id}: no answer ({sdk.getTxRxResult(result)})")
                continue
            start[dxl_id] = _position(sdk, port, dxl_id)
            sdk.write1ByteTxRx(port, dxl_id, table["torque_enable"].address, 1)
            kind = "stepper joint" if joint.is_stepper else "RX-64 servo"
            say(f"arm id {dxl_id}: model {model:#06x} ({kind}), position {start[dxl_id]}, "
                f"error byte {error}")
            ok += 1
        moves = {i: delta for i, delta in ARM_MOVES.items() if i in start}
        for dxl_id in ARM_MOVES.keys() - moves.keys():
            say(f"arm id {dxl_id}: not moved (it did not answer)")
        for dxl_id, delta in moves.items():
            table = STEPPER_TABLE if dxl_id in STEPPER_IDS else RX64_TABLE
            size = 4 if dxl_id in STEPPER_IDS else 2
            goal = start[dxl_id] + delta
            write = sdk.write4ByteTxRx if size == 4 else sdk.write2ByteTxRx
            write(port, dxl_id, table["goal_position"].address, goal & (2 ** (8 * size) - 1))
            say(f"arm id {dxl_id}: goal {goal}")
        time.sleep(2.0)
        moved = 0
        for dxl_id, delta in moves.items():
            now = _position(sdk, port, dxl_id)
            say(f"arm id {dxl_id}: present position {now} (moved {now - start[dxl_id]} "
                f"of {delta})")
            moved += abs(now - start[dxl_id] - delta) <= 0.25 * abs(delta)
    finally:
        port.closePort()
    say(f"arm: {ok} of 7 nodes answered; {moved} of {len(ARM_MOVES)} joints reached their goal")
    return 0 if ok == len(ARM_JOINTS) and moved == len(ARM_MOVES) else 1


def _position(sdk: Any, port: Any, dxl_id: int) -> int:
    if dxl_id in STEPPER_IDS:
        value, _, _ = sdk.read4ByteTxRx(port, dxl_id, STEPPER_TABLE["present_position"].address)
        return int(value) - (1 << 32) if value & 0x8000_0000 else int(value)
    value, _, _ = sdk.read2ByteTxRx(port, dxl_id, RX64_TABLE["present_position"].address)
    return int(value)


def main() -> int:
    say("# hil-emulator --config full  (the hand on the arm's wrist)")
    proc = subprocess.Popen([sys.executable, "-m", "tools.hil_emulator", "--config", "full"],
                            cwd=ROOT, stdout=subprocess.PIPE, text=True)
    why = "a node did not answer or a joint did not move"
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        if not line:
            why = "the emulator did not start (its error is above)"
            status = 1
        else:
            ports = json.loads(line)
            say(f"ports: {json.dumps(ports)}")
            status = _session("hand", hand_session, ports["palm"])
            status |= _session("arm", arm_session, ports["arm"])
    except KeyboardInterrupt:
        why, status = "interrupted", 1
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
    say("demo: " + ("every node answered and the joints moved" if status == 0
                    else f"FAILED ({why})"))
    return status


def _session(name: str, session: Callable[[str], int], path: str) -> int:
    """Run one session; an error on the wire is reported as a failure, not a traceback."""
    try:
        return session(path)
    except Exception as exc:  # noqa: BLE001 - a demo reports, it does not crash
        say(f"{name}: stopped by {type(exc).__name__}: {exc}")
        return 1


if __name__ == "__main__":
    sys.exit(main())
