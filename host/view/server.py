"""Where the view is served from: rerun's web viewer in a child process of the session.

:class:`ViewServer` starts ``rerun --serve-web`` (the binary the ``rerun-sdk`` wheel ships,
package ``rerun_cli``) under a small watcher (:mod:`host.view.child`), so serving the page
and buffering its data cost the robot's process nothing: the host only encodes and sends
(a gRPC client, ``rerun.GrpcSink``).  The child starts with the view and ends with it:
:meth:`ViewServer.close` ends it, and so does the host process ending in any way, a kill -9
included (the watcher sees its stdin pipe close; on Linux rerun also dies with the
watcher).  :meth:`ViewServer.cpu_seconds` says what the child has cost (s of CPU), so a
measurement of the host's loop can name the rest.

Ports: the page on ``web_port``, its data on ``grpc_port``, both bound to 127.0.0.1.
"""

from __future__ import annotations

import importlib.util
import os
import select
import socket
import subprocess
import sys
import urllib.parse
from pathlib import Path
from typing import Final

from host.errors import ViewUnavailable

#: The watcher program, run as a script (standard library only).
CHILD: Final = Path(__file__).with_name("child.py")
#: How long the child may take to answer ``ready`` (s, wall clock; a busy machine).
READY_TIMEOUT_S: Final = 90.0
#: How long :meth:`ViewServer.close` waits for the child (s) before killing it.
CLOSE_TIMEOUT_S: Final = 15.0
#: What the server keeps for late-arriving pages before dropping the oldest.
SERVER_MEMORY: Final = "512MiB"


def free_port() -> int:
    """A TCP port free on this machine now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def port_free(port: int) -> bool:
    """Whether a server can bind ``port`` on 127.0.0.1 now, binding as rerun's server (and
    most servers) binds: with ``SO_REUSEADDR``, so the connections of a server that just
    ended, waiting out TCP's TIME_WAIT, do not count; a socket listening there does."""
    with socket.socket() as s:
        if os.name == "posix":  # on Windows the option would let two listeners share it
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _listening_inodes(port: int) -> set[str]:
    """The socket inodes listening on TCP ``port`` (any address), from ``/proc/net``."""
    inodes = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            with open(table, encoding="ascii") as rows:
                next(rows, None)
                for row in rows:
                    fields = row.split()
                    # local address "0100007F:2382", state 0A = LISTEN, inode field 9
                    if (len(fields) > 9 and fields[3] == "0A"
                            and int(fields[1].rsplit(":", 1)[1], 16) == port):
                        inodes.add(fields[9])
        except OSError:
            continue
    return inodes


def port_holder(port: int) -> str | None:
    """Who listens on TCP ``port``: ``"pid 1234 (python3)"`` where ``/proc`` says (Linux, a
    process this user may look into), ``"another program"`` where only the kernel's table
    does, None where nothing listens."""
    inodes = _listening_inodes(port)
    if not inodes:
        return None
    wanted = {f"socket:[{inode}]" for inode in inodes}
    for entry in sorted(Path("/proc").iterdir(), key=lambda p: p.name):
        if not entry.name.isdigit():
            continue
        try:
            for fd in (entry / "fd").iterdir():
                if os.readlink(fd) in wanted:
                    name = (entry / "comm").read_text(encoding="utf-8", errors="replace")
                    return f"pid {entry.name} ({name.strip()})"
        except OSError:
            continue
    return "another program"


def grpc_url(grpc_port: int) -> str:
    """The data endpoint's address (what the page and the logging SDK connect to)."""
    return f"rerun+http://127.0.0.1:{grpc_port}/proxy"


def page_address(web_port: int, grpc: str, host: str = "127.0.0.1") -> str:
    """The address of the web page that shows the data served at ``grpc``."""
    return f"http://{host}:{web_port}/?url={urllib.parse.quote(grpc, safe='')}"


def rerun_binary() -> Path:
    """The ``rerun`` executable of the installed rerun-sdk (``RERUN_CLI_PATH`` overrides it,
    as the wheel's own ``rerun`` script allows)."""
    override = os.environ.get("RERUN_CLI_PATH")
    if override:
        return Path(override)
    spec = importlib.util.find_spec("rerun_cli")
    if spec is None or spec.origin is None:
        raise ViewUnavailable("rerun-sdk's viewer (package rerun_cli) is not installed")
    binary = Path(spec.origin).with_name("rerun.exe" if sys.platform == "win32" else "rerun")
    if not binary.is_file():
        raise ViewUnavailable(f"rerun-sdk's viewer binary is missing: {binary}")
    return binary


def _cpu_seconds(pid: int, children: bool) -> float:
    """utime + stime of process ``pid`` (and of its waited-for children), s; 0 if gone."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as stat:
            fields = stat.read().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    ticks = int(fields[11]) + int(fields[12])
    if children:
        ticks += int(fields[13]) + int(fields[14])
    return ticks / os.sysconf("SC_CLK_TCK")


class ViewServer:
    """rerun's web page on ``web_port`` and its data on ``grpc_port``, served by a child
    process until :meth:`close` (or until this process ends)."""

    def __init__(self, web_port: int, grpc_port: int, memory_limit: str = SERVER_MEMORY
                 ) -> None:
        for port in (web_port, grpc_port):
            if not port_free(port):
                holder = port_holder(port)
                raise ViewUnavailable(f"port {port} is taken (by {holder or 'another program'}): "
                                      "choose other ports (--view-port N: N and N+1)")
        command = [sys.executable, "-I", "-S", str(CHILD), str(rerun_binary()),
                   str(web_port), str(grpc_port), memory_limit, str(os.getpid())]
        self.web_port = web_port
        self.grpc_port = grpc_port
        self.url = grpc_url(grpc_port)
        self.address = page_address(web_port, self.url)
        self.process = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                        start_new_session=True)
        #: rerun's pid (a child of :attr:`process`).
        self.server_pid: int | None = None
        answer = self._first_line()
        if not answer.startswith("ready "):
            self.close()
            raise ViewUnavailable(f"the view's server did not start: "
                                  f"{answer.removeprefix('failed: ') or 'no answer'}")
        self.server_pid = int(answer.split()[1])

    def _first_line(self) -> str:
        assert self.process.stdout is not None
        readable, _, _ = select.select([self.process.stdout], [], [], READY_TIMEOUT_S)
        if not readable:
            return f"failed: no answer within {READY_TIMEOUT_S:g} s"
        return self.process.stdout.readline().decode("utf-8", "replace").strip()

    @property
    def running(self) -> bool:
        """Whether the child still runs."""
        return self.process.poll() is None

    def cpu_seconds(self) -> float | None:
        """CPU time the child has used so far (s: the watcher and rerun, user + system);
        None where ``/proc`` does not say (not Linux)."""
        if not Path("/proc/self/stat").exists():
            return None
        total = _cpu_seconds(self.process.pid, children=True)
        if self.server_pid is not None:
            total += _cpu_seconds(self.server_pid, children=False)
        return total

    def close(self) -> None:
        """End the child (it stops rerun first) and wait for it (idempotent)."""
        if self.process.stdin is not None and not self.process.stdin.closed:
            try:
                self.process.stdin.close()
            except OSError:
                pass
        try:
            self.process.wait(CLOSE_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        if self.process.stdout is not None:
            self.process.stdout.close()
