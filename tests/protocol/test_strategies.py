"""The shared strategies: mutations break frames as named, splits join, packets decode."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from protocol import dynamixel as dx
from protocol.control_tables import STEPPER_TABLE
from protocol.framing import BAD_CRC, FRAME, check_frame, encode_frame
from protocol.messages import CATALOGUE
from protocol.strategies import (
    MUTATIONS,
    dynamixel_instructions,
    mutate_frame,
    request_frames,
    write_splits,
)

PING = encode_frame(1, 0x01)


def test_bad_crc_and_foreign_address_by_hand() -> None:
    assert check_frame(PING)[0] == FRAME
    assert mutate_frame(PING, "bad_crc", 0) == PING[:-1] + bytes([PING[-1] ^ 1])
    assert check_frame(mutate_frame(PING, "bad_crc", 9))[0] == BAD_CRC
    foreign = mutate_frame(PING, "foreign_address", 0)
    assert foreign == encode_frame(0, 0x01)  # the first address that is not 1 or 0xFF
    assert mutate_frame(PING, "foreign_address", 1, avoid=(2,)) == encode_frame(3, 0x01)


@settings(max_examples=200, deadline=None)
@given(request_frames(list(CATALOGUE), 10), st.sampled_from(MUTATIONS), st.integers(0, 2**16))
def test_mutations_are_deterministic_and_never_the_frame(frame: bytes, how: str,
                                                         value: int) -> None:
    broken = mutate_frame(frame, how, value)
    assert broken == mutate_frame(frame, how, value)
    assert broken != frame
    if how == "foreign_address":
        assert broken[1] not in (10, 0xFF) and check_frame(broken)[0] == FRAME


@settings(max_examples=100, deadline=None)
@given(st.data(), st.binary(min_size=1, max_size=40))
def test_write_splits_join(data: st.DataObject, payload: bytes) -> None:
    split = data.draw(write_splits(payload, 500))
    assert b"".join(chunk for chunk, _ in split) == payload
    assert split[0][1] == 0 and all(0 <= gap <= 500 for _, gap in split)


@settings(max_examples=100, deadline=None)
@given(dynamixel_instructions(STEPPER_TABLE, (1, 2), exclude=("id", "baud_rate")))
def test_dynamixel_instructions_decode_and_spare_guarded_registers(packet: bytes) -> None:
    p = dx.InstructionPacket.decode(packet)
    if p.instruction in (dx.Instruction.WRITE, dx.Instruction.REG_WRITE) and len(p.params) > 1:
        address, data = dx.parse_write(p.params)
        guarded = {STEPPER_TABLE["id"].address, STEPPER_TABLE["baud_rate"].address}
        assert not guarded & set(range(address, address + len(data)))
