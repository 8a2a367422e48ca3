"""Pairing requests with replies for a replay: by request, never by position, and never a
crash whatever bytes a recording holds."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from protocol.control_tables import STEPPER_TABLE
from protocol.dynamixel import StatusPacket, make_bulk_read, make_ping, make_read
from protocol.messages import CATALOGUE
from protocol.topology import ADDR_HOST, ADDR_PALM
from tools.hil_bench.replay.compare import compare
from tools.hil_bench.replay.exchanges import arm_exchanges, hand_exchanges
from tools.hil_bench.replay.source import Timed

#: Byte strings at non-decreasing times, as a recording's channel holds them.
_CHUNKS = st.lists(st.tuples(st.floats(0, 1e-3, allow_nan=False), st.binary(max_size=40)),
                   max_size=30)


def _timed(chunks: list[tuple[float, bytes]]) -> list[Timed]:
    t, out = 0.0, []
    for dt, data in chunks:
        t += dt
        out.append(Timed(t, data))
    return out


def _position_reply(dxl_id: int, counts: int) -> bytes:
    return StatusPacket(dxl_id, 0, STEPPER_TABLE["present_position"].encode(counts)).encode()


@given(_CHUNKS, _CHUNKS)
def test_the_arm_pairing_never_fails_and_answers_only_what_was_asked_before(
        tx: list[tuple[float, bytes]], rx: list[tuple[float, bytes]]) -> None:
    exchanges = arm_exchanges(_timed(tx), _timed(rx))
    for ex in exchanges:
        assert ex.values()["replied"] in (0.0, 1.0)
        if ex.reply_t is not None:
            assert ex.reply_t >= ex.t


@given(_CHUNKS, _CHUNKS)
def test_the_hand_pairing_never_fails_on_any_bytes(
        tx: list[tuple[float, bytes]], rx: list[tuple[float, bytes]]) -> None:
    for ex in hand_exchanges(_timed(tx), _timed(rx)):
        assert ex.prefix.startswith("hand.")


@given(st.lists(st.sampled_from([1, 2, 3, 4]), min_size=1, max_size=4, unique=True),
       st.permutations([0, 1, 2, 3]))
def test_arm_replies_in_any_order_find_their_own_requests(
        ids: list[int], order: list[int]) -> None:
    """A BULK_READ's replies come back in another order: each value lands on its node."""
    request = make_bulk_read([(4, i, STEPPER_TABLE["present_position"].address)
                              for i in ids]).encode()
    replies = [_position_reply(i, 100 * i) for i in ids]
    shuffled = [replies[k] for k in order if k < len(replies)]
    exchanges = arm_exchanges([Timed(0.0, request)],
                              [Timed(1e-3 * (k + 1), r) for k, r in enumerate(shuffled)])
    assert len(exchanges) == len(ids)
    for ex, dxl_id in zip(exchanges, ids, strict=True):
        assert ex.fields is not None and ex.fields["present_position"] == 100 * dxl_id


def test_a_lost_reply_costs_only_its_own_request() -> None:
    """A reply the replay did not get parts one ``replied`` sample; every later request
    still compares with its own reply, not its neighbour's."""
    reads = [Timed(0.01 * k, (make_ping(1) if k == 2 else make_read(1, 32, 4)).encode())
             for k in range(6)]
    answers = [Timed(0.01 * k + 0.001, _position_reply(1, 10 * k)) for k in range(6)]
    recorded = arm_exchanges(reads, answers)
    replayed = arm_exchanges(reads, [a for k, a in enumerate(answers) if k != 3])
    channels = compare(recorded, replayed)
    assert channels["arm.J1.replied"].errors == [0.0, 0.0, 0.0, -1.0, 0.0, 0.0]
    assert channels["arm.J1.present_position"].errors == [0.0, 0.0, 0.0, 0.0]
    assert channels["arm.J1.present_position"].within


def test_hand_replies_are_matched_by_their_sequence_number() -> None:
    """Two ``txn`` requests answered in the other order: each reply goes to its own."""
    txn = CATALOGUE.by_name("txn")
    ping = CATALOGUE.by_name("ping")
    version = CATALOGUE.by_name("hw_version")

    def request(seq: int, msg: object) -> bytes:
        inner = msg.type_id  # type: ignore[attr-defined]
        return txn.request_frame(ADDR_PALM, {"seq": seq, "inner_type": inner, "inner": b""})

    def reply(seq: int, inner_type: int, body: bytes) -> bytes:
        from protocol.framing import encode_frame

        payload = txn.build_reply({"seq": seq, "board": 1, "address": ADDR_PALM,
                                   "inner_type": inner_type, "status": 0, "inner": body})
        return encode_frame(ADDR_HOST, txn.type_id, payload)

    tx = [Timed(0.0, request(7, version)), Timed(0.0, request(8, ping))]
    body = version.build_reply({"version": 0xBEEF4C41})
    rx = [Timed(0.001, reply(8, ping.type_id, b"")),
          Timed(0.002, reply(7, version.type_id, body))]
    first, second = hand_exchanges(tx, rx)
    assert first.fields is not None and first.fields["version"] == 0xBEEF4C41
    assert first.reply_t == 0.002 and second.reply_t == 0.001
