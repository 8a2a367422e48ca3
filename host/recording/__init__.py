"""MCAP recordings: the writer every recorder uses (``writer``) and the topics, declared once
(``topics``); the hand's and the arm's recorders live in their rooms (``host.hand.recording``,
``host.arm.recording``).

``from host.recording import …`` of a name of the writer keeps working: names not found here
come from :mod:`host.recording.writer`, loaded on first use.
"""

from __future__ import annotations

import importlib
from typing import Any


def __getattr__(name: str) -> Any:
    """A name of :mod:`host.recording.writer`, imported on first use."""
    if name.startswith("__"):
        raise AttributeError(name)
    return getattr(importlib.import_module("host.recording.writer"), name)
