"""Manchester encode/decode throughput, in MB (10**6 bytes) of *payload* per second.

All cases use UART framing (20 chips per payload byte) and the IEEE 802.3 convention.  The
vectorised paths run on a random payload of 1 MiB (256 KiB with ``quick``); the baseline is a
straightforward pure-Python per-bit encoder/decoder on chip lists, run on 4 KiB (1 KiB), so
every fast result is printed as a ratio to it.  "unpacked" is one chip per ``uint8`` (20 bytes
of chips per payload byte); "packed" is 8 chips per byte (2.5 bytes per payload byte).

Run: ``python -m benchmarks.bench_manchester`` (or ``python -m benchmarks`` for all).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from benchmarks.harness import Result, best_rate
from protocol.errors import ManchesterError
from protocol.manchester import (
    decode,
    decode_packed,
    decode_report_packed,
    encode,
    encode_packed,
    pack_chips,
)

GROUP = "manchester"
UNIT = "MB"
TARGET_MB_S = 100.0
MB = 1e6

NAIVE_ENCODE = "encode naive (pure Python, per bit)"
NAIVE_DECODE = "decode naive (pure Python, per bit)"


def naive_encode(data: bytes) -> list[int]:
    """IEEE 802.3 chips of ``data`` with UART framing, one bit at a time."""
    chips: list[int] = []
    for byte in data:
        bits = [0] + [(byte >> i) & 1 for i in range(8)] + [1]
        for bit in bits:
            chips.append(1 - bit)
            chips.append(bit)
    return chips


def naive_decode(chips: list[int]) -> bytes:
    """Inverse of :func:`naive_encode`, validating every pair and the framing."""
    if len(chips) % 20:
        raise ManchesterError("length")
    out = bytearray()
    for start in range(0, len(chips), 20):
        bits = []
        for j in range(start, start + 20, 2):
            first, second = chips[j], chips[j + 1]
            if first == second:
                raise ManchesterError("invalid pair", (j // 2,))
            bits.append(second)
        if bits[0] != 0 or bits[9] != 1:
            raise ManchesterError("framing", (start // 2,))
        value = 0
        for i, bit in enumerate(bits[1:9]):
            value |= bit << i
        out.append(value)
    return bytes(out)


def run(quick: bool = False) -> list[Result]:
    """Measure encode/decode rates; returns one :class:`Result` per case (MB/s of payload)."""
    rng = np.random.default_rng(2024)
    n_fast = (256 if quick else 1024) * 1024
    n_naive = (1 if quick else 4) * 1024
    repeat, min_time = (2, 0.05) if quick else (5, 0.2)

    data = rng.integers(0, 256, n_fast, dtype=np.uint8).tobytes()
    small = data[:n_naive]
    chips = encode(data)
    packed = encode_packed(data)
    small_chips = naive_encode(small)

    # The fast paths and the baseline must agree before anything is timed.
    if chips[: len(small_chips)].tolist() != small_chips or naive_decode(small_chips) != small:
        raise RuntimeError("naive Manchester baseline disagrees with protocol.manchester")
    if decode(chips) != data or decode_packed(packed) != data:
        raise RuntimeError("Manchester round trip failed")

    # A bus with ~1% of characters hit by a flipped chip, for the lenient decoder.
    corrupted = chips.copy()
    hits = rng.choice(n_fast, size=n_fast // 100, replace=False)
    corrupted[hits * 20 + rng.integers(0, 20, hits.size)] ^= 1
    corrupted_packed = pack_chips(corrupted)
    if len(decode_report_packed(corrupted_packed).bad_characters) != hits.size:
        raise RuntimeError("decode_report_packed missed corrupted characters")

    def rate(func: Callable[[], object], n: int) -> float:
        def work() -> int:
            func()
            return n

        return best_rate(work, repeat=repeat, min_time=min_time) / MB

    fast_note = f"{n_fast // 1024} KiB payload, UART framing"
    naive_note = f"{n_naive // 1024} KiB payload, chips as a list"

    def naive(name: str, func: Callable[[], object]) -> Result:
        return Result(GROUP, name, rate(func, n_naive), UNIT, note=naive_note)

    def fast(name: str, func: Callable[[], object], baseline: str) -> Result:
        return Result(
            GROUP, name, rate(func, n_fast), UNIT, baseline, target=TARGET_MB_S, note=fast_note
        )

    return [
        naive(NAIVE_ENCODE, lambda: naive_encode(small)),
        fast("encode unpacked (1 chip/byte)", lambda: encode(data), NAIVE_ENCODE),
        fast("encode packed (8 chips/byte)", lambda: encode_packed(data), NAIVE_ENCODE),
        naive(NAIVE_DECODE, lambda: naive_decode(small_chips)),
        fast("decode unpacked (1 chip/byte)", lambda: decode(chips), NAIVE_DECODE),
        fast("decode packed (8 chips/byte)", lambda: decode_packed(packed), NAIVE_DECODE),
        Result(
            GROUP,
            "decode_report packed, 1% bad characters",
            rate(lambda: decode_report_packed(corrupted_packed), n_fast),
            UNIT,
            NAIVE_DECODE,
            note=fast_note + ", every bad character reported",
        ),
    ]


def _format(result: Result, by_name: dict[str, Result]) -> str:
    text = f"{result.group:<11} {result.name:<42} {result.rate:10.2f} {result.unit}/s"
    if result.baseline in by_name:
        text += f"  x{result.rate / by_name[result.baseline].rate:,.0f} vs baseline"
    if result.target is not None:
        verdict = "meets" if result.rate >= result.target else "MISSES"
        text += f"  ({verdict} target {result.target:g} {result.unit}/s)"
    if result.note:
        text += f"  [{result.note}]"
    return text


if __name__ == "__main__":
    import sys

    measured = run(quick="--quick" in sys.argv[1:])
    names = {r.name: r for r in measured}
    for r in measured:
        print(_format(r, names))
