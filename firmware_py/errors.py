"""The one exception tree of `firmware_py`."""

from __future__ import annotations


class FirmwareError(Exception):
    """Base of every error raised by firmware_py."""


class HalError(FirmwareError, LookupError):
    """A peripheral the board does not have, or a HAL used wrongly."""


class FlashError(FirmwareError, OSError):
    """A flash operation that the hardware refuses (busy, locked, out of range)."""


class ConfigError(FirmwareError, ValueError):
    """A board configuration that cannot work."""
