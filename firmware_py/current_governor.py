"""The palm's current governor: one shared effort cap from the summed finger currents.

The original motherboard lowered and raised a hand-wide effort cap from the measured finger
supply currents and sent it to every fmcb (message 0x23).  This is that law, on its own so
that it can be tested without a palm:

- every tick (the palm ticks every :data:`GOVERNOR_PERIOD_US`) the caller passes the sum of
  the finger currents (mA);
- above ``limit_ma`` the cap drops by ``step_down`` (never below ``min_cap``);
- below ``limit_ma − hysteresis_ma`` it rises by ``step_up`` towards :data:`FULL_CAP`;
- inside the band it holds, so a load sitting at the limit does not make the cap chatter.

The cap is in 1/255 of full PWM (u8).  With the default steps the cap falls from 255 to 0 in
16 ticks (160 ms) and climbs back in 64 ticks (640 ms): fast to protect the supply, slow to
give the effort back.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

#: The cap that means "no throttling" (1/255 of full PWM).
FULL_CAP: Final = 255
#: How often the palm runs the governor (µs).
GOVERNOR_PERIOD_US: Final = 10_000
#: Default limit (mA): the largest the message can carry, i.e. no limit until the host sets one.
DEFAULT_LIMIT_MA: Final = 0xFFFF
#: Default hysteresis as a fraction of the limit, and its floor (mA).
HYSTERESIS_FRACTION: Final = 0.10
MIN_HYSTERESIS_MA: Final = 50


@dataclass
class CurrentGovernor:
    """Lower the effort cap while the hand draws more than ``limit_ma``; raise it back after.

    ``step_down``/``step_up`` are cap steps per tick (1/255 of full PWM); ``hysteresis_ma``
    (mA) is the band below the limit in which the cap holds; None derives it from the limit
    (:data:`HYSTERESIS_FRACTION`, at least :data:`MIN_HYSTERESIS_MA`).
    """

    limit_ma: int = DEFAULT_LIMIT_MA
    step_down: int = 16
    step_up: int = 4
    hysteresis_ma: int | None = None
    min_cap: int = 0
    cap: int = FULL_CAP

    def __post_init__(self) -> None:
        if not 0 <= self.min_cap <= FULL_CAP:
            raise ValueError(f"min_cap {self.min_cap} is outside 0..{FULL_CAP}")
        if self.step_down <= 0 or self.step_up <= 0:
            raise ValueError("governor steps must be positive")
        self.cap = max(self.min_cap, min(FULL_CAP, int(self.cap)))

    @property
    def band_ma(self) -> int:
        """The hysteresis band below the limit (mA)."""
        if self.hysteresis_ma is not None:
            return max(0, int(self.hysteresis_ma))
        return max(MIN_HYSTERESIS_MA, int(self.limit_ma * HYSTERESIS_FRACTION))

    def set_limit(self, limit_ma: int) -> None:
        """A new limit (mA); the cap moves from where it is at the next ticks."""
        self.limit_ma = max(0, int(limit_ma))

    def update(self, total_ma: int) -> int:
        """One tick with the hand's total finger current (mA); returns the new cap."""
        if total_ma > self.limit_ma:
            self.cap = max(self.min_cap, self.cap - self.step_down)
        elif total_ma < self.limit_ma - self.band_ma:
            self.cap = min(FULL_CAP, self.cap + self.step_up)
        return self.cap
