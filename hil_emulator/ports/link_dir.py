"""One emulator per ``--link-dir``: a lock file held for the emulator's life.

Two emulators linking into the same directory would fight over ``DIR/palm``, ``DIR/arm``
and ``DIR/control``: the second would replace the first's links (leaving the first running,
unreachable) and delete them when it exits.  So an emulator takes an exclusive ``flock`` on
``DIR/.hil-emulator.lock`` (holding its pid, for the message) before it makes any link, and
refuses a directory another live emulator holds.  The kernel drops the lock when its holder
exits, however it exits, so a crashed emulator never blocks the next one; its stale links
are then replaced.  The lock file is removed on a clean exit.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path
from typing import Final

from hil_emulator.errors import PortError

#: The lock file's name inside the link directory.
LOCK_NAME: Final = ".hil-emulator.lock"


class LinkDirLock:
    """The exclusive hold of one emulator on a link directory (see the module's doc)."""

    def __init__(self, link_dir: str | os.PathLike[str]) -> None:
        self.directory = Path(link_dir)
        self.path = self.directory / LOCK_NAME
        self._fd: int | None = None

    def acquire(self) -> None:
        """Make the directory if needed and take the lock; :class:`PortError` names why not
        (a file where the directory should be, a live emulator holding it)."""
        if self.directory.exists() and not self.directory.is_dir():
            raise PortError(f"the link directory {self.directory} is a file, not a directory: "
                            "give a directory (it is made if missing)")
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise PortError(f"cannot make the link directory {self.directory}: "
                            f"{exc.strerror or exc}") from exc
        while self._fd is None:
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            except OSError as exc:
                raise PortError(f"cannot lock the link directory {self.directory}: "
                                f"{exc.strerror or exc}") from exc
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.read(fd, 32).decode("ascii", "replace").strip() or "unknown"
                os.close(fd)
                raise PortError(
                    f"the link directory {self.directory} belongs to a running emulator "
                    f"(pid {holder}): stop it first, or give another --link-dir") from None
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False  # its holder removed it as we opened it: take a fresh one
            if not same:
                os.close(fd)
                continue
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode("ascii"))
            self._fd = fd

    def release(self) -> None:
        """Remove the lock file and drop the lock (idempotent)."""
        if self._fd is None:
            return
        try:
            self.path.unlink()
        except FileNotFoundError:
            pass
        os.close(self._fd)
        self._fd = None
