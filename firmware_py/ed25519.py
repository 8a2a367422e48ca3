"""ED25519 signature verification (RFC 8032), as a bootloader without a crypto library has it.

Verification only, in plain integers: the curve -x² + y² = 1 + d·x²·y² over GF(2²⁵⁵ − 19)
in extended coordinates (X, Y, Z, T with x = X/Z, y = Y/Z, x·y = T/Z).  A signature
(R, S) of message M by public key A is valid if S < L and [S]B = R + [k]A with
k = SHA-512(R ‖ A ‖ M) mod L (the cofactorless check).  Not constant-time: it handles no
secret.  A verification costs a few ms of host CPU; :func:`verify` caches its answers.
"""

from __future__ import annotations

import functools
import hashlib
from typing import Final

_P: Final = 2**255 - 19
#: Order of the base point's group.
_L: Final = 2**252 + 27742317777372353535851937790883648493
_D: Final = (-121665 * pow(121666, _P - 2, _P)) % _P
_SQRT_M1: Final = pow(2, (_P - 1) // 4, _P)

_Point = tuple[int, int, int, int]


def _add(a: _Point, b: _Point) -> _Point:
    """Sum of two points (extended coordinates, the a = −1 addition law)."""
    x1, y1, z1, t1 = a
    x2, y2, z2, t2 = b
    pa = (y1 - x1) * (y2 - x2) % _P
    pb = (y1 + x1) * (y2 + x2) % _P
    pc = 2 * t1 * t2 * _D % _P
    pd = 2 * z1 * z2 % _P
    e, f, g, h = pb - pa, pd - pc, pd + pc, pb + pa
    return (e * f % _P, g * h % _P, f * g % _P, e * h % _P)


def _mul(k: int, point: _Point) -> _Point:
    """[k]point by double-and-add."""
    out: _Point = (0, 1, 1, 0)
    while k:
        if k & 1:
            out = _add(out, point)
        point = _add(point, point)
        k >>= 1
    return out


def _encode(point: _Point) -> bytes:
    x, y, z, _t = point
    zi = pow(z, _P - 2, _P)
    x, y = x * zi % _P, y * zi % _P
    return (y | ((x & 1) << 255)).to_bytes(32, "little")


def _decode(raw: bytes) -> _Point | None:
    """The point encoded in 32 bytes, or None if they encode none."""
    n = int.from_bytes(raw, "little")
    sign, y = n >> 255, n & ((1 << 255) - 1)
    if y >= _P:
        return None
    u, v = (y * y - 1) % _P, (_D * y * y + 1) % _P
    x = u * pow(v, 3, _P) * pow(u * pow(v, 7, _P), (_P - 5) // 8, _P) % _P
    if (v * x * x - u) % _P:
        x = x * _SQRT_M1 % _P
        if (v * x * x - u) % _P:
            return None
    if x == 0 and sign:
        return None
    if x & 1 != sign:
        x = _P - x
    return (x, y, 1, x * y % _P)


_BY: Final = 4 * pow(5, _P - 2, _P) % _P
_BASE = _decode(_BY.to_bytes(32, "little"))
assert _BASE is not None


@functools.lru_cache(maxsize=64)
def verify(public_key: bytes, signature: bytes, message: bytes) -> bool:
    """True if ``signature`` (64 bytes) is ``public_key``'s (32 bytes) ED25519 signature of
    ``message``; False for a wrong signature, a malformed key or signature."""
    if len(public_key) != 32 or len(signature) != 64:
        return False
    a = _decode(public_key)
    r = _decode(signature[:32])
    s = int.from_bytes(signature[32:], "little")
    if a is None or r is None or s >= _L:
        return False
    k = int.from_bytes(hashlib.sha512(signature[:32] + public_key + message).digest(),
                       "little") % _L
    assert _BASE is not None
    return _encode(_mul(s, _BASE)) == _encode(_add(r, _mul(k, a)))
