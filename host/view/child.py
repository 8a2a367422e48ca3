"""The view's server process: rerun's web viewer and data endpoint, ended with the session.

Run by :class:`host.view.server.ViewServer` as a script (``python -I -S child.py``:
standard library only, nothing of this project is imported here)::

    child.py RERUN_BINARY WEB_PORT GRPC_PORT MEMORY_LIMIT PARENT_PID

It starts ``rerun --serve-web`` (the binary the ``rerun-sdk`` wheel ships) bound to
127.0.0.1, waits until both ports accept connections and prints one line on stdout:
``ready PID`` (rerun's pid) or ``failed: WHY``.  Then it waits for the session to end and
stops rerun (SIGTERM, SIGKILL after :data:`STOP_GRACE_S`) when any of these happens:

* its stdin reaches end of file: the host closed the pipe, or the host process is gone
  however it ended (a kill -9 included: the kernel closes the pipe);
* its parent is no longer ``PARENT_PID`` (the host died and this process was re-parented);
* rerun itself exited.

On Linux rerun is also started with a parent-death signal, so killing this process
(even with SIGKILL) takes rerun down with it.  The process sits in its own session (the
host starts it so), so a Ctrl-C at the terminal reaches the host only; the host ends the
view as the session ends.
"""

from __future__ import annotations

import ctypes
import os
import select
import signal
import socket
import subprocess
import sys
import tempfile
import time
from typing import IO

#: How long rerun may take to listen on both ports (s, wall clock; a busy machine).
START_TIMEOUT_S = 60.0
#: How long rerun gets to exit after SIGTERM before SIGKILL (s).
STOP_GRACE_S = 5.0
#: How often the parent and rerun are checked while stdin stays quiet (s).
CHECK_INTERVAL_S = 1.0
_PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:
    """In the forked rerun, before exec: SIGTERM when this process dies (Linux only)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    except (OSError, AttributeError):
        pass


def _listening(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(1.0)
        return s.connect_ex(("127.0.0.1", port)) == 0


def _tail(log: IO[bytes], lines: int = 3) -> str:
    log.seek(0)
    text = log.read().decode("utf-8", "replace")
    useful = [line.strip() for line in text.splitlines()
              if line.strip() and "INFO" not in line]
    return " / ".join(useful[-lines:]) or "no output"


def _stop(process: subprocess.Popen[bytes]) -> None:
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(STOP_GRACE_S)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def _wait_for_end(process: subprocess.Popen[bytes], parent: int) -> None:
    """Until stdin closes, the parent changes or rerun exits."""
    stdin = sys.stdin.fileno()
    while True:
        readable, _, _ = select.select([stdin], [], [], CHECK_INTERVAL_S)
        if readable and not os.read(stdin, 4096):
            return
        if os.getppid() != parent or process.poll() is not None:
            return


def main(argv: list[str]) -> int:
    binary, web_port, grpc_port, memory, parent = argv
    if os.getppid() != int(parent):  # the host is already gone
        return 1
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    command = [binary, "--serve-web", "--bind", "127.0.0.1", "--port", grpc_port,
               "--web-viewer-port", web_port, "--server-memory-limit", memory]
    env = {**os.environ, "RERUN_APP_ONLY": "true"}  # as the SDK's own spawn: no opt-in text
    with tempfile.TemporaryFile() as log:
        try:
            process = subprocess.Popen(
                command, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                env=env, preexec_fn=_die_with_parent if sys.platform == "linux" else None)
        except OSError as exc:
            print(f"failed: cannot run {binary}: {exc}", flush=True)
            return 1
        try:
            deadline = time.monotonic() + START_TIMEOUT_S
            while not (_listening(int(grpc_port)) and _listening(int(web_port))):
                if process.poll() is not None:
                    print(f"failed: rerun exited ({_tail(log)})", flush=True)
                    return 1
                if time.monotonic() > deadline:
                    print(f"failed: rerun did not listen within {START_TIMEOUT_S:g} s",
                          flush=True)
                    return 1
                time.sleep(0.05)
            print(f"ready {process.pid}", flush=True)
            _wait_for_end(process, int(parent))
        finally:
            _stop(process)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
