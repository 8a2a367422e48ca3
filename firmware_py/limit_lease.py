"""Joint limits a host widened hold only while the host is there.

A host widens the fmcb's joint limits in RAM (``fmcb.param_set`` of ``joint_lower_j`` /
``joint_upper_j``) to push a finger onto its mechanical stops, and puts them back when it is
done.  A host killed in between would leave them widened until power-off: every later
command could drive the joints past their limits onto the stops.  So widening starts a
*lease*: :class:`LimitLease` remembers the limits in force before (the *standing* limits),
and the widened ones hold only while requests from the host keep arriving within
:data:`~protocol.robot.FINGER_LIMIT_LEASE_MS`.  Then the standing limits come back by
themselves.

* Widening: a write that takes a lower limit below, or an upper limit above, the standing
  one.  Writes narrowing them, or any within the standing limits, change them as before.
* The lease ends (the limits written stand) when every limit is back within the standing
  ones, or on ``fmcb.param_commit`` (the host asks to keep them), ``param_reload`` and
  ``param_defaults`` (the values come from flash or the defaults).
* What renews it: any request the fmcb handles but those the palm sends by itself
  (``fmcb.status`` polls, ``fmcb.effort_cap``): those keep coming after the host is gone.

Pure logic on integer microseconds; the fmcb calls :meth:`LimitLease.check` from a timer.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from typing import Final

from protocol.robot import FINGER_LIMIT_LEASE_MS

__all__ = ["LIMIT_NAMES", "LimitLease"]

_F32: Final = struct.Struct("<f")

#: The joint-limit parameters, in the order :class:`LimitLease` keeps them.
LIMIT_NAMES: Final = tuple(f"joint_{end}_{j}" for j in range(3) for end in ("lower", "upper"))


def _f32(value: float) -> float:
    """``value`` as the 4-byte float the parameter holds on the wire and in flash."""
    return float(_F32.unpack(_F32.pack(value))[0])


def _within(values: Sequence[float], standing: Sequence[float]) -> bool:
    """True when every limit in ``values`` is no wider than its standing one, compared as
    the f32 values the wire carries (a default held as a double and the same value read
    and written back by the host are the same limit)."""
    return all(_f32(v) >= _f32(s) if name.startswith("joint_lower") else _f32(v) <= _f32(s)
               for name, v, s in zip(LIMIT_NAMES, values, standing, strict=True))


class LimitLease:
    """Whether widened joint limits are on lease, and what to put back when it runs out.

    ``lease_us``: the longest silence of the host (µs) the widened limits survive.
    """

    def __init__(self, lease_us: int = FINGER_LIMIT_LEASE_MS * 1000) -> None:
        if lease_us <= 0:
            raise ValueError("the lease must be positive")
        self.lease_us = int(lease_us)
        #: The limits before the widening (in :data:`LIMIT_NAMES` order), None: no lease.
        self.standing: tuple[float, ...] | None = None
        self._heard_us = 0
        #: Leases that ran out (the standing limits put back by the fmcb itself).
        self.expired = 0

    @property
    def active(self) -> bool:
        """True while widened limits are on lease."""
        return self.standing is not None

    def written(self, before: Sequence[float], after: Sequence[float], now_us: int) -> None:
        """The host wrote the limits from ``before`` to ``after`` (:data:`LIMIT_NAMES`
        order) at ``now_us``: start, renew or end the lease."""
        if self.standing is None:
            if not _within(after, before):
                self.standing = tuple(float(v) for v in before)
                self._heard_us = now_us
            return
        if _within(after, self.standing):
            self.standing = None  # back within the standing limits: they stand again
        else:
            self._heard_us = now_us

    def heard(self, now_us: int) -> None:
        """A request from the host at ``now_us`` renews the lease."""
        if self.standing is not None:
            self._heard_us = now_us

    def end(self) -> None:
        """The limits now in RAM stand (commit, reload, defaults)."""
        self.standing = None

    def check(self, now_us: int) -> tuple[float, ...] | None:
        """The standing limits to put back when the lease ran out at ``now_us`` (and the
        lease ends), else None."""
        if self.standing is None or now_us - self._heard_us < self.lease_us:
            return None
        standing, self.standing = self.standing, None
        self.expired += 1
        return standing
