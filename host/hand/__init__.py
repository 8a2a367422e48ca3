"""The hand: the :class:`Hand` facade (``facade``) over its helpers, the session that talks
to the palm (``session``), the hand's state, homing, grasps and recording.

``from host.hand import Hand`` (and any other name of the facade's module) keeps working:
names not found here come from :mod:`host.hand.facade`, loaded on first use.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from host.hand.facade import Hand as Hand


def __getattr__(name: str) -> Any:
    """A name of :mod:`host.hand.facade`, imported on first use."""
    if name.startswith("__"):
        raise AttributeError(name)
    return getattr(importlib.import_module("host.hand.facade"), name)
