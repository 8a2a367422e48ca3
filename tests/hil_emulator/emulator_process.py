"""Run the ``hil-emulator`` command as a user would: a separate process, ports on ptys."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]


#: How long a test waits for something that must happen before it calls it a hang (s of
#: wall time): never a timing bound, which comes from the simulation clock or the
#: emulator's reported lateness.
HANG_GUARD_S = 60.0


@contextmanager
def running_emulator(*args: str, startup_timeout_s: float = 120.0) -> Iterator[dict[str, Any]]:
    """Start ``hil-emulator --stats ARGS``, yield its JSON line (plus ``"process"``), stop it
    with SIGINT and check it exits 0 with nothing more on standard output.

    Without ``--link-dir`` or ``--control`` it is given a control socket in a temporary
    directory, so ``info["control"]`` is always there: :func:`status` reads the simulation
    clock and the lateness so far through it.  After the ``with`` block, ``info["stats"]``
    holds the emulator's own ``--stats`` report (delivery lateness in ms, port counters):
    tests take their wall-clock margins from it instead of assuming an idle machine."""
    with tempfile.TemporaryDirectory(prefix="hil-emulator-") as scratch:
        if "--link-dir" not in args and "--control" not in args:
            args = (*args, "--control", os.path.join(scratch, "control"))
        with _running(args, startup_timeout_s) as info:
            yield info


def status(info: dict[str, Any]) -> dict[str, Any]:
    """The running emulator's ``status`` (control channel): ``t_us``, the simulation clock,
    and its lateness figures so far."""
    return ask(info, "status")


def ask(info: dict[str, Any], op: str) -> dict[str, Any]:
    """The running emulator's answer to the control channel's ``op`` (``status``,
    ``truth``, ``timeline``); an answer that is not ``ok`` is an error."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as client:
        client.settimeout(HANG_GUARD_S)
        client.connect(info["control"])
        client.sendall(json.dumps({"op": op}).encode() + b"\n")
        answer = b""
        while not answer.endswith(b"\n"):
            chunk = client.recv(65536)
            if not chunk:
                raise ConnectionError("the control channel closed without an answer")
            answer += chunk
    reply = dict(json.loads(answer))
    assert reply["ok"], reply
    return reply


class SimulatedDeadline:
    """``seconds`` from now on the running emulator's simulation clock (a busy machine
    slows that clock down; the wall clock only guards against a hang, :data:`HANG_GUARD_S`)."""

    def __init__(self, info: dict[str, Any], seconds: float) -> None:
        self.info = info
        self.seconds = seconds
        self.end_us = status(info)["t_us"] + int(seconds * 1e6)
        self.guard = time.monotonic() + HANG_GUARD_S

    def passed(self) -> bool:
        """True once the simulation clock is past the deadline; a hang is an error."""
        assert time.monotonic() < self.guard, (
            f"{self.seconds} s of simulated time did not pass within {HANG_GUARD_S} s")
        return bool(status(self.info)["t_us"] >= self.end_us)


def wait_simulated(info: dict[str, Any], seconds: float) -> None:
    """Wait until the emulator's simulation clock has advanced ``seconds`` (however long
    that takes on the wall clock of a busy machine, within :data:`HANG_GUARD_S`)."""
    deadline = SimulatedDeadline(info, seconds)
    while not deadline.passed():
        time.sleep(0.02)


@contextmanager
def _running(args: tuple[str, ...], startup_timeout_s: float) -> Iterator[dict[str, Any]]:
    proc = subprocess.Popen([sys.executable, "-m", "tools.cli.serve_emulator", "--stats", *args],
                            cwd=ROOT,
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
        info["stats"] = emulator_stats(err)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def emulator_stats(stderr: str) -> dict[str, Any]:
    """The ``hil-emulator stats: {...}`` line of ``stderr``, parsed (strict JSON: no NaN)."""
    line = next(x for x in stderr.splitlines() if x.startswith("hil-emulator stats:"))
    return dict(json.loads(line.partition(":")[2], parse_constant=_no_constant))


def late_s(stats: dict[str, Any]) -> float:
    """The worst delivery lateness the emulator reported (s); 0 when nothing was late."""
    return max(0.0, (stats["max_ms"] or 0.0) / 1e3)


def _no_constant(name: str) -> float:
    raise ValueError(f"--stats printed {name}, which is not JSON")


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


@dataclass(frozen=True)
class Flood:
    """What :func:`flood_arm_port` saw: ``written`` bytes of junk the pty took, the
    emulator's resident memory growth over the flood (kB), the reply to the ping written
    afterwards and how long it took (s, wall clock), and the emulator's ``--stats``."""

    written: int
    rss_growth_kb: int
    reply: bytes
    answered_s: float
    stats: dict[str, Any]


def rss_kb(pid: int) -> int:
    """Resident memory of process ``pid`` (kB, ``VmRSS``)."""
    text = Path(f"/proc/{pid}/status").read_text()
    return int(next(x for x in text.splitlines() if x.startswith("VmRSS:")).split()[1])


def flood_arm_port(seconds: float = 3.0) -> Flood:
    """Run ``hil-emulator --config arm --no-physics``, write junk to its arm port as fast as
    the pty takes it for ``seconds``, then write a ping to servo 1 and time its reply."""
    import serial

    from protocol.dynamixel import InstructionPacket

    ping = InstructionPacket(1, 0x01, b"").encode()
    with running_emulator("--config", "arm", "--no-physics") as info:
        pid = info["process"].pid
        with serial.Serial(info["arm"], 1_000_000, timeout=0) as port:
            port.write(ping)
            deadline = time.monotonic() + 5.0
            first = b""
            while not first.startswith(b"\xff\xff") and time.monotonic() < deadline:
                first += port.read(64)
                time.sleep(0.01)
            if not first.startswith(b"\xff\xff"):
                raise AssertionError(f"no reply to a ping before the flood: {first!r}")
            rss_before = rss_kb(pid)
            fd = port.fileno()
            os.set_blocking(fd, False)
            junk = b"\x55" * 4096
            written = 0
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                try:
                    written += os.write(fd, junk)
                except BlockingIOError:
                    time.sleep(0.0005)
            os.set_blocking(fd, True)
            port.flush()  # the pty has handed everything over to the emulator
            rss_after = rss_kb(pid)
            time.sleep(0.02)
            port.reset_input_buffer()
            t0 = time.perf_counter()
            port.write(ping)
            got = b""
            while len(got) < 6 and time.perf_counter() - t0 < 2.0:
                got += port.read(64)
            answered_s = time.perf_counter() - t0
    return Flood(written, rss_after - rss_before, got, answered_s, info["stats"])
