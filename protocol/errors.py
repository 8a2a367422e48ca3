"""The one exception tree of the `protocol` package.

Every error raised by `protocol` is a :class:`ProtocolError`, which is also a
:class:`ValueError`: bad bytes are bad values.  Errors coming from ``construct`` are
wrapped at the package boundary by :func:`wrap_construct`, keeping construct's path
(``(parsing) -> fields -> hall_pos``) so a person sees *where* a payload went wrong::

    ProtocolError(ValueError)
    ├── FrameError                    a hand frame is malformed
    │   ├── CrcError                  its CRC-16/XMODEM does not match
    │   └── FrameLengthError          it declares a payload longer than the maximum
    ├── ManchesterError               a chip stream cannot be decoded
    ├── MessageError                  a message cannot be found, built or parsed
    │   ├── UnknownMessageError       no catalogue entry by that name or key
    │   └── PayloadError              a payload does not match its declaration
    ├── ImageError                    a firmware image is truncated or inconsistent
    └── DynamixelError                a Dynamixel 1.0 packet is malformed
        ├── DynamixelChecksumError    its checksum does not match
        └── RegisterError             a control-table access is not allowed (protocol.control_tables)
            ├── RegisterRangeError    outside the table or its register's limits
            └── RegisterAccessError   a write to a read-only register

Defined here unless they need their module's data (the module is named).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import construct

T = TypeVar("T")


class ProtocolError(ValueError):
    """Base of every error raised by the protocol package."""


class FrameError(ProtocolError):
    """A hand frame is malformed (bad sync, bad length, truncated)."""


class CrcError(FrameError):
    """A hand frame's CRC-16/XMODEM does not match its contents."""


class FrameLengthError(FrameError):
    """A hand frame declares a payload longer than the configured maximum."""


class ManchesterError(ProtocolError):
    """A Manchester chip stream cannot be decoded (invalid chip pairs, bad framing)."""

    def __init__(self, message: str, positions: tuple[int, ...] = ()) -> None:
        super().__init__(message)
        #: Chip-pair indices (bit-cell positions) where the stream was invalid.
        self.positions = positions


class MessageError(ProtocolError):
    """A message cannot be found, built or parsed from the catalogue."""


class UnknownMessageError(MessageError):
    """No catalogue entry has that name or (board, type, direction)."""


class PayloadError(MessageError):
    """A payload does not match its message declaration.

    ``path`` is construct's path to the offending field, when known.
    """

    def __init__(self, message: str, path: str | None = None) -> None:
        super().__init__(message if not path else f"{message} (at {path})")
        self.path = path


class ImageError(ProtocolError):
    """A firmware image is truncated, oversized or inconsistent."""


class DynamixelError(ProtocolError):
    """A Dynamixel 1.0 packet is malformed."""


class DynamixelChecksumError(DynamixelError):
    """A Dynamixel 1.0 packet's checksum does not match."""


def wrap_construct(func: Callable[[], T], what: str, error: type[ProtocolError] = PayloadError) -> T:
    """Run ``func`` and turn any construct error into ``error``, keeping construct's path.

    ``what`` names the thing being parsed or built (for example ``"fmcb.status reply"``).
    """
    try:
        return func()
    except construct.ConstructError as exc:
        path = getattr(exc, "path", None)
        if error is PayloadError:
            raise PayloadError(f"{what}: {exc.__class__.__name__}: {_short(exc)}", path) from exc
        raise error(f"{what}: {_short(exc)}" + (f" (at {path})" if path else "")) from exc
    except KeyError as exc:
        raise error(f"{what}: missing field {exc}") from exc
    except (TypeError, AttributeError, OverflowError, struct_error_types()) as exc:
        # construct lets some build-time errors through unwrapped (a missing field, a wrong type).
        raise error(f"{what}: {exc.__class__.__name__}: {exc}") from exc


def _short(exc: BaseException) -> str:
    text = str(exc)
    # construct prefixes messages with the path in parentheses; keep only the message.
    if "\n" in text:
        text = text.splitlines()[-1]
    return text


def struct_error_types() -> type[Exception]:
    """The stdlib ``struct.error`` type (construct can leak it when building)."""
    import struct

    return struct.error
