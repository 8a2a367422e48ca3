"""The flashing package's one exception tree.

    FlashError
    ├── ImageFileError(ValueError)   an input or image file is missing, unreadable or wrong
    ├── SigningError(ValueError)     a key is unreadable, or a signature does not verify
    ├── PlanError(ValueError)        the plan cannot run: nothing has been touched
    └── StepFailed                   a node's flashing step failed for good (the batch driver
                                     catches it and marks the node FAILED; never escapes)
"""

from __future__ import annotations


class FlashError(Exception):
    """Base of every error raised by the flashing package."""


class ImageFileError(FlashError, ValueError):
    """An input file (raw, Intel HEX, ELF) or image file cannot be used."""


class SigningError(FlashError, ValueError):
    """A key file cannot be read, or an image's signature does not verify."""


class PlanError(FlashError, ValueError):
    """The plan cannot run (wrong image, finger not answering …); nothing was touched."""


class StepFailed(FlashError):
    """A step of a node's flashing failed for good (the message says which and why)."""
