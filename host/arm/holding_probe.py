"""A holding-torque probe: lower a loaded stepper's holding current until its rotor slips,
and stop there.

A stepper's holding torque (``k_T · I · G`` at the joint: torque constant, current,
reduction) shows only where the load on it reaches it: below, the rotor stays at its
electrical equilibrium whatever the load.  The probe makes that moment observable, safely:
with the arm at rest in a pose that loads ``joint`` under gravity, it

1. waits for the arm to be at rest (:class:`host.arm.rest.RestWatch`, at most
   :data:`SETTLE_S`), then reads the load the joint carries (the elastic element's torque, N·m, from its
   deflection: :attr:`host.arm.state.StepperState.torque`) and what the node reports;
2. sets the node's ``slip_threshold`` to the deflection it has now plus
   :data:`SLIP_MARGIN_COUNTS`, so that the node's own watch latches SLIP at the first lost
   electrical period (4 full steps: 15–20 encoder counts at the joint);
3. ramps ``holding_current`` down, a write per cycle every :data:`PERIOD_S`, from the
   current whose nominal holding torque (:data:`protocol.robot.STEPPER_TORQUE_CONSTANT_NM_PER_A`)
   is :data:`RAMP_FROM` times the load to the one where it is :data:`RAMP_TO` times it
   (within the node's ``max_current``), over ``seconds``;
4. at the first cycle that reads SLIP, or at the ramp's end, writes the holding current and
   the threshold back and clears the latch.

A slip costs the joint one or two electrical periods of sag (a fraction of a degree) before
the current is back; nothing is commanded to move, and the rotor re-locks at full current.
What the recording then holds, the current at which the rotor let go under a known load, is
what ``hil-bench fit`` matches (the ``torque_constant`` parameters).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

from host.arm.interface import DrivenArm
from host.arm.rest import RestWatch
from host.arm.state import JOINT_NAMES, N_STEPPERS
from host.errors import UsageError
from protocol.control_tables import STEPPER_TABLE, StepperClear
from protocol.robot import STEPPER_TORQUE_CONSTANT_NM_PER_A

_S = STEPPER_TABLE
#: The ramp's start and end: nominal holding torque over the load the joint carries.
RAMP_FROM: Final = 2.0
RAMP_TO: Final = 0.5
#: Cycle period of the ramp (s): a holding-current write and a read of the arm.
PERIOD_S: Final = 0.01
#: Counts of deflection beyond the present one at which the node latches SLIP (an
#: electrical period is 20 counts of J2, 15 of J4).
SLIP_MARGIN_COUNTS: Final = 10
#: Longest wait (s) for the arm to come to rest before a probe (the elbow rings at ~5 Hz).
SETTLE_S: Final = 3.0
#: Least load (N·m) the probe needs: below it there is nothing to hold against.
MIN_LOAD_NM: Final = 0.5


@dataclass(frozen=True)
class ProbeResult:
    """One probe: the ``joint`` (0..3), the ``load_nm`` it carried (N·m, from its
    deflection and nominal stiffness), the ramp's ``from_ma`` and ``to_ma`` (mA), and the
    current at which its rotor slipped (``slipped_ma``; None: it held to the end)."""

    joint: int
    load_nm: float
    from_ma: int
    to_ma: int
    slipped_ma: int | None

    @property
    def holding_nm_per_ma(self) -> float | None:
        """The holding torque per mA the slip shows (N·m/mA at the joint: the load over the
        current it slipped at), or None."""
        return None if self.slipped_ma is None else self.load_nm / self.slipped_ma

    def as_dict(self) -> dict[str, object]:
        """The probe as JSON-ready data."""
        return {"joint": JOINT_NAMES[self.joint], "load_nm": self.load_nm,
                "from_ma": self.from_ma, "to_ma": self.to_ma, "slipped_ma": self.slipped_ma}


def ramp_currents(load_nm: float, joint: int, reduction: float, max_ma: int
                  ) -> tuple[int, int]:
    """The ramp's first and last holding current (mA) for ``joint`` carrying ``load_nm``
    (N·m) through ``reduction``: :data:`RAMP_FROM` and :data:`RAMP_TO` times the load in
    nominal holding torque, the first at most ``max_ma``."""
    per_ma = STEPPER_TORQUE_CONSTANT_NM_PER_A[joint] * reduction / 1000.0
    start = min(max_ma, math.ceil(RAMP_FROM * load_nm / per_ma))
    end = max(1, math.floor(RAMP_TO * load_nm / per_ma))
    if end >= start:
        raise UsageError(f"{JOINT_NAMES[joint]}: its load {load_nm:.2f} N·m needs more than "
                         f"the node's max_current {max_ma} mA to probe")
    return start, end


def probe_holding(arm: DrivenArm, joint: int, seconds: float) -> ProbeResult:
    """Probe stepper ``joint``'s (0..3) holding torque (module doc) over ``seconds`` (s) of
    ramp, the arm at rest; :class:`~host.errors.UsageError` for a joint that is no stepper
    or carries less than :data:`MIN_LOAD_NM`."""
    if not 0 <= joint < N_STEPPERS:
        raise UsageError(f"{JOINT_NAMES[joint] if 0 <= joint < len(JOINT_NAMES) else joint}"
                         " has no stepper: only J1..J4 have a holding torque to probe")
    if not (math.isfinite(seconds) and seconds > 0):
        raise UsageError(f"probe time {seconds} must be a finite number > 0 s")
    info = arm.steppers[joint]
    bus, clock = arm.bus, arm.transport
    state = arm.cycle()
    rest, end_t = RestWatch(), clock.now() + SETTLE_S
    while not rest.update(state) and clock.now() < end_t:
        clock.sleep(PERIOD_S)
        state = arm.cycle()
    stepper = state.steppers[joint]
    load = abs(stepper.torque)
    if load < MIN_LOAD_NM:
        raise UsageError(f"{JOINT_NAMES[joint]} carries {load:.2f} N·m here: too little load "
                         "to probe its holding torque against (raise the links it holds)")
    hold_reg, slip_reg, cap_reg = _S["holding_current"], _S["slip_threshold"], _S["max_current"]
    hold_ma = hold_reg.decode(bus.read(info.dxl_id, hold_reg.address, hold_reg.size))
    threshold = slip_reg.decode(bus.read(info.dxl_id, slip_reg.address, slip_reg.size))
    cap = cap_reg.decode(bus.read(info.dxl_id, cap_reg.address, cap_reg.size))
    start, end = ramp_currents(load, joint, info.reduction, min(cap, hold_ma))
    offset_reg = _S["deflection_offset"]
    offset = offset_reg.decode(bus.read(info.dxl_id, offset_reg.address, offset_reg.size))
    watch = abs(stepper.deflection - offset) + SLIP_MARGIN_COUNTS
    bus.write(info.dxl_id, slip_reg.address, slip_reg.encode(watch))
    n = max(1, round(seconds / PERIOD_S))
    slipped: int | None = None
    try:
        for k in range(n + 1):
            current = round(start + (end - start) * k / n)
            bus.write(info.dxl_id, hold_reg.address, hold_reg.encode(current))
            clock.sleep(PERIOD_S)
            if arm.cycle().steppers[joint].slip:
                slipped = current
                break
    finally:
        bus.write(info.dxl_id, hold_reg.address, hold_reg.encode(hold_ma))
        bus.write(info.dxl_id, slip_reg.address, slip_reg.encode(threshold))
        clear = _S["clear_flags"]
        bus.write(info.dxl_id, clear.address, clear.encode(int(StepperClear.SLIP)))
    return ProbeResult(joint, load, start, end, slipped)
