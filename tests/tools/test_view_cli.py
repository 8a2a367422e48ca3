"""``watch`` and ``--view`` on handctl and armctl, ``--view`` on the demo's parser: each
serves the page on this machine and prints its address; without rerun-sdk a clear error."""

from __future__ import annotations

import http.client
import io
import os
import re
import signal
import socket
import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest

pytest.importorskip("rerun", reason="the view needs rerun-sdk (the 'view' extra)")

from hil_emulator.inprocess import forget_shared_emulators  # noqa: E402
from host.view.server import free_port, port_free  # noqa: E402
from tools.cli import armctl, handctl  # noqa: E402

pytestmark = pytest.mark.process_wide("rerun serves its web viewer until the process ends")

ROOT = Path(__file__).resolve().parents[2]
ADDRESS = re.compile(r"view: (http://127\.0\.0\.1:\d+/\?url=\S+)")


@pytest.fixture(autouse=True)
def _fresh_emulators():
    yield
    forget_shared_emulators()


def test_armctl_watch_serves_the_page_and_prints_its_address(
        capsys: pytest.CaptureFixture[str]) -> None:
    out = io.StringIO()
    status = armctl.main(["--port", "emu://arm/arm?name=view_cli", "--view-port", "0",
                          "watch", "--seconds", "0.3", "--rate", "20"], out)
    assert status == 0
    assert out.getvalue().strip() == "7 states read"  # 0, 0.05, … 0.30 s
    match = ADDRESS.search(capsys.readouterr().err)
    assert match, "no address printed"


def test_armctl_status_with_view_keeps_its_output_and_serves_a_page(
        capsys: pytest.CaptureFixture[str]) -> None:
    out = io.StringIO()
    status = armctl.main(["--port", "emu://arm/arm?name=view_cli", "--json", "--view",
                          "--view-port", "0", "status"], out)
    assert status == 0 and '"joints"' in out.getvalue()
    assert ADDRESS.search(capsys.readouterr().err)


def test_handctl_watch_reads_the_hand(capsys: pytest.CaptureFixture[str]) -> None:
    status = handctl.main(["--port", "emu://hand/palm?name=view_cli", "--view-port", "0",
                           "watch", "--seconds", "0.1", "--rate", "20"])
    captured = capsys.readouterr()
    assert status == 0 and captured.out.strip() == "3 states read"
    assert ADDRESS.search(captured.err)


def test_the_printed_address_is_the_viewer_page_served_from_the_package() -> None:
    from host.view.live import RobotView

    with RobotView(web_port=0) as view:
        assert view.address is not None
        page = urllib.request.urlopen(view.address, timeout=30).read().decode()
    assert "Rerun" in page and "<canvas" in page


def test_a_taken_port_is_a_clear_error(capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        status = armctl.main(["--port", "emu://arm/arm?name=view_cli", "--view",
                              "--view-port", str(port), "status"], io.StringIO())
    assert status == 1
    assert f"port {port} is taken" in capsys.readouterr().err


def test_a_bad_view_port_is_a_usage_error() -> None:
    assert armctl.main(["--port", "emu://arm/arm", "--view-port", "70000", "status"]) == 2


def test_without_rerun_the_view_says_how_to_install_it() -> None:
    code = ("import sys; sys.modules['rerun'] = None; from tools.cli.armctl import main; "
            "sys.exit(main(['--port', 'emu://arm/arm', '--view', '--view-port', '0', "
            "'status']))")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 1, proc.stderr
    assert "needs rerun-sdk" in proc.stderr and "pip install" in proc.stderr
    assert "Traceback" not in proc.stderr


def _two_free_ports() -> int:
    """A port N with N and N+1 both free now (the page's and its data's)."""
    while True:
        port = free_port()
        if port < 65534 and port_free(port + 1):
            return port


@pytest.mark.slow
def test_a_view_follows_one_a_page_was_open_on_at_once(tmp_path: Path) -> None:
    """``armctl watch`` with a page open on it (its connections kept, as a browser keeps
    them), Ctrl-C, then at once ``armctl status … --view`` on the same ports: served, though
    the first server's side of those connections still waits on the ports."""
    port = _two_free_ports()
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    watch = subprocess.Popen(
        [sys.executable, "-m", "tools.cli.armctl", "--port", "emu://arm/arm", "watch",
         "--view-port", str(port), "--rate", "5"],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert watch.stderr is not None
        line = ""
        while not ADDRESS.search(line):
            line = watch.stderr.readline()
            assert line, "armctl watch ended without printing the view's address"
        page = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
        page.request("GET", "/")  # HTTP/1.1: kept open after the answer, as a browser does
        assert page.getresponse().read()
        data = socket.create_connection(("127.0.0.1", port + 1), timeout=30)
        data.sendall(b"GET /proxy HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        watch.send_signal(signal.SIGINT)
        assert watch.wait(timeout=120) == 130
        follow = subprocess.run(
            [sys.executable, "-m", "tools.cli.armctl", "status", "--port", "emu://arm/arm",
             "--view", "--view-port", str(port)],
            cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
        page.close()
        data.close()
    finally:
        if watch.poll() is None:
            watch.kill()
            watch.wait()
    assert follow.returncode == 0, follow.stderr
    assert f"view: http://127.0.0.1:{port}/" in follow.stderr
