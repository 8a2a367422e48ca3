"""Record what the emulated robot sends its host for a fixed host script and seed.

A refactor that must not change behaviour on the wire proves it with this: run it before and
after, compare the digests (or the JSON-lines files).  Every byte every port sends toward
the host is recorded with the simulation time (µs) of its last bit, and the plant's final
state is hashed, so a change of wire bytes, of firmware timing or of physics shows.

    python -m tools.traffic_record --seed 7 --out run.jsonl      # prints the sha-256 digest

It records the emulator with ``--sensors ideal`` unless told otherwise: the digest of the
ideal robot is the one kept across refactors.

The host script (fixed, in-process, fast mode): bring the hand up as ``--ready`` does, then
ping and identify every hand node through the palm, read statuses, move a finger in joint
mode, poll, read the phalanges' tactile data; on the arm, ping every id, enable torque,
command goals by WRITE and SYNC_WRITE, read positions by READ and BULK_READ; then the
loose-finger configuration: bring-up, a move and a status.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from hil_emulator.emulator import Emulator
from hil_emulator.imperfections import SENSOR_MODES
from hil_emulator.inprocess import bring_up
from protocol import dynamixel as dxl
from protocol.control_tables import RX64_TABLE, STEPPER_TABLE
from protocol.messages import CATALOGUE
from protocol.messages.fmcb import ControlMode
from protocol.topology import (
    ADDR_F2,
    ADDR_PALM,
    ARM_JOINTS,
    FINGERS,
    HOP_ADDRESS,
    SERVO_IDS,
    STEPPER_IDS,
    Hop,
)
from tools.cli.numeric import read_negative_numbers
from tools.cli.output import guard_output

Record = dict[str, Any]
#: The ``palm.route`` timeout of the script's routed requests (ms).
ROUTE_MS = 20


def request(name: str, **fields: Any) -> bytes:
    """The frame carrying request ``name`` to the palm (or a loose finger's fmcb: the same
    address), without the ``txn`` envelope: the script's bytes are fixed."""
    return CATALOGUE[name].request_frame(ADDR_PALM, fields)


def routed(finger: int, name: str, **fields: Any) -> bytes:
    """``palm.route`` carrying request ``name`` to finger ``finger``'s fmcb."""
    return request("palm.route", finger=finger, hop=Hop.FMCB, timeout_ms=ROUTE_MS,
                   frame=CATALOGUE[name].request_frame(HOP_ADDRESS[Hop.FMCB], fields))


def _recorder(port: str, out: list[Record]) -> Callable[[bytes, int], None]:
    def record(data: bytes, t_us: int) -> None:
        out.append({"port": port, "t_us": t_us, "hex": data.hex()})
    return record


def _full_run(seed: int, out: list[Record], sensors: str) -> None:
    emu = Emulator("full", seed=seed, can="none", sensors=sensors)
    assert emu.hand is not None and emu.arm is not None
    emu.hand.on_host_bytes = _recorder("palm", out)
    emu.arm.on_host_bytes = _recorder("arm", out)
    bring_up(emu)
    hand, arm = emu.hand, emu.arm

    def hand_send(frame: bytes, wait_us: int = 20_000) -> None:
        hand.send_from_host(frame)
        emu.step(wait_us)

    hand_send(request("ping"))
    hand_send(request("identify"))
    hand_send(request("palm.hand_status"))
    for finger in range(FINGERS):
        hand_send(routed(finger, "identify"))
        for hop in (Hop.F2, Hop.F3):
            hand_send(request("palm.route", finger=finger, hop=hop, timeout_ms=ROUTE_MS,
                              frame=CATALOGUE["identify"].request_frame(HOP_ADDRESS[hop])))
    hand_send(routed(1, "fmcb.control", mode=ControlMode.JOINT, args={"target": [0.3, 0.6, 0.4]}))
    hand_send(request("palm.poll", rate_hz=50))
    emu.step(800_000)
    hand_send(routed(1, "fmcb.status"))
    hand_send(request("palm.route", finger=1, hop=Hop.F2, timeout_ms=ROUTE_MS,
                      frame=CATALOGUE["f2.tactile"].request_frame(ADDR_F2)))
    hand_send(request("palm.hand_status"))

    def arm_send(packet: dxl.InstructionPacket, wait_us: int = 5_000) -> None:
        arm.send_from_host(packet.encode())
        emu.step(wait_us)

    arm_ids = [joint.dxl_id for joint in ARM_JOINTS]
    for dxl_id in arm_ids:
        arm_send(dxl.make_ping(dxl_id))
    torque = STEPPER_TABLE["torque_enable"].address
    for dxl_id in arm_ids:
        arm_send(dxl.make_write(dxl_id, torque, b"\x01"))
    goal = STEPPER_TABLE["goal_position"]
    arm_send(dxl.make_write(1, goal.address, (300).to_bytes(4, "little", signed=True)))
    servo_goal = RX64_TABLE["goal_position"].address
    arm_send(dxl.make_sync_write(servo_goal, 2, {5: (600).to_bytes(2, "little"),
                                                 6: (400).to_bytes(2, "little"),
                                                 7: (512).to_bytes(2, "little")}))
    emu.step(500_000)
    present = STEPPER_TABLE["present_position"].address
    for dxl_id in STEPPER_IDS:
        arm_send(dxl.make_read(dxl_id, present, 4))
    arm_send(dxl.make_bulk_read([(4, dxl_id, present) for dxl_id in STEPPER_IDS]
                                + [(2, dxl_id, RX64_TABLE["present_position"].address)
                                   for dxl_id in SERVO_IDS]), 10_000)
    emu.step(200_000)
    assert emu.plant is not None
    out.append({"port": "plant", "t_us": emu.scheduler.now_us(),
                "qpos_sha256": _array_digest(emu.plant.data.qpos),
                "qvel_sha256": _array_digest(emu.plant.data.qvel)})


def _loose_run(seed: int, out: list[Record], sensors: str) -> None:
    emu = Emulator("loose-finger", seed=seed, can="none", sensors=sensors)
    assert emu.loose is not None
    emu.loose.on_host_bytes = _recorder("finger0", out)
    bring_up(emu)
    loose = emu.loose
    for frame in (request("identify"),
                  request("fmcb.control", mode=ControlMode.JOINT, args={"target": [0.2, 0.4, 0.2]})):
        loose.send_from_host(frame)
        emu.step(20_000)
    emu.step(500_000)
    loose.send_from_host(request("fmcb.status"))
    emu.step(20_000)
    assert emu.plant is not None
    out.append({"port": "loose-plant", "t_us": emu.scheduler.now_us(),
                "qpos_sha256": _array_digest(emu.plant.data.qpos)})


def _array_digest(values: Any) -> str:
    return hashlib.sha256(np.ascontiguousarray(values, dtype=np.float64).tobytes()).hexdigest()


def record(seed: int = 7, sensors: str = "ideal") -> list[Record]:
    """Run the fixed host script on the full and loose-finger configurations; the records.

    ``sensors`` (``--sensors``): ``"ideal"`` by default, so the digest stays what it was
    before the sensors had imperfections; ``"realistic"`` records the robot as built."""
    out: list[Record] = []
    _full_run(seed, out, sensors)
    _loose_run(seed, out, sensors)
    return out


def digest(records: list[Record]) -> str:
    """SHA-256 over the canonical JSON lines of ``records``."""
    h = hashlib.sha256()
    for line in _lines(records):
        h.update(line.encode())
    return h.hexdigest()


def _lines(records: list[Record]) -> Iterator[str]:
    for rec in records:
        yield json.dumps(rec, sort_keys=True) + "\n"


@guard_output("traffic_record")
def main(argv: list[str] | None = None) -> int:
    """``python -m tools.traffic_record [--seed N] [--sensors ideal|realistic] [--out FILE]``:
    print the run's digest."""
    parser = argparse.ArgumentParser(prog="traffic_record", description=__doc__.split("\n")[0])
    parser.add_argument("--seed", type=int, default=7, help="emulator seed (default 7)")
    parser.add_argument("--sensors", choices=SENSOR_MODES, default="ideal",
                        help="the emulator's sensors (default ideal: the digest of before)")
    parser.add_argument("--out", help="write the records as JSON lines to this file")
    args = read_negative_numbers(parser).parse_args(argv)
    records = record(args.seed, args.sensors)
    if args.out:
        with open(args.out, "w", encoding="utf-8") as fh:
            fh.writelines(_lines(records))
    counts: dict[str, int] = {}
    for rec in records:
        counts[rec["port"]] = counts.get(rec["port"], 0) + 1
    print(json.dumps({"digest": digest(records), "records": counts}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
