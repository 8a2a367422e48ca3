"""The control channel (``hil_emulator/faults/control.py``): faults injected into a running
emulator, its ground truth, and the ``hil-emulator`` command taking faults from another
process."""

from __future__ import annotations

import json
import os
import socket
from pathlib import Path

import pytest

from protocol.dynamixel import make_ping
from tests.ground_truth import arm_plant_of, arm_rig_of
from tests.hil_emulator.faults.probes import MS, FaultyEmulator


def test_the_control_channel_injects_into_a_running_emulator(tmp_path: Path) -> None:
    emu = FaultyEmulator("arm", physics=False)
    path = emu.open_control(str(tmp_path / "control"))
    client = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        client.connect(path)
        client.sendall(b'{"op": "inject", "fault": "line_cut", "params": {"bus": "arm"}}\n'
                       b'{"op": "inject", "fault": "line_cut", "params": {"wire": 1}}\n')
        emu.step(1 * MS)
        answers = [json.loads(line) for line in client.recv(4096).splitlines()]
        assert answers[0]["ok"] and answers[0]["id"] == 0
        assert not answers[1]["ok"] and "params.wire" in answers[1]["error"]
        assert arm_rig_of(emu).bus.line_cut
        client.sendall(b'{"op": "clear", "id": 0}\n{"op": "timeline"}\n')
        emu.step(1 * MS)
        lines = client.recv(65536).splitlines()
        assert json.loads(lines[0]) == {"ok": True}
        assert [e["action"] for e in json.loads(lines[1])["events"]] == ["apply", "clear"]
        assert not arm_rig_of(emu).bus.line_cut
        client.sendall(b'{"op": "status"}\n')
        t_us = emu.scheduler.now_us()
        emu.step(1 * MS)
        status = json.loads(client.recv(65536))
        assert status["ok"] and status["t_us"] == t_us  # the simulation clock when read
        assert status["max_ms"] is None and status["slipped_s"] == 0.0  # never paced
        assert status["count"] == 0 and type(status["count"]) is int
        assert type(status["late_episodes"]) is int
        client.sendall(b"status\n[1, 2]\n\xff\xfe\n")  # not JSON objects
        emu.step(1 * MS)
        errors = [json.loads(line) for line in client.recv(65536).splitlines()]
        assert [e["ok"] for e in errors] == [False, False, False]
        assert all('{"op": "status"}' in e["error"] for e in errors)
        assert errors[0]["error"].startswith("not a JSON line")
    finally:
        client.close()
        emu.close()
    assert not os.path.exists(path)


def _ask(client: socket.socket, emu: FaultyEmulator, request: bytes) -> dict[str, object]:
    """One control-channel request answered while ``emu`` steps 1 ms."""
    client.sendall(request + b"\n")
    emu.step(1 * MS)
    answer: dict[str, object] = json.loads(client.recv(65536))
    return answer


def test_the_control_channel_tells_the_arm_plants_ground_truth(tmp_path: Path) -> None:
    emu = FaultyEmulator("arm", seed=1)
    path = emu.open_control(str(tmp_path / "control"))
    client = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        client.connect(path)
        emu.step(20 * MS)
        truth = _ask(client, emu, b'{"op": "truth"}')
        assert truth["ok"] and truth["t_us"] == 20 * MS
        arm = truth["arm"]
        assert isinstance(arm, dict)
        assert arm["joints"] == pytest.approx(list(arm_plant_of(emu).joint_angles()), abs=1e-3)
        assert len(arm["velocities"]) == 7 and len(arm["deflections"]) == 4
        assert sorted(arm["nodes"], key=int) == [str(i) for i in range(1, 8)]
        assert all(n["torque_enable"] == 0 for n in arm["nodes"].values())  # comes up off
        assert emu.arm is not None
        emu.arm.app(2).set("torque_enable", 1)
        arm = _ask(client, emu, b'{"op": "truth"}')["arm"]
        assert isinstance(arm, dict)
        assert [n["torque_enable"] for n in arm["nodes"].values()] == [0, 1, 0, 0, 0, 0, 0]
    finally:
        client.close()
        emu.close()
    hand = FaultyEmulator("hand", physics=False)
    try:
        client = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        client.connect(hand.open_control(str(tmp_path / "hand-control")))
        assert _ask(client, hand, b'{"op": "truth"}')["arm"] is None
        client.close()
    finally:
        hand.close()


def test_the_command_loads_a_plan_and_takes_faults_from_another_process(tmp_path: Path
                                                                        ) -> None:
    import time

    from tests.hil_emulator.emulator_process import running_emulator

    plan = tmp_path / "plan.toml"
    plan.write_text('[[faults]]\nfault = "supply_sag"\nparams = { supply_mv = 6000 }\n'
                    'at_s = 0.0\nduration_s = 0.05\nlabel = "sag"\n')
    links = tmp_path / "links"
    links.mkdir()
    with running_emulator("--config", "arm", "--no-physics", "--link-dir", str(links),
                          "--faults", str(plan)) as info:
        assert info["control"] == str(links / "control") and info["faults"] == 1
        client = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        client.settimeout(10)
        client.connect(info["control"])
        fd = os.open(links / "arm", os.O_RDWR | os.O_NOCTTY)
        try:
            client.sendall(b'{"op": "inject", "fault": "line_cut", "params": {"bus": "arm"}}\n')
            assert json.loads(client.recv(4096))["ok"]
            os.write(fd, make_ping(5).encode())
            time.sleep(0.2)
            os.set_blocking(fd, False)
            with pytest.raises(BlockingIOError):
                os.read(fd, 64)  # the line is cut: no answer
            client.sendall(b'{"op": "clear", "id": 1}\n')
            assert json.loads(client.recv(4096)) == {"ok": True}
            os.write(fd, make_ping(5).encode())
            deadline = time.monotonic() + 5
            reply = b""
            while not reply and time.monotonic() < deadline:
                time.sleep(0.02)
                try:
                    reply = os.read(fd, 64)
                except BlockingIOError:
                    pass
            assert reply[:3] == b"\xff\xff\x05"
        finally:
            os.close(fd)
            client.close()
    timeline = info["stats"]["fault_timeline"]
    assert sorted((e["label"], e["action"]) for e in timeline) == [
        ("line_cut", "apply"), ("line_cut", "clear"), ("sag", "apply"), ("sag", "clear")]
    assert not (links / "control").exists()
