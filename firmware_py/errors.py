"""The one exception tree of `firmware_py`::

    FirmwareError
    ├── HalError(LookupError)         a peripheral the board does not have, a HAL misused
    ├── FlashMemoryError(OSError)     the flash refuses an operation (busy, locked, range)
    └── ConfigError(ValueError)       a board configuration that cannot work

(``FlashMemoryError``, not ``FlashError``: that name is the flashing package's base,
:class:`bootloader.errors.FlashError`.)
"""

from __future__ import annotations


class FirmwareError(Exception):
    """Base of every error raised by firmware_py."""


class HalError(FirmwareError, LookupError):
    """A peripheral the board does not have, or a HAL used wrongly."""


class FlashMemoryError(FirmwareError, OSError):
    """A flash operation that the hardware refuses (busy, locked, out of range)."""


class ConfigError(FirmwareError, ValueError):
    """A board configuration that cannot work."""
