"""The robot CLIs share one --port/--json/--timeout/--priority and one error-to-exit-status
mapping."""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Callable

import pytest

from host.errors import (
    HomingError,
    NodeError,
    ReplyTimeout,
    RouteError,
    TransportError,
    UsageError,
)
from host.hand.facade import Hand
from host.hand.session import LINK_BUDGET_S, HandSession, Timeouts
from host.scheduling import RT_PRIORITY, Scheduling, current, rtprio_limit
from host.transports.base import open_transport, schemes
from protocol.messages.common import TxnStatus
from tools.cli import armctl, flash_all_fingers, handctl
from tools.cli import common as cli_common

CLIS: dict[str, Callable[[list[str]], int]] = {
    "handctl": handctl.main, "armctl": armctl.main, "flash-all-fingers": flash_all_fingers.main}
#: A command each CLI accepts after the common options.
COMMAND = {"handctl": ["status"], "armctl": ["status"], "flash-all-fingers": []}


@pytest.mark.parametrize("name", sorted(CLIS))
def test_every_cli_has_the_common_options_and_lists_the_schemes(
        name: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert CLIS[name](["--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    for option in ("--port P", "--json", "--timeout S"):
        assert option in text
    assert ", ".join(schemes()) in text.replace("\n", " ")


@pytest.mark.parametrize("name", sorted(CLIS))
def test_a_bad_command_line_is_exit_2(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert CLIS[name](["--port", "loop://", "--timeout", "0", *COMMAND[name]]) == 2
    assert "give a time > 0" in capsys.readouterr().err
    assert CLIS[name](["--bogus"]) == 2


@pytest.mark.parametrize("name", ["handctl", "armctl"])
def test_a_missing_port_is_exit_1_with_advice(
        name: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert CLIS[name](["--port", "/dev/no-such-robot", *COMMAND[name]]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"{name}: cannot use /dev/no-such-robot")
    assert "Check the path" in err and "Traceback" not in err


@pytest.mark.parametrize("name", ["handctl", "armctl"])
def test_ctrl_c_is_exit_130(name: str, monkeypatch: pytest.MonkeyPatch,
                            capsys: pytest.CaptureFixture[str]) -> None:
    def interrupted(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr("host.hand.facade.Hand.open", interrupted)
    monkeypatch.setattr("host.arm.facade.Arm.open", interrupted)
    assert CLIS[name](["--port", "loop://", *COMMAND[name]]) == 130
    assert capsys.readouterr().err == f"{name}: interrupted\n"


@pytest.mark.parametrize(("exc", "status", "words"), [
    (UsageError("joint limit"), 2, "prog: error: joint limit"),
    (TransportError("gone"), 1, "Check the path"),
    (ReplyTimeout("no reply to identify"), 1, "--timeout S"),
    (RouteError("route unpowered", status=1, finger=2, hop=0), 1, "route unpowered"),
    (NodeError("refused: busy"), 1, "refused: busy"),
    (HomingError("no index mark on J2", joint="J2"), 1, "homing failed: no index mark"),
    (PermissionError("cannot write run.mcap"), 1, "cannot write run.mcap"),
    (KeyboardInterrupt(), 130, "interrupted"),
])
def test_one_mapping_of_errors_to_exit_statuses(
        exc: BaseException, status: int, words: str,
        capsys: pytest.CaptureFixture[str]) -> None:
    def body() -> int:
        raise exc

    assert cli_common.run("prog", "/dev/ttyX", body) == status
    err = capsys.readouterr().err
    assert err.startswith("prog: ") and words in err


def test_a_clis_own_refusals_count_as_usage_and_hints_end_robot_errors(
        capsys: pytest.CaptureFixture[str]) -> None:
    class Refused(Exception):
        pass

    def refused() -> int:
        raise Refused("wrong board")

    def link_failed() -> int:
        raise TransportError("unplugged")

    assert cli_common.run("prog", "P", refused, usage=(Refused,)) == 2
    assert capsys.readouterr().err == "prog: wrong board\n"
    assert cli_common.run("prog", "P", link_failed, hint="run again to resume") == 1
    assert capsys.readouterr().err.endswith("\nrun again to resume.\n")
    with pytest.raises(Refused):
        cli_common.run("prog", "P", refused)


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    cli_common.add_common_arguments(parser, what="the palm's port")
    return parser.parse_args(list(argv))


@pytest.mark.parametrize(("port", "link_s"), [
    ("emu://hand/palm", 0.030), ("loop://", 0.030), ("/dev/ttyUSB0", 0.100),
    ("./robot/palm?baud=2000000", 0.100), ("serial:///dev/ttyACM0", 0.100),
    ("can://slcan//dev/ttyACM0", 0.100), ("socket://localhost:5000", 0.250),
])
def test_link_budget_defaults_by_link_kind(port: str, link_s: float) -> None:
    assert cli_common.hand_timeouts(_args("--port", port)).link_s == link_s
    assert cli_common.hand_timeouts(_args("--port", port, "--timeout", "0.4")).link_s == 0.4


def test_serial_budgets_cover_a_usb_adapters_latency_timer_both_ways() -> None:
    assert LINK_BUDGET_S["serial"] >= 0.1 and LINK_BUDGET_S["can"] >= 0.1
    assert LINK_BUDGET_S["in-process"] == Timeouts().link_s
    with pytest.raises(UsageError):
        Timeouts.for_url("loop://", 0.0)


def test_sessions_pick_the_budget_of_their_link() -> None:
    with HandSession(open_transport("loop://")) as session:
        assert session.timeouts.link_s == LINK_BUDGET_S["loop"]
    with Hand.open("loop://", timeouts=Timeouts(link_s=0.2)) as hand:
        assert hand.session.timeouts.link_s == 0.2


def test_a_request_a_bootloader_does_not_know_says_to_wait_for_the_application() -> None:
    exc = NodeError("palm refused palm.finger_power: unknown_type",
                    status=TxnStatus.UNKNOWN_TYPE)
    text = cli_common.advice(exc, "./robot/palm", "handctl")
    assert text.startswith("palm refused palm.finger_power: unknown_type")
    assert "bootloader" in text and "handctl --port ./robot/palm ping" in text
    other = NodeError("palm refused palm.poll: bad_payload", status=TxnStatus.BAD_PAYLOAD)
    assert cli_common.advice(other, "./robot/palm", "handctl") == str(other)


def test_output_cut_short_by_its_reader_ends_quietly() -> None:
    """``handctl … | head -1``: the reader closes the pipe; the CLI stops without a word on
    stderr (neither its own nor the interpreter's at exit), status 141 as after SIGPIPE."""
    import subprocess
    import sys

    program = ("from tools.cli import common as cli_common\n"
               "def body():\n"
               "    for k in range(200000):\n"
               "        print('joint', k)\n"
               "    return 0\n"
               "raise SystemExit(cli_common.run('prog', 'P', body))\n")
    proc = subprocess.Popen([sys.executable, "-c", program], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    assert proc.stdout is not None and proc.stderr is not None
    assert proc.stdout.readline() == b"joint 0\n"
    proc.stdout.close()  # as head does after its line
    err = proc.stderr.read()
    assert proc.wait(timeout=60) == cli_common.EXIT_BROKEN_PIPE
    assert err == b""


@pytest.mark.parametrize(("port", "says_baud"), [
    ("/dev/ttyUSB0", True), ("./robot/arm", True), ("can://slcan//dev/ttyACM0", False),
    ("emu://hand/palm", False), ("socket://robot:5000", False)])
def test_a_timeout_names_the_baud_rate_only_where_the_port_has_one(port: str,
                                                                   says_baud: bool) -> None:
    text = cli_common.advice(ReplyTimeout("no reply to identify"), port, "handctl")
    assert ("?baud=N" in text) == says_baud
    assert f"handctl --port {port} ping" in text and "--timeout S" in text


def test_a_timeout_of_ping_itself_does_not_say_try_ping() -> None:
    exc = ReplyTimeout("no reply to identify")
    assert "armctl --port ./robot/arm ping" in cli_common.advice(exc, "./robot/arm", "armctl",
                                                                  "status")
    text = cli_common.advice(exc, "./robot/arm", "armctl", "ping")
    assert "ping`" not in text and "power and cabling" in text


def _scheduling_seen(argv: list[str]) -> tuple[int, Scheduling]:
    """Run a command line of the common options with a body that records the scheduling
    its thread has; the exit status and what it saw."""
    parser = argparse.ArgumentParser(prog="probe")
    cli_common.add_common_arguments(parser, what="a port")
    seen: list[Scheduling] = []

    def body(args: argparse.Namespace) -> int:
        seen.append(current())
        return 0

    return cli_common.run_cli(parser, argv, body), seen[0]


@pytest.mark.skipif(not (os.geteuid() == 0 or rtprio_limit() > 0),
                    reason="real-time scheduling is not allowed here")
@pytest.mark.parametrize("port", ["/dev/pts/99", "can://slcan//dev/ttyACM0"])
def test_a_command_on_a_real_link_runs_real_time_and_gives_it_back(port: str) -> None:
    before = current()
    if before.realtime:
        pytest.skip("the tests themselves run real-time (started under chrt)")
    status, seen = _scheduling_seen(["--port", port])
    assert status == 0
    assert seen.realtime and seen.policy == "SCHED_RR"
    assert seen.priority < RT_PRIORITY  # below an emulator's pacing thread on the same machine
    assert current() == before  # the thread has its own scheduling back


@pytest.mark.parametrize("argv", [["--port", "emu://arm/arm"],
                                  ["--port", "/dev/pts/99", "--priority", "normal"]])
def test_in_process_links_and_priority_normal_leave_the_scheduling(argv: list[str]) -> None:
    before = current()
    status, seen = _scheduling_seen(argv)
    assert status == 0
    assert seen == before and not seen.realtime


@pytest.mark.parametrize("name", sorted(CLIS))
def test_every_cli_takes_priority_and_refuses_another_word(
        name: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert CLIS[name](["--help"]) == 0
    assert "--priority {realtime,normal}" in " ".join(capsys.readouterr().out.split())
    assert CLIS[name](["--port", "loop://", "--priority", "high", *COMMAND[name]]) == 2
    assert "invalid choice: 'high'" in capsys.readouterr().err


#: A fresh in-process emulator for each: the same state, so the same output.
STATUS_PORT = {"handctl": "emu://hand/palm?name=options-{}", "armctl": "emu://arm/arm?name=options-{}"}


@pytest.mark.parametrize("name", ["handctl", "armctl"])
def test_the_global_options_are_taken_before_or_after_the_sub_command(
        name: str, capsys: pytest.CaptureFixture[str]) -> None:
    """``--port P --json status`` and ``status --port P --json`` print the same; a
    sub-command's own option of the same name (``armctl move --timeout``) keeps its
    meaning after it, and a missing ``--port`` is still a bad command line."""
    outputs = []
    for i, argv in enumerate((["--port", "{}", "--json", "status"],
                              ["status", "--port", "{}", "--json"],
                              ["--json", "status", "--port", "{}"])):
        port = STATUS_PORT[name].format(i)
        assert CLIS[name]([a.replace("{}", port) for a in argv]) == 0
        outputs.append(json.loads(capsys.readouterr().out))
    assert outputs[0] == outputs[1] == outputs[2]
    assert CLIS[name](["status", "--json"]) == 2
    assert capsys.readouterr().err.endswith(
        f"{name}: error: the following arguments are required: --port\n")


def test_a_sub_commands_own_option_keeps_its_meaning_after_it() -> None:
    parser = armctl.make_parser()
    args = parser.parse_args(["move", "--joints", "0,0,0,0,0,0,0", "--timeout", "3",
                              "--port", "loop://", "--view", "--view-port", "9200"])
    assert (args.timeout, args.link_timeout) == (3.0, None)
    assert (args.port, args.view, args.view_port) == ("loop://", True, 9200)
    args = parser.parse_args(["--timeout", "0.5", "status", "--port", "loop://"])
    assert args.link_timeout == 0.5 and not args.view
