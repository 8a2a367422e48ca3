"""The board table (:data:`protocol.topology.BOARDS`) agrees with the enumerations that name
boards on the wire, and the lists derived from it are the ones the code always had."""

from __future__ import annotations

from protocol.catalogue import NODES
from protocol.interpret import NODE_KINDS_TRIED
from protocol.messages import CATALOGUE
from protocol.topology import (
    ARM_BOARDS,
    BOARDS,
    FINGER_BOARDS,
    HAND_BOARDS,
    HOP_ADDRESS,
    HOP_NODE,
    NODE_ADDRESS,
    BoardType,
    Hop,
    NodeKind,
    board,
)


def test_every_board_type_has_exactly_one_row() -> None:
    assert sorted(b.board_type for b in BOARDS) == sorted(BoardType)
    assert len({b.app for b in BOARDS}) == len(BOARDS)


def test_the_hand_boards_are_the_node_kinds_in_their_order() -> None:
    assert [b.node_kind for b in HAND_BOARDS] == list(NodeKind)
    assert [b.app for b in HAND_BOARDS] == [k.value for k in NodeKind]
    assert all(b.node_kind is None and b.hop is None for b in ARM_BOARDS)


def test_each_hop_is_one_finger_board_of_the_same_name() -> None:
    assert [b.hop for b in FINGER_BOARDS] == list(Hop)
    assert all(b.hop is not None and b.hop.name == b.board_type.name for b in FINGER_BOARDS)


def test_the_derived_tables_are_the_wire_facts() -> None:
    assert NODE_ADDRESS == {NodeKind.PALM: 10, NodeKind.FMCB: 10, NodeKind.F2: 1,
                            NodeKind.F3: 2}
    assert HOP_NODE == {Hop.FMCB: NodeKind.FMCB, Hop.F2: NodeKind.F2, Hop.F3: NodeKind.F3}
    assert HOP_ADDRESS == {Hop.FMCB: 10, Hop.F2: 1, Hop.F3: 2}
    assert [b.app for b in FINGER_BOARDS] == ["fmcb", "f2", "f3"]


def test_boards_sharing_a_bus_have_distinct_addresses() -> None:
    """A finger's boards share its tendon bus (behind its pogo link): one address each."""
    addresses = [b.address for b in FINGER_BOARDS]
    assert len(set(addresses)) == len(addresses)


def test_the_catalogue_and_the_decoder_know_every_hand_board() -> None:
    assert NODES == ("common", *(b.app for b in HAND_BOARDS), "bootloader")
    assert NODE_KINDS_TRIED == ("fmcb", "palm", "f2", "f3", "bootloader")
    assert sorted(NODE_KINDS_TRIED) == sorted([*(b.app for b in HAND_BOARDS), "bootloader"])


def test_each_self_test_is_a_request_its_board_answers() -> None:
    for b in FINGER_BOARDS:
        assert b.self_test, b.app
        for name in b.self_test:
            msg = CATALOGUE[name]
            assert msg.node in ("common", b.app) and msg.replies, name


def test_a_board_is_found_by_name_or_type() -> None:
    assert board("f2") is board(BoardType.F2)
    assert board("rx64").board_type == BoardType.RX64
    try:
        board("f4")
    except KeyError:
        pass
    else:
        raise AssertionError("board('f4') found a board")
