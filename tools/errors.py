"""The tools' one exception tree.

Each error also inherits what a caller catches for it: a bad file or value is a
``ValueError``, an output that cannot be written an ``OSError``, a fuzz target that does not
answer a :class:`host.errors.TransportError` (so the host library's handlers see a link
failure), an oracle's verdict an ``AssertionError``::

    ToolError
    ├── InputError(ValueError)            handbus: bad arguments or input (exit 2)
    ├── FieldValueError(ValueError)       a ``field=value`` word that cannot be used
    ├── OutputError(OSError)              standard output could not be written (exit 1)
    ├── McapCaptureError                  not a readable MCAP recording, or no such channel
    ├── NotARecording                     robot-view: not an MCAP recording of this project
    ├── BuildError                        the compiled core could not be built
    ├── DemoFailed                        a step of ``make demo`` failed
    ├── ScenarioError(ValueError)         a hil-bench scenario file that cannot be used
    ├── ReplayRefused(ValueError)         a recording hil-bench replay cannot replay (exit 2)
    ├── TargetSilent(TransportError)      a fuzz target does not answer before the campaign
    ├── WrongTarget(TransportError)       the node on the port is another board
    ├── FuzzFailure(AssertionError)       a hil-fuzz oracle failed
    └── FuzzPropertyError(AssertionError) an in-process fuzz property failed

Not errors: ``tools.fuzz.campaign.LinkLost`` and ``BudgetSpent`` are ``BaseException``
signals carried through hypothesis, which must not catch them.
"""

from __future__ import annotations

from host.errors import TransportError


class ToolError(Exception):
    """Base of every error the tools raise on purpose."""


class InputError(ToolError, ValueError):
    """Bad arguments or input to ``handbus``: printed, exit status 2."""


class FieldValueError(ToolError, ValueError):
    """A ``field=value`` word that cannot be used."""


class OutputError(ToolError, OSError):
    """Standard output could not be written (its ``errno`` and ``strerror`` say why)."""


class McapCaptureError(ToolError):
    """The file is not a readable MCAP recording or holds no raw channel of that kind."""


class NotARecording(ToolError):
    """A file that is not an MCAP recording this project wrote."""


class BuildError(ToolError):
    """The compiled core could not be built (no C compiler, or mypyc rejected a module)."""


class DemoFailed(ToolError):
    """A step failed: ``step`` names it, the message says why."""

    def __init__(self, step: str, reason: str) -> None:
        super().__init__(reason)
        self.step = step


class ScenarioError(ToolError, ValueError):
    """A scenario file that cannot be used; the message names the file and the key."""


class ReplayRefused(ToolError, ValueError):
    """A recording ``hil-bench replay`` cannot replay (the message says why, in one line)."""


class TargetSilent(ToolError, TransportError):
    """The target does not answer a ping before the campaign or replay sends anything."""


class WrongTarget(ToolError, TransportError):
    """The node answering on the port identifies as another board than the target's."""


class FuzzFailure(ToolError, AssertionError):
    """An oracle failed; the message says which and how."""


class FuzzPropertyError(ToolError, AssertionError):
    """A property of a decoder or handler failed on an input."""
