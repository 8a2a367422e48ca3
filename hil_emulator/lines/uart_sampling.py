"""What a UART reads from characters sent at another baud rate: bit-level re-sampling.

A UART character on the line is a start bit (0), eight data bits least significant first and
a stop bit (1), each one bit period long; the line idles at 1.  A receiver hunting for a
character waits for a falling edge (1 → 0), checks the start bit half of *its own* bit period
later (still 0, or it was a glitch and it hunts again), samples the eight data bits one of its
periods apart from there, and the stop bit one period after the last: a 0 there is a framing
error, which the receiving USART flags, and the character is left out (as the tendon bus's
Manchester model does).  It hunts for the next falling edge from the stop bit's sample.

:func:`misread` runs that receiver over the waveform of ``data`` sent back to back at
``sent_baud`` and sampled at ``read_baud``; the result is deterministic (no noise: the
sampling instants alone decide).  Equal rates (or within about 4 %, a UART's tolerance)
give ``data`` back; beyond that the characters read differ, and their number too (a slow
receiver spans several sent characters with one, a fast one ends early and often finds its
stop bit 0), so a frame's bytes change and its checksum no longer holds.  Each call is one
burst: the line idle before and after it.
"""

from __future__ import annotations

import math

from protocol.topology import BITS_PER_CHAR

__all__ = ["misread"]


def misread(data: bytes, sent_baud: float, read_baud: float) -> bytes:
    """The characters a UART at ``read_baud`` (bit/s) reads from ``data`` sent back to back
    at ``sent_baud`` (bit/s); characters with a framing error are left out."""
    if sent_baud <= 0 or read_baud <= 0:
        raise ValueError(f"baud rates must be positive, got {sent_baud} and {read_baud}")
    if not data:
        return b""
    if sent_baud == read_baud:
        return bytes(data)
    n_bits = BITS_PER_CHAR * len(data)

    def bit(m: int) -> int:
        """The line during sent bit period ``m`` (1 before and after the burst)."""
        if m < 0 or m >= n_bits:
            return 1
        char, pos = divmod(m, BITS_PER_CHAR)
        if pos == 0:
            return 0  # start bit
        if pos > 8:
            return 1  # stop bit
        return (data[char] >> (pos - 1)) & 1

    period = sent_baud / read_baud  # the receiver's bit period, in sent bit periods
    out = bytearray()
    t = 0.0  # where the receiver hunts from (sent bit periods from the first start bit)
    while True:
        edge = max(0, math.ceil(t))  # the next 1 → 0 bit boundary at or after t
        while edge < n_bits and not (bit(edge - 1) and not bit(edge)):
            edge += 1
        if edge >= n_bits:
            return bytes(out)
        if bit(math.floor(edge + 0.5 * period)):  # the start bit is over already: a glitch
            t = edge + 0.5 * period
            continue
        value = 0
        for k in range(8):
            value |= bit(math.floor(edge + (1.5 + k) * period)) << k
        stop = edge + 9.5 * period
        if bit(math.floor(stop)):
            out.append(value)
        t = stop
