"""Output every tool shares: standard output or an output file that cannot be written (a
full disk, ``/dev/full``, a read-only folder) ends the tool with one line on stderr and exit
status 1, never a traceback; standard output closed by its reader (``… | head``) ends it
quietly with 141, as a process killed by SIGPIPE.

Every ``main`` of ``tools/`` is wrapped in :func:`guard_output`; :func:`tools.cli.common.run`
(the robot CLIs) catches :class:`OutputError` itself, before its other mappings.
"""

from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, Final, TextIO, TypeVar, cast

from tools.errors import OutputError

#: A file or standard output that cannot be written.
EXIT_OUTPUT: Final = 1
#: Standard output closed by its reader (``… | head``): as a process killed by SIGPIPE.
EXIT_BROKEN_PIPE: Final = 141

_Main = TypeVar("_Main", bound=Callable[..., int])


class _CheckedStdout:
    """Standard output whose write errors (but a closed pipe) become :class:`OutputError`,
    so they are told apart from a file's."""

    def __init__(self, stream: TextIO) -> None:
        self._stream = stream
        #: The first failure, kept: a caller (argparse's --help) may swallow it.
        self.failed: OSError | None = None

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except OSError as exc:
            raise self._failure(exc) from exc

    def flush(self) -> None:
        try:
            self._stream.flush()
        except OSError as exc:
            raise self._failure(exc) from exc

    def _failure(self, exc: OSError) -> OSError:
        error = exc if isinstance(exc, BrokenPipeError) else OutputError(exc.errno, exc.strerror)
        self.failed = self.failed or error
        return error

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


@contextmanager
def checked_stdout() -> Iterator[None]:
    """Within the block, a failed write to ``sys.stdout`` raises :class:`OutputError`."""
    real = sys.stdout
    if isinstance(real, _CheckedStdout):
        yield
        return
    sys.stdout = cast(TextIO, _CheckedStdout(real))
    try:
        yield
    finally:
        sys.stdout = real


def output_failed(prog: str, exc: OSError) -> int:
    """Say on stderr, in one line, that ``exc`` stopped the output; the exit status."""
    if isinstance(sys.stdout, _CheckedStdout):
        sys.stdout.failed = None  # told once: an outer guard does not tell it again
    if isinstance(exc, BrokenPipeError):
        silence_stdout()
        return EXIT_BROKEN_PIPE
    if isinstance(exc, OutputError):
        silence_stdout()  # the interpreter's flush at exit would fail again
        print(f"{prog}: cannot write standard output: {exc.strerror or exc}", file=sys.stderr)
    else:
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"{prog}: {where}{exc.strerror or exc}", file=sys.stderr)
    return EXIT_OUTPUT


def guard_output(prog: str) -> Callable[[_Main], _Main]:
    """Decorate a tool's ``main``: an ``OSError`` it does not handle itself (standard output
    or a file that cannot be written, or read) is one line on stderr and exit status 1."""

    def wrap(main: _Main) -> _Main:
        @functools.wraps(main)
        def guarded(*args: Any, **kwargs: Any) -> int:
            with checked_stdout():
                stdout = sys.stdout
                try:
                    try:
                        status = main(*args, **kwargs)
                    except SystemExit:
                        _check(stdout)  # --help into a full disk is a failure too
                        raise
                    _check(stdout)
                    return status
                except OSError as exc:
                    return output_failed(prog, exc)

        return cast(_Main, guarded)

    return wrap


def _check(stdout: TextIO) -> None:
    """Flush ``stdout``; raise the first failure of its writes even if it was swallowed."""
    stdout.flush()
    failed = getattr(stdout, "failed", None)
    if failed is not None:
        raise failed


def silence_stdout() -> None:
    """Point standard output at /dev/null, so the interpreter's flush at exit does not
    report the failure again."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):
        return  # not a file descriptor (a test's capture): nothing will be flushed to it
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, fd)
    os.close(devnull)
