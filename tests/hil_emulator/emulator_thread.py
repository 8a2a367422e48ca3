"""An emulator serving its ptys in real time on a thread of the test's own process (beside
:mod:`tests.hil_emulator.emulator_process`, which runs the ``hil-emulator`` command)."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from hil_emulator.emulator import Emulator
from hil_emulator.ports.host_links import PtyBacked
from tests.hil_emulator.emulator_process import HANG_GUARD_S


@dataclass
class Serving:
    """A running :meth:`Emulator.run`: its ``ports`` (:meth:`Emulator.open_ports`, empty
    when it serves none), the ``stop`` flag and the ``thread``."""

    emulator: Emulator
    ports: Mapping[str, Any]
    stop: threading.Event
    thread: threading.Thread

    def end(self, join_s: float = HANG_GUARD_S) -> None:
        """Set the stop flag and wait up to ``join_s`` (s of wall time: a hang guard) for
        the run to return; a run that does not is an error."""
        self.stop.set()
        self.thread.join(join_s)
        assert not self.thread.is_alive(), f"Emulator.run did not stop within {join_s} s"


@contextmanager
def serving(emulator: Emulator, *, ports: bool = True, realtime: bool = True,
            close: bool = True) -> Iterator[Serving]:
    """``emulator`` running on a thread (real time unless ``realtime=False``) until the
    block ends; with ``ports`` (default) it opens its host ptys first and the block starts
    once their readers take bytes.  Afterwards the run is stopped and joined and, with
    ``close`` (default), the emulator is closed (its ptys gone)."""
    opened = emulator.open_ports() if ports else {}
    stop = threading.Event()
    thread = threading.Thread(target=emulator.run, args=(stop,), kwargs={"realtime": realtime},
                              daemon=True, name=f"emulator-{'-'.join(opened) or 'run'}")
    run = Serving(emulator, opened, stop, thread)
    try:
        run.thread.start()
        if realtime:
            _wait_for_readers(run)
        yield run
    finally:
        try:
            run.end()
        finally:
            if close:
                emulator.close()


def _wait_for_readers(run: Serving) -> None:
    links = [link for link in run.emulator.links.values() if isinstance(link, PtyBacked)]
    deadline = time.monotonic() + HANG_GUARD_S
    while not all(link.reader is not None for link in links):
        assert run.thread.is_alive(), "Emulator.run ended at once"
        assert time.monotonic() < deadline, "the emulator's port readers did not start"
        time.sleep(0.001)
