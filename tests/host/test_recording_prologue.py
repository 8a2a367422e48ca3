"""A link's prologue (its first messages, kept for a recorder that attaches later) and what
an in-process link says of the programs before it."""

from __future__ import annotations

from hil_emulator.emulator import Emulator
from hil_emulator.inprocess import EmulatorTransport, bring_up
from host.arm.bus import DynamixelBus
from host.recording.prologue import Prologue
from protocol.dynamixel import make_ping


def test_a_prologue_keeps_its_first_messages_and_says_when_it_left_some_out() -> None:
    prologue = Prologue(limit=3)
    for k in range(3):
        prologue.add("tx", 0.1 * k, bytes([k]))
    assert prologue.state() == "complete"
    prologue.add("rx", 0.4, b"late")
    assert prologue.state() == "partial"
    assert [m[2] for m in prologue.messages] == [b"\x00", b"\x01", b"\x02"]


def test_the_bus_keeps_its_opening_until_a_listener_takes_the_bytes() -> None:
    with Emulator("arm", can="none") as emulator:
        _watch_the_bus(DynamixelBus(EmulatorTransport(emulator, "arm")))


def _watch_the_bus(bus: DynamixelBus) -> None:
    bus.exchange([make_ping(1)])
    kept = list(bus.prologue.messages)
    assert kept and kept[0][0] == "tx" and kept[0][2] == make_ping(1).encode()
    assert bus.prologue.complete
    seen: list[str] = []
    bus.on_bytes = lambda direction, data, t: seen.append(direction)
    bus.exchange([make_ping(2)])
    assert seen and bus.prologue.messages == kept  # the listener has them, not the prologue
    assert not bus.prologue.complete  # a later recorder would miss what this one took


def test_an_emulator_link_tells_a_new_transport_what_earlier_ones_sent() -> None:
    with Emulator("hand", physics=False, can="none") as emulator:
        _two_programs(emulator)


def _two_programs(emulator: Emulator) -> None:
    bring_up(emulator)  # the emulator's own bring-up: not a host program's
    first = EmulatorTransport(emulator, "palm")
    assert first.sent_before() == []
    first.send(b"\x42\x0a\x00\x00\x01\x00\x00")
    first.close()
    second = EmulatorTransport(emulator, "palm")
    earlier = second.sent_before()
    assert earlier is not None and [data for _t, data in earlier] == [
        b"\x42\x0a\x00\x00\x01\x00\x00"]
    second.send(b"more")
    assert second.sent_before() == earlier  # only what came before it opened
