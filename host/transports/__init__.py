"""Transport backends; each is imported only when a URL needs it (see :mod:`host.transports.base`)."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from host.transports.base import Transport as Transport
    from host.transports.base import open_transport as open_transport


def __getattr__(name: str) -> Any:
    """:class:`Transport`, :func:`open_transport` … of :mod:`host.transports.base`, imported
    on first use (a backend module is imported only when a URL needs it)."""
    if name.startswith("__"):
        raise AttributeError(name)
    return getattr(importlib.import_module("host.transports.base"), name)
