"""The whole hand's firmware end to end: host → palm → fmcb → tendon → phalanges and back.

Real bootloaders, real applications, the palm's routing and the fmcb's tunnel; no physics.
"""

from __future__ import annotations

from typing import Any

import pytest

from hil_emulator.hand.rig import HandRig
from hil_emulator.inprocess import BOOT_US
from protocol.framing import parse_frame
from protocol.messages import CATALOGUE
from protocol.stream import decode_all
from protocol.topology import ADDR_PALM, HOP_ADDRESS, Hop

S = 1_000_000  # µs


def ask(rig: HandRig, name: str, wait_us: int = 20_000, **fields: Any) -> dict[str, Any]:
    """Send a request for message ``name`` to the palm and return the parsed reply."""
    msg = CATALOGUE[name]
    rig.take_host_bytes()
    rig.send_from_host(msg.request_frame(ADDR_PALM, fields))
    rig.run_for(wait_us)
    replies = [f for f in decode_all(rig.take_host_bytes()) if f.type == msg.type_id]
    assert replies, f"no reply to {name}"
    return msg.parse_reply(replies[-1].payload)


def route(rig: HandRig, finger: int, hop: int, name: str, timeout_ms: int = 20,
          **fields: Any) -> tuple[int, dict[str, Any] | None]:
    """Route ``name`` to a node behind the palm; return (route status, parsed inner reply)."""
    msg = CATALOGUE[name]
    inner = msg.request_frame(HOP_ADDRESS[Hop(hop)], fields)
    reply = ask(rig, "palm.route", wait_us=(timeout_ms + 10) * 1000, finger=finger, hop=hop,
                timeout_ms=timeout_ms, frame=inner)
    assert (reply["finger"], reply["hop"]) == (finger, hop)
    if reply["status"] != 0:
        return reply["status"], None
    frame = parse_frame(reply["frame"])
    assert frame.type == msg.type_id and frame.address == 0
    return 0, msg.parse_reply(frame.payload)


@pytest.fixture(scope="module")
def booted_hand() -> HandRig:
    """A hand with the palm booted, all fingers at full power and phalanges powered."""
    rig = HandRig(line_model=True, seed=3)
    rig.power_on()
    rig.run_for(BOOT_US)  # palm bootloader window, then the palm application
    assert rig.palm.program_name == "palm"
    ask(rig, "palm.finger_power", finger=0xFF, state=2, stagger_ms=5)
    rig.run_for(BOOT_US)  # fmcb bootloaders, then the applications
    for k in range(4):
        assert ask(rig, "palm.finger_power", finger=k, state=2, stagger_ms=0)["states"] == [2] * 4
        status, _ = route(rig, k, 0, "fmcb.phalange_power", on=1)
        assert status == 0
    rig.run_for(BOOT_US)  # phalange bootloaders, then f2/f3 applications
    return rig


@pytest.mark.slow
def test_every_node_answers_through_the_palm(booted_hand: HandRig) -> None:
    rig = booted_hand
    palm_id = ask(rig, "identify")
    assert palm_id["board"] == 1 and palm_id["running"] == 1
    seen_uids = {palm_id["uid"]}
    for k in range(4):
        for hop, board in ((0, 2), (1, 3), (2, 4)):
            status, ident = route(rig, k, hop, "identify")
            assert status == 0 and ident is not None, (k, hop)
            assert ident["board"] == board and ident["running"] == 1
            seen_uids.add(ident["uid"])
    assert len(seen_uids) == 13  # thirteen distinct microcontrollers answered


@pytest.mark.slow
def test_phalange_tactile_reaches_the_host_through_the_tunnel(booted_hand: HandRig) -> None:
    rig = booted_hand
    f3_hal = rig.fingers[2].f3.hal
    f3_hal.sensors.values.update({f"taxel{i}": 3000 + i for i in range(12)})  # type: ignore[attr-defined]
    rig.run_for(30_000)
    status, reply = route(rig, 2, 2, "f3.tactile")
    assert status == 0 and reply is not None
    assert reply["taxels"] == [3000 + i for i in range(12)]


@pytest.mark.slow
def test_breakaway_is_reported_and_the_finger_comes_back() -> None:
    rig = HandRig()
    rig.power_on()
    rig.run_for(BOOT_US)
    ask(rig, "palm.finger_power", finger=1, state=2, stagger_ms=0)
    rig.run_for(BOOT_US)
    ask(rig, "palm.poll", rate_hz=50)
    rig.run_for(200_000)
    assert ask(rig, "palm.hand_status")["fingers"][1]["present"] == 1
    rig.take_host_bytes()
    rig.break_away(1)
    rig.run_for(300_000)
    events = [CATALOGUE["palm.finger_event"].parse_reply(f.payload)
              for f in decode_all(rig.take_host_bytes()) if f.type == 0x66]
    assert any(e["finger"] == 1 and e["event"] == 0 for e in events)  # lost
    assert ask(rig, "palm.hand_status")["fingers"][1]["present"] == 0
    status, _ = route(rig, 1, 0, "ping")
    assert status != 0
    rig.reattach(1)
    rig.run_for(BOOT_US)  # its bootloader window, then the application
    assert rig.fingers[1].fmcb.program_name == "fmcb"
    assert route(rig, 1, 0, "ping")[0] == 0
    rig.run_for(300_000)
    assert ask(rig, "palm.hand_status")["fingers"][1]["present"] == 1
