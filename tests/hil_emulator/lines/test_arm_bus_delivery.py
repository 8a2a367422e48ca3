"""The arm's line delivers a packet only to the nodes that act on it, and nothing changes.

A whole packet for another node is let pass by an arm node without a look beyond its ID
byte, except the status packet a BULK_READ turn waits for; the bus leaves such packets
undelivered (``Rs485Bus.attach(..., hears=DynamixelSlave.acts_on)``, all nodes asked at once
through ``Rs485Bus.set_audience`` and ``LineAudience``).  What the host gets,
and when, is checked equal to a line that delivers everything to everyone under random
traffic, garbage and packets split across writes included.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil_emulator.arm.rig import ArmRig
from protocol import dynamixel as dxl
from protocol.control_tables import RX64_TABLE, STEPPER_TABLE
from protocol.topology import SERVO_IDS, STEPPER_IDS

ARM_IDS = (*STEPPER_IDS, *SERVO_IDS)
STEPPER_POSITION = STEPPER_TABLE["present_position"].address
SERVO_POSITION = RX64_TABLE["present_position"].address


def bulk_read(ids: list[int]) -> bytes:
    return dxl.make_bulk_read(
        [(4, i, STEPPER_POSITION) if i in STEPPER_IDS else (2, i, SERVO_POSITION)
         for i in ids]).encode()


def count_deliveries(rig: ArmRig) -> dict[int, list[bytes]]:
    """Per node ID, the frames the line hands its UART."""
    got: dict[int, list[bytes]] = defaultdict(list)
    for dxl_id, (hal, _app) in rig.nodes.items():
        uart = hal.uart("bus")
        receiver = uart._receiver
        assert receiver is not None

        def spy(data: bytes, t_us: int, dxl_id: int = dxl_id, receiver=receiver) -> None:  # type: ignore[no-untyped-def]
            got[dxl_id].append(bytes(data))
            receiver(data, t_us)

        uart.set_receiver(spy)
    return got


def test_a_status_packet_reaches_the_host_and_the_next_node_of_the_chain_only() -> None:
    rig = ArmRig(seed=1)
    host: list[bytes] = []
    rig.on_host_bytes = lambda data, t: host.append(data)
    got = count_deliveries(rig)
    order = [3, 1, 6]
    request = bulk_read(order)
    rig.send_from_host(request)
    rig.run_for(5_000)
    assert [dxl.decode_packet(p)[0] for p in host] == order
    status = {dxl.decode_packet(p)[0]: p for p in host}
    assert got[3] == [request]  # first in the chain: the request only
    assert got[1] == [request, status[3]]  # waits for 3's status
    assert got[6] == [request, status[1]]  # waits for 1's status
    for other in set(ARM_IDS) - set(order):
        assert got[other] == [request]  # a BULK_READ is broadcast; no status packet


def test_a_node_with_half_a_packet_still_hears_everything() -> None:
    rig = ArmRig(seed=1)
    got = count_deliveries(rig)
    ping = dxl.make_ping(4).encode()
    rig.send_from_host(dxl.make_ping(2).encode()[:3])  # a header, then silence
    rig.run_for(100)
    rig.send_from_host(ping)
    rig.run_for(2_000)
    assert all(ping in frames for frames in got.values())


PACKETS = st.one_of(
    st.lists(st.sampled_from(ARM_IDS), min_size=1, max_size=7, unique=True).map(bulk_read),
    st.sampled_from(ARM_IDS).map(lambda i: dxl.make_ping(i).encode()),
    st.sampled_from(STEPPER_IDS).map(
        lambda i: dxl.make_read(i, STEPPER_POSITION, 4).encode()),
    st.sampled_from(SERVO_IDS).map(lambda i: dxl.make_read(i, SERVO_POSITION, 2).encode()),
    st.binary(min_size=1, max_size=12),  # garbage
)
TRAFFIC = st.lists(st.tuples(PACKETS, st.integers(0, 6), st.integers(0, 3_000)),
                   min_size=1, max_size=12)


def host_view(traffic: list[tuple[bytes, int, int]], every_node_hears_all: bool
              ) -> list[tuple[bytes, int]]:
    rig = ArmRig(seed=3)
    if every_node_hears_all:
        for node in rig.bus._nodes:
            node.hears = None
            node.by_audience = False
    else:
        # The line asks all nodes at once (LineAudience): each time, what every node's
        # own acts_on says.
        picked = rig.bus._audience
        assert picked is not None

        def checked(data: bytes) -> Sequence[object]:
            keys = picked(data)
            assert list(keys) == [hal.uart("bus") for hal, app in rig.nodes.values()
                                  if app.acts_on(data)]
            return keys

        rig.bus._audience = checked
    seen: list[tuple[bytes, int]] = []
    rig.on_host_bytes = lambda data, t: seen.append((bytes(data), t))
    for packet, split, gap_us in traffic:
        cut = min(split, len(packet))
        rig.send_from_host(packet[:cut])  # a packet split across two writes, sometimes
        rig.run_for(gap_us // 10)
        rig.send_from_host(packet[cut:])
        rig.run_for(gap_us)
    rig.run_for(20_000)
    return seen


@settings(max_examples=60, deadline=None)
@given(TRAFFIC)
def test_the_host_sees_the_same_as_on_a_line_that_delivers_everything(
        traffic: list[tuple[bytes, int, int]]) -> None:
    assert host_view(traffic, every_node_hears_all=False) == host_view(
        traffic, every_node_hears_all=True)


def test_unplugging_a_node_the_audience_asks_for_hands_the_verdicts_back_to_each_node() -> None:
    rig = ArmRig(seed=1)
    host: list[bytes] = []
    rig.on_host_bytes = lambda data, t: host.append(data)
    rig.bus.detach(rig.nodes[7][0].uart("bus"))
    assert rig.bus._audience is None
    assert not any(node.by_audience for node in rig.bus._nodes)
    got = count_deliveries(rig)
    ping = dxl.make_ping(3).encode()
    rig.send_from_host(ping)
    rig.run_for(2_000)
    assert [dxl.decode_packet(p)[0] for p in host] == [3]
    # Each node's acts_on: the ping reaches node 3 only, its status the host only.
    assert dict(got) == {3: [ping]}


def test_an_audience_takes_the_uarts_in_the_order_attached() -> None:
    rig = ArmRig(seed=1)
    uarts = [rig.nodes[i][0].uart("bus") for i in (2, 1)]
    with pytest.raises(ValueError, match="order attached"):
        rig.bus.set_audience(uarts, lambda data: uarts)
