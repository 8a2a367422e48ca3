"""Run the ``hil-emulator`` command as a user would: a separate process, ports on ptys."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]


@contextmanager
def running_emulator(*args: str, startup_timeout_s: float = 60.0) -> Iterator[dict[str, Any]]:
    """Start ``hil-emulator ARGS``, yield its JSON line (plus ``"process"``), stop it with
    SIGINT and check it exits 0 with nothing more on standard output."""
    proc = subprocess.Popen([sys.executable, "-m", "tools.hil_emulator", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert proc.stdout is not None
        line = _readline(proc, startup_timeout_s)
        info = json.loads(line)
        info["process"] = proc
        yield info
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
        assert proc.returncode == 0, err
        assert out == "", f"more than one line on stdout: {out!r}"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def _readline(proc: subprocess.Popen[str], timeout_s: float) -> str:
    import selectors

    assert proc.stdout is not None
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        if not sel.select(timeout_s):
            proc.kill()
            raise TimeoutError(f"hil-emulator printed nothing in {timeout_s} s")
    line = proc.stdout.readline()
    if not line:
        _, err = proc.communicate(timeout=10)
        raise RuntimeError(f"hil-emulator exited ({proc.returncode}) before its ports: {err}")
    return line
