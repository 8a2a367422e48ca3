"""The live browser view: :class:`RobotView` (``live``), what it draws (``render``,
``columns``, ``geometry``) and its page served by rerun in a child process (``server``,
``child``).

``from host.view import RobotView`` (and any other name of the view's module) keeps working:
names not found here come from :mod:`host.view.live`, loaded on first use.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from host.view.live import RobotView as RobotView
    from host.view.live import ViewSpec as ViewSpec
    from host.view.live import open_view as open_view


def __getattr__(name: str) -> Any:
    """A name of :mod:`host.view.live`, imported on first use."""
    if name.startswith("__"):
        raise AttributeError(name)
    return getattr(importlib.import_module("host.view.live"), name)
