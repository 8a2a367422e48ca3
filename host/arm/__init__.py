"""The arm: the :class:`Arm` facade (``facade``) over its helpers: the Dynamixel bus
(``bus``), the control cycle, the gate every motion passes, hold, rest, homing, moves,
trajectories, kinematics, gravity and recording.

``from host.arm import Arm`` (and any other name of the facade's module) keeps working:
names not found here come from :mod:`host.arm.facade`, loaded on first use.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from host.arm.facade import Arm as Arm


def __getattr__(name: str) -> Any:
    """A name of :mod:`host.arm.facade`, imported on first use."""
    if name.startswith("__"):
        raise AttributeError(name)
    return getattr(importlib.import_module("host.arm.facade"), name)
