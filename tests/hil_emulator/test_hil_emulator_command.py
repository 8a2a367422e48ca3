"""The ``hil-emulator`` command as a user runs it: a process, ptys, links, signals."""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hil_emulator.ports.link_dir import LOCK_NAME
from tests.hil_emulator.emulator_process import ROOT, emulator_stats, running_emulator, status

EXPECTED = {
    "full": {"palm", "arm", "can"},
    "hand": {"palm", "can"},
    "arm": {"arm"},
    "loose-finger": {"fingers"},
}


def _is_tty(path: str) -> bool:
    return stat.S_ISCHR(os.stat(path).st_mode)


@pytest.mark.slow
@pytest.mark.parametrize("config", sorted(EXPECTED))
def test_every_configuration_starts_names_its_ports_and_cleans_up(config: str,
                                                                  tmp_path: Path) -> None:
    links = tmp_path / "robot"
    with running_emulator("--config", config, "--link-dir", str(links)) as info:
        assert info["config"] == config
        assert isinstance(info["fingers"], list)
        for key in ("palm", "arm"):
            assert key in info  # always present; null when the configuration has none
            assert (info[key] is not None) == (key in EXPECTED[config])
        assert ("can" in info) == ("can" in EXPECTED[config])
        if config == "loose-finger":
            assert len(info["fingers"]) == 1
        else:
            assert info["fingers"] == []
        ports = [info[k] for k in ("palm", "arm", "can") if info.get(k)] + info["fingers"]
        assert ports and all(_is_tty(p) for p in ports)
        made = sorted(p.name for p in links.iterdir()
                      if p.name not in ("control", LOCK_NAME))
        expected_links = sorted({"loose-finger": ["finger0"]}.get(
            config, [k for k in ("palm", "arm", "can") if k in EXPECTED[config]]))
        assert made == expected_links
        for name in made:
            assert os.path.realpath(links / name) in ports
        assert (links / "control").is_socket()  # the fault-injection control channel
    assert list(links.iterdir()) == []  # links removed on exit


@pytest.mark.slow
def test_sigterm_also_stops_it_cleanly(tmp_path: Path) -> None:
    proc = subprocess.Popen([sys.executable, "-m", "tools.cli.serve_emulator", "--config", "arm",
                             "--no-physics", "--link-dir", str(tmp_path)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().startswith("{")
        assert (tmp_path / "arm").is_symlink()
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=20)
        assert proc.returncode == 0
        assert "Traceback" not in proc.communicate()[1]
        assert not (tmp_path / "arm").exists()
    finally:
        if proc.poll() is None:
            proc.kill()


@pytest.mark.slow
def test_sigterm_acts_at_once_on_an_emulator_far_behind_on_a_busy_machine() -> None:
    """With a CPU hog running, the emulator is stopped (SIGSTOP) for half a second, so it
    is that far behind when SIGTERM arrives right after SIGCONT.  It stops its loop and
    exits 0: the test measures kill to exit (bounded at 2 s: interpreter and MuJoCo
    teardown on a loaded machine); ``stop_ms`` in ``--stats`` is the emulator's own figure
    from the signal to its loop's end."""
    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    proc = subprocess.Popen([sys.executable, "-m", "tools.cli.serve_emulator", "--config", "arm",
                             "--stats"], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().startswith("{")
        time.sleep(0.5)
        proc.send_signal(signal.SIGSTOP)
        time.sleep(0.5)
        proc.send_signal(signal.SIGCONT)
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=30)
        kill_to_exit_s = time.monotonic() - t0
        err = proc.communicate()[1]
    finally:
        hog.kill()
        hog.wait()
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    stats = emulator_stats(err)
    assert stats["late_episodes"] >= 1 and "ms late" in err  # it was far behind
    assert stats["stop_ms"] is not None and stats["stop_ms"] <= kill_to_exit_s * 1e3
    assert kill_to_exit_s < 2.0, (kill_to_exit_s, stats["stop_ms"])


def test_an_unknown_configuration_is_refused_with_the_choices() -> None:
    result = subprocess.run([sys.executable, "-m", "tools.cli.serve_emulator", "--config", "octopus"],
                            cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert result.stdout == ""
    assert "full" in result.stderr and "loose-finger" in result.stderr


def test_an_unknown_hand_layout_is_refused_with_the_choices() -> None:
    result = subprocess.run([sys.executable, "-m", "tools.cli.serve_emulator", "--config", "hand",
                             "--layout", "octopus"],
                            cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert result.stdout == ""
    assert "layout" in result.stderr and "four-finger-thumb" in result.stderr


@pytest.mark.slow
def test_viewer_without_a_display_says_so_and_runs_on() -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    proc = subprocess.Popen([sys.executable, "-m", "tools.cli.serve_emulator", "--config", "arm",
                             "--viewer", "--duration", "1"], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0
    assert '"viewer": false' in out
    assert "no display" in err


@pytest.mark.slow
def test_fast_mode_serves_the_stock_sdk_too() -> None:
    from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

    with running_emulator("--config", "arm", "--fast", "--no-physics") as info:
        port = PortHandler(info["arm"])
        assert port.openPort() and port.setBaudRate(1_000_000)
        try:
            sdk = PacketHandler(1.0)
            for _ in range(4):  # a user retries a ping a busy machine let time out
                model, result, _ = sdk.ping(port, 6)
                if result == COMM_SUCCESS:
                    break
                time.sleep(0.1)
                port.ser.reset_input_buffer()  # a late reply is not the next one's
            assert result == COMM_SUCCESS and model == 64
        finally:
            port.closePort()


def test_a_link_name_taken_by_a_file_is_a_clear_error(tmp_path: Path) -> None:
    (tmp_path / "arm").write_text("not a link")
    result = subprocess.run([sys.executable, "-m", "tools.cli.serve_emulator", "--config", "arm",
                             "--no-physics", "--link-dir", str(tmp_path)],
                            cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 1
    assert result.stdout == ""
    assert "arm" in result.stderr and "not a symlink" in result.stderr
    assert (tmp_path / "arm").read_text() == "not a link"  # nothing of the user's is lost


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "soon"])
def test_duration_must_be_positive_and_finite(value: str) -> None:
    result = subprocess.run([sys.executable, "-m", "tools.cli.serve_emulator", "--duration", value],
                            cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert result.stdout == ""
    assert "--duration" in result.stderr and "seconds" in result.stderr


def test_a_link_dir_that_cannot_be_made_is_named(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("")
    bad = tmp_path / "file" / "robot"
    result = subprocess.run([sys.executable, "-m", "tools.cli.serve_emulator", "--config", "arm",
                             "--no-physics", "--link-dir", str(bad)],
                            cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 1
    assert str(bad) in result.stderr and "Not a directory" in result.stderr


def test_a_link_dir_a_running_emulator_holds_is_refused_and_left_alone(tmp_path: Path) -> None:
    """A second emulator on the same --link-dir neither replaces the first one's links and
    control socket nor removes them when it exits: it refuses, naming the first's pid."""
    links = tmp_path / "robot"
    with running_emulator("--config", "arm", "--no-physics", "--link-dir", str(links)) as info:
        before = {name: os.readlink(links / name) for name in ("arm",)}
        second = subprocess.run([sys.executable, "-m", "tools.cli.serve_emulator", "--config", "arm",
                                 "--no-physics", "--link-dir", str(links)],
                                cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert second.returncode == 1 and second.stdout == ""
        assert "belongs to a running emulator" in second.stderr
        assert f"pid {info['process'].pid}" in second.stderr
        assert second.stderr.count("\n") == 1
        assert {name: os.readlink(links / name) for name in ("arm",)} == before
        assert status(info)["ok"]  # the first one's control socket still answers
    assert list(links.iterdir()) == []  # and the first cleans up after itself


def test_links_the_emulator_did_not_make_are_never_removed(tmp_path: Path) -> None:
    links = tmp_path / "robot"
    with running_emulator("--config", "arm", "--no-physics", "--link-dir", str(links)) as info:
        (links / "mine").symlink_to(info["arm"])  # the user's own link to the same pty
    assert (links / "mine").is_symlink()


def test_a_link_dir_naming_a_file_says_so(tmp_path: Path) -> None:
    (tmp_path / "robot").write_text("")
    result = subprocess.run([sys.executable, "-m", "tools.cli.serve_emulator", "--config", "arm",
                             "--no-physics", "--link-dir", str(tmp_path / "robot")],
                            cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 1 and result.stdout == ""
    assert "is a file, not a directory" in result.stderr and "File exists" not in result.stderr
