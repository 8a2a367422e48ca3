"""The view's server child (host.view.server, host.view.child): rerun serves the page from a
process of its own, started with the view and gone when the view closes or when the host
process dies, a kill -9 included; a server that cannot start says why.

Waits here are for processes to end and have generous bounds (the machine may be busy);
nothing is timed.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("rerun", reason="the view needs rerun-sdk (the 'view' extra)")

from host.view.live import RobotView, ViewUnavailable  # noqa: E402
from host.view.server import port_free  # noqa: E402

ROOT = Path(__file__).resolve().parents[3]
#: How long a process may take to go (s; a generous bound on a busy machine).
GONE_WITHIN_S = 60.0


def alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie, dead but not yet reaped, does not)."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as stat:
            return stat.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def wait_gone(*pids: int) -> list[int]:
    """The pids still running after waiting up to :data:`GONE_WITHIN_S`."""
    deadline = time.monotonic() + GONE_WITHIN_S
    while time.monotonic() < deadline and any(alive(p) for p in pids):
        time.sleep(0.1)
    return [p for p in pids if alive(p)]


def test_the_page_is_served_by_a_child_that_ends_when_the_view_closes() -> None:
    view = RobotView(web_port=0)
    server = view.server
    assert server is not None and server.server_pid is not None
    watcher, rerun = server.process.pid, server.server_pid
    assert watcher != os.getpid() and alive(watcher) and alive(rerun)
    with socket.create_connection(("127.0.0.1", server.web_port), timeout=30):
        pass  # the page is served: by the child, this process listens on nothing
    assert view.server_cpu_s() is not None
    view.close()
    assert not server.running
    assert wait_gone(watcher, rerun) == []
    assert port_free(server.web_port) and port_free(server.grpc_port)


CHILD_SESSION = """
import sys, time
from host.view.live import RobotView
view = RobotView(web_port=0)
print(view.server.process.pid, view.server.server_pid, flush=True)
if sys.argv[1] == "sleep":
    time.sleep(600)
sys.stdin.readline()  # "exit": ends when told, never closing the view
"""


@pytest.mark.parametrize("ending", ["kill -9", "exit without close"])
def test_the_server_ends_when_the_host_process_does(ending: str) -> None:
    sleep = ending == "kill -9"
    host = subprocess.Popen([sys.executable, "-c", CHILD_SESSION, "sleep" if sleep else "exit"],
                            cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert host.stdout is not None and host.stdin is not None
        watcher, rerun = (int(pid) for pid in host.stdout.readline().split())
        assert alive(watcher) and alive(rerun)
        if sleep:
            host.send_signal(signal.SIGKILL)
        else:
            host.stdin.write("\n")
            host.stdin.flush()
        host.wait(GONE_WITHIN_S)
        assert wait_gone(watcher, rerun) == [], f"the view's server outlived its host ({ending})"
    finally:
        if host.poll() is None:
            host.kill()
            host.wait()


def test_a_taken_port_is_refused_before_anything_starts_naming_who_holds_it() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(ViewUnavailable) as refused:
            RobotView(web_port=port)
    name = Path("/proc/self/comm").read_text().strip()
    assert str(refused.value) == (f"port {port} is taken (by pid {os.getpid()} ({name})): "
                                  "choose other ports (--view-port N: N and N+1)")


def test_a_port_a_server_just_left_is_free_while_its_connections_wait() -> None:
    """A server that served a page and ended leaves its side of each connection in TCP's
    TIME_WAIT for up to a minute; a new server binds the port all the same (with
    SO_REUSEADDR, as rerun's does), so the check says free, and such a server binds."""
    with socket.socket() as server:
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind(("127.0.0.1", 0))
        server.listen()
        port = server.getsockname()[1]
        with socket.create_connection(("127.0.0.1", port)) as page:
            served, _ = server.accept()
            served.sendall(b"HTTP/1.1 200 OK\r\n\r\n")
            served.close()  # the server closes first: its side waits in TIME_WAIT
            while page.recv(4096):
                pass
    assert port_free(port)
    with socket.socket() as next_server:
        next_server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        next_server.bind(("127.0.0.1", port))
        next_server.listen()
        assert not port_free(port)  # a listener there: taken


def test_a_server_that_cannot_start_says_why_and_leaves_nothing(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RERUN_CLI_PATH", "/bin/false")
    before = set(Path(f"/proc/{os.getpid()}/task/{os.getpid()}/children").read_text().split())
    with pytest.raises(ViewUnavailable, match="did not start: rerun exited"):
        RobotView(web_port=0)
    after = set(Path(f"/proc/{os.getpid()}/task/{os.getpid()}/children").read_text().split())
    assert after <= before
