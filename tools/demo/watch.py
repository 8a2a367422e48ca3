"""What the demo (:mod:`tools.demo`) watches while it runs, for its recordings and report.

- :class:`HandSampler`: the hand's state at :data:`HAND_STATE_HZ` (simulated or link
  time) while the arm moves or holds.  Each read is started from an arm cycle and taken
  when its replies are in, a later cycle: the arm's control loop never waits for the hand.
  The reads reach the hand's state taps, so the recording (``/hand/state``) and the report
  get them.
- :class:`MugInHand`: in process, the physics' ground truth of the mug and the palm: the
  mug's height, the palm's, and how far the mug moved in the palm's frame while it was off
  the table (a slip).
- :func:`felt`: what each finger's pads felt, against a baseline reading (the report's
  "tactile rise": the sum over its taxels of the rise above the baseline, ADC counts).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np

from host.errors import HostError
from host.hand.facade import Hand, StatusRead
from host.hand.state import FingerState
from host.hand.synergies import TACTILE_CONTACT_COUNTS

#: Rate of the hand-state reads while the arm moves or holds (Hz, the link's clock).
HAND_STATE_HZ: Final = 10.0
#: A read whose replies are not all in after this long (s) is finished anyway (the
#: missing fingers then say why).
READ_GIVE_UP_S: Final = 0.3
#: The mug is off the table when its centre is this far above its start (m).
OFF_TABLE_M: Final = 0.01
#: The mug slipped when it moved this far (m) in the palm's frame while off the table.
SLIP_M: Final = 0.02


class HandSampler:
    """Reads ``hand``'s state at ``rate_hz`` without blocking: call :meth:`poll` often
    (from the arm's state taps)."""

    def __init__(self, hand: Hand, rate_hz: float = HAND_STATE_HZ) -> None:
        self.hand = hand
        self.period = 1.0 / rate_hz
        self._due = 0.0
        self._read: StatusRead | None = None
        self._busy = False
        self.reads = 0

    def poll(self) -> None:
        """Take in a read whose replies are in; start the next when it is due."""
        if self._busy:
            return
        self._busy = True
        try:
            session = self.hand.session
            now = session.now()
            if self._read is None:
                if now >= self._due:
                    self._read = self.hand.start_status()
                    self._due = max(self._due + self.period, now)
                return
            session.pump(0.0)
            if self._read.ready or now - self._read.t >= READ_GIVE_UP_S:
                read, self._read = self._read, None
                read.finish()
                self.reads += 1
        except HostError:
            self._read = None  # the link said why; the demo's own calls will too
        finally:
            self._busy = False

    def finish(self) -> None:
        """Take in the read in flight, if any (before the link is used otherwise)."""
        if self._read is not None:
            read, self._read = self._read, None
            try:
                read.finish()
            except HostError:
                pass


@dataclass
class MugInHand:
    """Ground truth from the in-process plant: ``samples`` (t s, mug z m, palm z m, slip
    m); ``slip_m`` the most the mug moved in the palm's frame while off the table, and
    when (``slip_t``)."""

    tracker: Any  # hil_emulator.scene_model.MugTracker
    data: Any  # mujoco.MjData
    palm_id: int
    samples: list[tuple[float, float, float, float]] = field(default_factory=list)
    slip_m: float = 0.0
    slip_t: float | None = None
    _held: np.ndarray | None = None

    @classmethod
    def from_emulator(cls, emulator: Any, tracker: Any) -> MugInHand | None:
        plant = emulator.plant
        try:
            palm_id = plant.model.body("hand/palm").id
        except (KeyError, AttributeError):
            return None
        return cls(tracker, plant.data, palm_id)

    def _in_palm(self) -> np.ndarray:
        rotation = np.asarray(self.data.xmat[self.palm_id]).reshape(3, 3)
        offset = np.asarray(self.tracker.position) - np.asarray(self.data.xpos[self.palm_id])
        return rotation.T @ offset

    def sample(self, t: float) -> None:
        """Note where the mug and the palm are now (``t``: the link's clock, s)."""
        mug_z = float(self.tracker.position[2])
        palm_z = float(self.data.xpos[self.palm_id][2])
        slip = 0.0
        if mug_z - float(self.tracker.start[2]) > OFF_TABLE_M:
            where = self._in_palm()
            if self._held is None:
                self._held = where
            slip = float(np.linalg.norm(where - self._held))
            if slip > self.slip_m:
                self.slip_m, self.slip_t = slip, t
        else:
            self._held = None  # on the table: the next lift starts a new hold
        self.samples.append((t, mug_z, palm_z, slip))


def touch(state: FingerState, baseline: FingerState) -> tuple[int, int]:
    """(sum, largest) of ``state``'s taxel rises above ``baseline`` (ADC counts; a fall
    counts as none)."""
    total, largest = 0, 0
    for pad, values in state.tactile.items():
        base = baseline.tactile.get(pad, values)
        for v, b in zip(values, base, strict=False):
            rise = max(0, v - b)
            total += rise
            largest = max(largest, rise)
    return total, largest


def felt(states: Mapping[int, FingerState], baselines: Mapping[int, FingerState]
         ) -> dict[int, str]:
    """Per finger, what its pads feel now against its baseline: ``contact: … counts`` or
    ``no contact``."""
    out = {}
    for k, state in sorted(states.items()):
        if k not in baselines:
            continue
        total, largest = touch(state, baselines[k])
        out[k] = (f"contact: taxels +{total} counts in all (+{largest} the most)"
                  if largest >= TACTILE_CONTACT_COUNTS else
                  f"no contact (taxels +{largest} counts at most)")
    return out
