"""Joint limits widened in the fmcb's RAM go back by themselves when the host goes quiet
(:mod:`firmware_py.limit_lease`), on the virtual fmcb board, without physics."""

from __future__ import annotations

import struct

from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_py.limit_lease import LIMIT_NAMES, LimitLease
from protocol.robot import FINGER_JOINT_LIMITS, FINGER_LIMIT_LEASE_MS, joint_to_motor
from tests.firmware_py.test_fmcb import Rig

#: The limits as the hand calibration widens them (rad).
WIDE = 2.25  # exact in f32
#: The default limits as the fmcb holds them (f32), in LIMIT_NAMES order.
DEFAULTS = tuple(struct.unpack("<f", struct.pack("<f", v))[0]
                 for pair in FINGER_JOINT_LIMITS for v in pair)
WIDENED = tuple(-WIDE if "lower" in n else WIDE for n in LIMIT_NAMES)


def widen(rig: Rig, wide: float = WIDE) -> None:
    """The host's writes: every joint limit to ±``wide``, as the calibration does."""
    for name in LIMIT_NAMES:
        value = -wide if "lower" in name else wide
        rig.ask("fmcb.param_set", {"index": rig.app.params.index(name),
                                   "value": struct.pack("<f", value)})


def limits(rig: Rig) -> tuple[float, ...]:
    """The joint limits the fmcb holds, read over the wire (LIMIT_NAMES order)."""
    out = []
    for name in LIMIT_NAMES:
        bits = rig.ask("fmcb.param_get", {"index": rig.app.params.index(name)})["value"]
        out.append(struct.unpack("<f", bits)[0])
    return tuple(out)


def palm_only(rig: Rig, ms: int) -> None:
    """``ms`` of what the palm sends by itself: a status poll and an effort cap every 10 ms."""
    for _ in range(ms // 10):
        rig.send("fmcb.status", run_ms=0)
        rig.send("fmcb.effort_cap", {"cap": 255}, run_ms=10)


def test_widened_limits_go_back_after_the_lease_with_only_the_palm_talking() -> None:
    rig = Rig()
    widen(rig)
    # The push past the standing limit, as the calibration's relative command.
    rig.send("fmcb.control", {"mode": 5, "args": {"target": [2.0, 0, 0],
                                                  "max_effort": [200, 200, 200]}}, run_ms=2)
    assert rig.app.hall_target[0] == round(joint_to_motor((2.0, 0, 0))[0])
    palm_only(rig, FINGER_LIMIT_LEASE_MS - 200)  # (read in RAM: a param_get would renew)
    assert rig.app.limit_lease.active and rig.app.params["joint_upper_0"] == WIDE
    # The host gone: nothing but the palm for the rest of the lease and a check period.
    palm_only(rig, 300)
    assert not rig.app.limit_lease.active and rig.app.limit_lease.expired == 1
    assert limits(rig) == DEFAULTS
    # The joint target is back inside the standing limit: J0 at its 1.57 rad.
    inside = joint_to_motor((FINGER_JOINT_LIMITS[0][1], 0, 0))[0]
    assert abs(rig.app.hall_target[0] - inside) <= 1


def test_widened_limits_hold_while_the_host_keeps_sending() -> None:
    rig = Rig()
    widen(rig)
    for _ in range(3 * FINGER_LIMIT_LEASE_MS // 1000):  # a request a second, three leases
        rig.send("fmcb.hall_counts", {"raw": 0}, run_ms=1000)
    assert rig.app.limit_lease.active and rig.app.limit_lease.expired == 0
    assert rig.app.params["joint_upper_0"] == WIDE


def test_limits_put_back_by_the_host_end_the_lease_and_stand() -> None:
    rig = Rig()
    widen(rig)
    for name, value in zip(LIMIT_NAMES, DEFAULTS, strict=True):
        rig.ask("fmcb.param_set", {"index": rig.app.params.index(name),
                                   "value": struct.pack("<f", value)})
    assert not rig.app.limit_lease.active
    # Narrower limits than the defaults are no widening: they stand through any silence.
    rig.ask("fmcb.param_set", {"index": rig.app.params.index("joint_upper_1"),
                               "value": struct.pack("<f", 1.0)})
    rig.run_ms(2 * FINGER_LIMIT_LEASE_MS)
    assert not rig.app.limit_lease.active and rig.app.limit_lease.expired == 0
    assert rig.app.params["joint_upper_1"] == 1.0


def test_committed_widened_limits_stand() -> None:
    rig = Rig()
    widen(rig)
    rig.ask("fmcb.param_commit", run_ms=3)
    rig.run_ms(2 * FINGER_LIMIT_LEASE_MS)
    assert limits(rig) == WIDENED and rig.app.limit_lease.expired == 0


_LIMIT = st.floats(-3.0, 3.0, allow_nan=False, width=32)


@settings(deadline=None, max_examples=200)
@given(before=st.lists(_LIMIT, min_size=6, max_size=6),
       after=st.lists(_LIMIT, min_size=6, max_size=6),
       silence_us=st.integers(0, 3 * FINGER_LIMIT_LEASE_MS * 1000))
def test_a_lease_gives_back_exactly_the_limits_it_widened(before: list[float],
                                                          after: list[float],
                                                          silence_us: int) -> None:
    lease = LimitLease()
    lease.written(before, after, 1_000)
    wider = any(a < b if n.startswith("joint_lower") else a > b
                for n, a, b in zip(LIMIT_NAMES, after, before, strict=True))
    assert lease.active == wider
    back = lease.check(1_000 + silence_us)
    if wider and silence_us >= lease.lease_us:
        assert back == tuple(before) and not lease.active
    else:
        assert back is None and lease.active == wider


def test_the_hand_calibrations_push_onto_a_stop_fits_in_the_lease() -> None:
    """The calibration sends nothing to a finger while it pushes it onto a stop
    (``STOP_PUSH_S``): the lease must outlast that push, with a second to spare for a link
    on a busy machine, or a live calibration would lose its widened limits mid-push."""
    from host.hand.calibration import STOP_PUSH_S

    assert STOP_PUSH_S + 1.0 <= FINGER_LIMIT_LEASE_MS / 1000
