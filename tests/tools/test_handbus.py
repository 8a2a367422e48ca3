"""Tests of the ``handbus`` capture decoder/encoder, in-process and as a console script."""

from __future__ import annotations

import contextlib
import io
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from protocol.framing import encode_frame
from tools.cli import handbus
from tools.cli.mcap_capture import MCAP_MAGIC
from tools.cli.values import FieldValueError, build_fields, parse_value

# Golden frames written by hand (CRCs from the bitwise reference in test_framing.py).
PING_HEX = "420a000001612d"
PING = bytes.fromhex(PING_HEX)
HW_REPLY = bytes.fromhex("420004" "00fa4100efbe" "317f")
POWER_ON = bytes.fromhex("420a01001e01" "17e1")
POWER_ON_BAD_CRC = POWER_ON[:-1] + bytes([POWER_ON[-1] ^ 0x01])
STATUS_REPLY = encode_frame(0, 0x21, bytes(range(148)))
GARBAGE = b"\x00\xff\x13\x37"

REPO = Path(__file__).resolve().parents[2]


def run_main(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = handbus.main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def json_lines(text: str) -> list[dict[str, Any]]:
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def capture() -> bytes:
    return GARBAGE + PING + HW_REPLY + POWER_ON_BAD_CRC + GARBAGE + STATUS_REPLY + POWER_ON


def check_capture_output(out: str) -> None:
    records = json_lines(out)
    *frames, summary = records
    assert [(r["name"], r["crc_ok"]) for r in frames] == [
        ("ping", True),
        ("hw_version", True),
        (None, False),
        ("fmcb.status", True),
        ("fmcb.phalange_power", True),
    ]
    ping, hw, bad, status, power = frames
    assert (ping["offset"], ping["addr"], ping["type"], ping["direction"]) == (4, 10, 1, "request")
    assert ping["fields"] == {}
    assert hw["fields"] == {"version": 0xBEEF0041}
    assert hw["direction"] == "reply"
    assert (bad["offset"], bad["addr"], bad["type"], bad["payload"]) == (22, 10, 0x1E, "01")
    assert bad["fields"] is None
    assert status["length"] == 148
    assert status["fields"]["pp_time"] == int.from_bytes(bytes([0, 1, 2, 3]), "little")
    assert status["fields"]["hall_pos"][0] == int.from_bytes(bytes(range(128, 132)), "little", signed=True)
    assert power["fields"] == {"on": 1}
    counters = summary["summary"]
    assert counters["frames"] == 4
    assert counters["crc_failures"] == 1
    assert counters["bytes_in"] == len(capture())
    assert counters["bytes_discarded"] == 2 * len(GARBAGE) + len(POWER_ON_BAD_CRC)
    assert set(counters) >= {"frames", "crc_failures", "length_errors", "resyncs",
                             "bytes_discarded", "gap_discards", "truncated"}


def test_decode_capture(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "capture.bin"
    path.write_bytes(capture())
    code, out, err = run_main(["decode", str(path)], capsys)
    assert code == 0
    assert err == ""
    check_capture_output(out)


@pytest.mark.slow
def test_decode_capture_as_a_console_script(tmp_path: Path) -> None:
    path = tmp_path / "capture.bin"
    path.write_bytes(capture())
    script = Path(sys.executable).with_name("handbus")
    cmd = [str(script)] if script.exists() else [sys.executable, "-m", "tools.cli.handbus"]
    proc = subprocess.run(
        [*cmd, "decode", str(path)], capture_output=True, text=True, cwd=REPO, timeout=60,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    assert proc.returncode == 0, proc.stderr
    check_capture_output(proc.stdout)
    # standard input works too, via python -m
    piped = subprocess.run(
        [sys.executable, "-m", "tools.cli.handbus", "decode", "-"], input=capture(),
        capture_output=True, cwd=REPO, timeout=60,
    )
    assert piped.returncode == 0
    check_capture_output(piped.stdout.decode())


def test_decode_with_node_hint(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "c.bin"
    path.write_bytes(encode_frame(10, 0x21, b""))
    _, out, _ = run_main(["decode", str(path)], capsys)
    assert json_lines(out)[0]["name"] == "fmcb.status"
    _, out, _ = run_main(["decode", "--node", "palm", str(path)], capsys)
    assert json_lines(out)[0]["name"] == "palm.state"


def test_reply_named_after_its_request(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # 12 bytes to the host, type 0x10: fmcb.imu or f2/f3 IMU-like; the request names it.
    path = tmp_path / "c.bin"
    path.write_bytes(encode_frame(10, 0x10, b"") + encode_frame(0, 0x10, bytes(64)))
    _, out, _ = run_main(["decode", str(path)], capsys)
    names = [r.get("name") for r in json_lines(out)[:-1]]
    assert names == ["fmcb.imu", "palm.tactile"]


def test_unknown_type_prints_payload(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "c.bin"
    path.write_bytes(encode_frame(10, 0xEE, b"\xab"))
    _, out, _ = run_main(["decode", str(path)], capsys)
    record = json_lines(out)[0]
    assert record["name"] is None and record["crc_ok"] is True and record["payload"] == "ab"


def test_undecodable_payload_reports_the_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "c.bin"
    path.write_bytes(encode_frame(0, 0x21, bytes(99)))
    code, out, _ = run_main(["decode", str(path)], capsys)
    assert code == 0
    record = json_lines(out)[0]
    assert record["fields"] is None
    assert record["error"]


def test_hex_input_with_comments(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "capture.txt"
    path.write_text(
        "# a capture from the bench\n"
        "42 0a 00 00 01 61 2d   # ping to the fmcb\n"
        "\n"
        "0x42,0x00:04 00 fa  41 00 ef be 31 7f\n"
        "ff ff  # garbage\n"
        "420a01001e0117e1\n"
    )
    code, out, _ = run_main(["decode", "--hex", str(path)], capsys)
    assert code == 0
    records = json_lines(out)
    assert [r.get("name") for r in records[:-1]] == ["ping", "hw_version", "fmcb.phalange_power"]
    assert [r["offset"] for r in records[:-1]] == [0, 7, 20]
    assert records[-1]["summary"]["bytes_discarded"] == 2


@pytest.mark.parametrize("text", ["42 0a 0", "42 zz", "0x4"])
def test_bad_hex_input(tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str) -> None:
    path = tmp_path / "bad.txt"
    path.write_text(text)
    code, out, err = run_main(["decode", "--hex", str(path)], capsys)
    assert code == 2
    assert "line 1" in err and "not hex" in err
    assert out == ""


def test_non_ascii_hex_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "bad.txt"
    path.write_bytes(b"42 \xff")
    code, _, err = run_main(["decode", "--hex", str(path)], capsys)
    assert code == 2
    assert "not hex text" in err


def test_missing_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "nope.bin"
    code, out, err = run_main(["decode", str(missing)], capsys)
    assert code == 2
    assert out == ""
    assert err.startswith("handbus: error: cannot read")
    assert str(missing) in err
    assert "No such file" in err
    assert "Traceback" not in err


def test_an_empty_capture_is_an_error_not_an_empty_success(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "empty.bin"
    path.write_bytes(b"")
    code, out, err = run_main(["decode", str(path)], capsys)
    assert code == 2 and out == ""
    assert err == f"handbus: error: {path} is empty (0 bytes): nothing to decode\n"


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=400), st.booleans())
def test_garbage_never_crashes(data: bytes, sprinkle_frames: bool) -> None:
    assume(not data.startswith(MCAP_MAGIC))  # read as a recording (test_handbus_mcap.py)
    assume(data or sprinkle_frames)  # an empty file is an error (test_an_empty_capture_…)
    if sprinkle_frames:
        data = data[: len(data) // 2] + PING + data[len(data) // 2 :]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "garbage.bin"
        path.write_bytes(data)
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = handbus.main(["decode", str(path)])
    assert code == 0
    assert err.getvalue() == ""
    *records, summary = json_lines(out.getvalue())
    counters = summary["summary"]
    assert counters["bytes_in"] == len(data)
    assert counters["frames"] == sum(1 for r in records if r["crc_ok"])
    if sprinkle_frames:
        assert counters["frames"] >= 1


def reference_lines(data: bytes, node: str | None = None) -> str:
    """What ``handbus decode`` printed before it was made fast: a dict per frame, deep-copied
    by ``jsonable`` and printed by ``json.dumps`` (the oracle of the fast writer)."""
    from benchmarks.bench_handbus import decode_per_frame_dumps
    from protocol.stream import StreamDecoder, decode_all
    decoder = StreamDecoder(gap_s=None, report_rejected=True)
    frames = decoder.feed(data) + decoder.flush()
    assert [f for f in frames if f.crc_ok] == decode_all(data)
    out = io.StringIO()
    decode_per_frame_dumps(data, out, node)
    return out.getvalue()


def fast_lines(data: bytes, node: str | None = None) -> str:
    out = io.StringIO()
    handbus.decode_hand(data, node, handbus.DEFAULT_MAX_PAYLOAD, out)
    return out.getvalue()


def test_fast_writer_prints_what_the_reference_does(monkeypatch: pytest.MonkeyPatch) -> None:
    from benchmarks.capture import make_capture

    data = make_capture(60_000, seed=5, noise=True)
    expected = reference_lines(data)
    monkeypatch.setattr(handbus, "CHUNK", 997)  # frames straddle the chunks fed
    assert fast_lines(data) == expected
    assert fast_lines(data, "palm") == reference_lines(data, "palm")


_FRAME_PARTS = st.tuples(st.sampled_from([0, 1, 2, 10, 0xFF, 7]),
                         st.sampled_from([0x01, 0x10, 0x12, 0x1D, 0x21, 0x22, 0x60, 0x61, 0x62,
                                          0x64, 0x07, 0x0A, 0x0D, 0xEE]),
                         st.binary(max_size=160))


@settings(max_examples=60, deadline=None)
@given(st.lists(_FRAME_PARTS, max_size=12), st.sampled_from([None, "palm", "f2", "bootloader"]))
def test_fast_writer_matches_the_reference_on_any_frames(
        parts: list[tuple[int, int, bytes]], node: str | None) -> None:
    # Frames of every kind, twice each so the line cache answers the second time.
    data = b"".join(encode_frame(a, t, p) for a, t, p in parts) * 2
    assert fast_lines(data, node) == reference_lines(data, node)


def test_fields_of_adapted_declarations_go_through_jsonable(
        monkeypatch: pytest.MonkeyPatch) -> None:
    import construct as c

    assert handbus._plain_declaration(c.Struct("a" / c.Int8ul, "b" / c.GreedyBytes))
    assert not handbus._plain_declaration(c.Struct("a" / c.Enum(c.Int8ul, on=1)))
    assert not handbus._plain_declaration(c.Struct("s" / c.Switch(c.this.a, {1: c.Flag})))
    seen: list[Any] = []

    def spy(value: Any) -> Any:
        seen.append(value)
        return {"on": "ON"}

    monkeypatch.setattr(handbus, "jsonable", spy)
    monkeypatch.setitem(handbus._coded_cache, ("fmcb.phalange_power", "request"),
                        frozenset({"*"}))  # as for a record that is not a Struct
    line = fast_lines(POWER_ON + encode_frame(10, 0x1E, b"\x02")).splitlines()[0]
    assert seen == [{"on": 1}, {"on": 2}]
    assert json.loads(line)["fields"] == {"on": "ON"}


def test_only_the_coded_fields_of_a_record_go_through_jsonable(
        monkeypatch: pytest.MonkeyPatch) -> None:
    from protocol.messages import CATALOGUE
    from protocol.messages.palm import RouteStatus
    from protocol.topology import Hop

    # palm.route reply: finger u8, hop (Hop), status (RouteStatus), frame (greedy bytes)
    assert handbus._coded_keys(CATALOGUE["palm.route"], "reply") == {"hop", "status"}
    assert handbus._coded_keys(CATALOGUE["fmcb.status"], "reply") == frozenset()
    seen: list[Any] = []
    real = handbus.jsonable

    def spy(value: Any) -> Any:
        seen.append(value)
        return real(value)

    monkeypatch.setattr(handbus, "jsonable", spy)
    line = fast_lines(encode_frame(0, 0x62, bytes([1, 2, 1, 0xAB])), node="palm")
    assert seen == [Hop.F3, RouteStatus.NO_REPLY]
    assert json.loads(line.splitlines()[0])["fields"] == {
        "finger": 1, "hop": "F3", "status": "NO_REPLY", "frame": "ab"}


class _FakeTerminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_bar_only_on_a_terminal(tmp_path: Path,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "capture.bin"
    path.write_bytes(capture() * 50)
    for stderr, shown in ((io.StringIO(), False), (_FakeTerminal(), True)):
        out = io.StringIO()
        monkeypatch.setattr(sys, "stderr", stderr)
        monkeypatch.setattr(handbus, "CHUNK", 64)
        with contextlib.redirect_stdout(out):
            assert handbus.main(["decode", str(path)]) == 0
        text = stderr.getvalue()
        assert bool(text) == shown
        if shown:
            assert text.startswith("\rhandbus: decoding [") and text.endswith("\n")
            assert "100%" in text.splitlines()[-1]
        assert json_lines(out.getvalue())[-1]["summary"]["frames"] == 4 * 50


def test_progress_bar_absent_for_a_console_script_with_stderr_piped(tmp_path: Path) -> None:
    path = tmp_path / "capture.bin"
    path.write_bytes(capture())
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    result = subprocess.run([sys.executable, "-m", "tools.cli.handbus", "decode", str(path)],
                            capture_output=True, env=env, check=False)
    assert (result.returncode, result.stderr) == (0, b"")


# --- encode -------------------------------------------------------------------------------------


def test_encode_ping_golden(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_main(["encode", "ping", "--addr", "10"], capsys)
    assert (code, out, err) == (0, PING_HEX + "\n", "")
    code, out, _ = run_main(["encode", "ping", "--addr", "0x0a", "--spaced"], capsys)
    assert out == "42 0a 00 00 01 61 2d\n"


def test_encode_field_and_reply(capsys: pytest.CaptureFixture[str]) -> None:
    _, out, _ = run_main(["encode", "fmcb.phalange_power", "on=1", "--addr", "10"], capsys)
    assert out.strip() == POWER_ON.hex()
    _, out, _ = run_main(["encode", "hw_version", "--reply", "version=0xBEEF0041"], capsys)
    assert out.strip() == HW_REPLY.hex()


def test_encode_fields_after_options(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_main(["encode", "fmcb.phalange_power", "--addr", "10", "on=1"], capsys)
    assert (code, out.strip(), err) == (0, POWER_ON.hex(), "")


@pytest.mark.parametrize(("value", "says"), [
    ("nan", "args.target[0]: nan is not a finite number"),
    ("1e400", "args.target[0]: inf is not a finite number"),
    ("-1e39", "args.target[0]: -1e+39 is outside the float32 range")])
def test_encode_refuses_a_float_field_that_is_not_finite_or_does_not_fit(
        value: str, says: str, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_main(["encode", "fmcb.control", "mode=2",
                               f"args.target={value},0.5,0.3", "--addr", "10"], capsys)
    assert (code, out) == (2, "") and says in err


def test_encode_control_with_nested_args(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_main(
        ["encode", "fmcb.control", "mode=2", "args.target=0.5,-1,2", "--addr", "10"], capsys
    )
    assert code == 0, err
    # payload: mode 2, then 0.5, -1.0, 2.0 as float32 LE (0x3F000000, 0xBF800000, 0x40000000)
    wire = bytes.fromhex(out.strip())
    assert wire[:5] == bytes.fromhex("420a0d001d")
    assert wire[5:-2] == bytes.fromhex("02" "0000003f" "000080bf" "00000040")
    assert wire == encode_frame(10, 0x1D, wire[5:-2])
    code, out, _ = run_main(
        ["encode", "fmcb.control", "mode=4", "args.target=0.1,0.2,0.3",
         "args.max_effort=10,20,30", "--addr", "10"], capsys,
    )
    assert code == 0
    assert bytes.fromhex(out.strip())[-5:-2] == bytes([10, 20, 30])
    code, out, _ = run_main(["encode", "fmcb.control", "mode=0", "--addr", "10"], capsys)
    assert bytes.fromhex(out.strip())[2:6] == bytes.fromhex("01001d00")


def test_coded_fields_decode_to_names_that_encode_back(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # palm.route reply: finger 1, hop 2, status 1 (NO_REPLY); then status 0x99 (no name).
    path = tmp_path / "c.bin"
    path.write_bytes(encode_frame(0, 0x62, bytes([1, 2, 1])) +
                     encode_frame(0, 0x62, bytes([1, 2, 0x99])))
    _, out, _ = run_main(["decode", "--node", "palm", str(path)], capsys)
    known, unknown = json_lines(out)[:2]
    assert known["fields"] == {"finger": 1, "hop": "F3", "status": "NO_REPLY", "frame": ""}
    assert unknown["fields"]["status"] == 0x99
    code, out, err = run_main(["encode", "palm.route", "--reply", "finger=1", "hop=2",
                               "status=NO_REPLY", "frame="], capsys)
    assert (code, err) == (0, "")
    assert bytes.fromhex(out.strip()) == encode_frame(0, 0x62, bytes([1, 2, 1]))


def test_encode_a_code_by_name(capsys: pytest.CaptureFixture[str]) -> None:
    by_number = run_main(["encode", "fmcb.control", "mode=3", "args.target=1000,-1,0",
                          "--addr", "10"], capsys)
    by_name = run_main(["encode", "fmcb.control", "mode=joint_fixed", "args.target=1000,-1,0",
                        "--addr", "10"], capsys)
    assert by_name == by_number
    assert bytes.fromhex(by_name[1].strip())[5:-2] == bytes.fromhex("03" "e803" "ffff" "0000")
    code, _, err = run_main(["encode", "fmcb.control", "mode=sideways", "--addr", "10"], capsys)
    assert code == 2 and "ControlMode" in err


def test_encode_bytes_and_text_fields(capsys: pytest.CaptureFixture[str]) -> None:
    _, out, _ = run_main(
        ["encode", "fmcb.tunnel", "max_ms=5", "data=420a", "--addr", "10"], capsys
    )
    assert bytes.fromhex(out.strip())[5:-2] == bytes.fromhex("0200" "0500" "420a")
    _, out, _ = run_main(["encode", "fmcb.param_name", "--reply", "name=123"], capsys)
    assert bytes.fromhex(out.strip())[5:-2] == b"\x03123"


def test_encode_unknown_name_suggests(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_main(["encode", "fmcb.stats", "--addr", "10"], capsys)
    assert code == 2
    assert out == ""
    assert "no message called 'fmcb.stats'" in err
    assert "did you mean" in err and "fmcb.status" in err
    code, _, err = run_main(["encode", "zzzzzzzz", "--addr", "10"], capsys)
    assert code == 2
    assert "handbus list" in err


@pytest.mark.parametrize(
    ("argv", "fragment"),
    [
        (["encode", "ping"], "--addr is required"),
        (["encode", "fmcb.control", "mode=9", "--addr", "10"],
         "fmcb.control: args is declared only for 0, 1, 2, 3, 4, 5, not for 9"),
        (["encode", "fmcb.phalange_power", "--addr", "10"],
         "fmcb.phalange_power: missing field 'on' (fields: on)"),
        (["encode", "fmcb.control", "mode=2", "targt=1,2,3", "--addr", "10"],
         "fmcb.control: unknown field 'targt' (fields: mode, args)"),
        (["encode", "fmcb.control", "mode=2", "args.targt=1,2,3", "--addr", "10"],
         "fmcb.control: unknown field 'args.targt' (fields of args: target)"),
        (["encode", "fmcb.control", "mode=0", "args.target=1", "--addr", "10"],
         "fmcb.control: unknown field 'args.target' (args has no fields)"),
        (["encode", "fmcb.control", "mode=2", "args.target=0.1,0.2", "--addr", "10"],
         "args.target: expected 3 numbers, got 2"),
        (["encode", "fmcb.control", "mode=2", "args.target=0.1,0.2,x", "--addr", "10"],
         "args.target[2]: expected a number, got 'x'"),
        (["encode", "fmcb.phalange_power", "on=256", "--addr", "10"], "on: 256 is outside 0..255"),
        # coded fields: a name is checked against the members, a number against the field,
        # and a Switch keyed by a code given by name checks that case's arguments
        (["encode", "fmcb.control", "mode=sideways", "--addr", "10"],
         "mode: 'sideways' is not a ControlMode (idle, motor, joint, joint_fixed, "
         "joint_effort, relative, or its number)"),
        (["encode", "fmcb.control", "mode=256", "--addr", "10"], "mode: 256 is outside 0..255"),
        (["encode", "fmcb.control", "mode=joint", "args.target=0.1,0.2", "--addr", "10"],
         "args.target: expected 3 numbers, got 2"),
        (["encode", "fmcb.control", "mode=JOINT", "args.targt=1,2,3", "--addr", "10"],
         "fmcb.control: unknown field 'args.targt' (fields of args: target)"),
        (["encode", "fmcb.phalange_power", "on=1.5", "--addr", "10"],
         "on: expected an integer, got 1.5"),
        (["encode", "fmcb.param_set", "index=1", "value=0102", "--addr", "10"],
         "value: expected 4 bytes, got 2"),
        (["encode", "fmcb.tunnel", "max_ms=1", "data=" + "00" * 513, "--addr", "10"],
         "fmcb.tunnel: length=513 fails the declared check (this['length'] <= 512)"),
        (["encode", "txn", "seq=1", "inner_type=1", "inner=" + "00" * 1100, "--addr", "10"],
         "the txn request payload is 1102 bytes; a decoder reading at most 1017 bytes"),
        (["encode", "txn", "seq=1", "inner_type=1", "inner=" + "00" * 20, "--addr", "10",
          "--max-payload", "16"], "payload is 22 bytes; a decoder reading at most 16 bytes"),
        (["encode", "ping", "--addr", "-1"], "address -1 is outside 0..255"),
        (["encode", "fmcb.phalange_power", "on", "--addr", "10"], "not field=value"),
        (["encode", "fmcb.tunnel", "data=xyz", "max_ms=1", "--addr", "10"], "not hex bytes"),
        (["encode", "palm.finger_event", "--addr", "10"], "has no request"),
        (["encode", "fmcb.control", "--reply"], "has no reply"),
        (["encode", "ping", "--addr", "300"], "address 300"),
    ],
)
def test_encode_errors(argv: list[str], fragment: str, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_main(argv, capsys)
    assert code == 2
    assert out == ""
    assert err.startswith("handbus: error:")
    assert fragment in err
    assert "Traceback" not in err and err.count("\n") == 1


def test_encode_at_the_payload_limit_is_accepted(capsys: pytest.CaptureFixture[str]) -> None:
    # txn: seq u8, inner_type u8, then the inner payload: 2 + 1015 = 1017 bytes exactly.
    code, out, err = run_main(
        ["encode", "txn", "seq=1", "inner_type=1", "inner=" + "ab" * 1015, "--addr", "10"], capsys)
    assert (code, err) == (0, "")
    assert bytes.fromhex(out.strip())[2:4] == (1017).to_bytes(2, "little")


def test_unrecognised_arguments_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        handbus.main(["encode", "ping", "--addr", "10", "--bogus"])
    assert info.value.code == 2
    with pytest.raises(SystemExit) as info:
        handbus.main(["decode", "a", "b"])
    assert info.value.code == 2
    capsys.readouterr()


def test_encode_round_trips_through_decode(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, out, _ = run_main(["encode", "fmcb.set_home", "offset=1,-2,3", "--addr", "10"], capsys)
    path = tmp_path / "x.txt"
    path.write_text(out)
    _, out, _ = run_main(["decode", "--hex", str(path)], capsys)
    record = json_lines(out)[0]
    assert (record["name"], record["fields"]) == ("fmcb.set_home", {"offset": [1, -2, 3]})


# --- list ---------------------------------------------------------------------------------------


def test_list(capsys: pytest.CaptureFixture[str]) -> None:
    from protocol.messages import CATALOGUE

    code, out, _ = run_main(["list"], capsys)
    assert code == 0
    lines = out.splitlines()
    assert len(lines) == len(CATALOGUE)
    first = lines[0].split()
    assert first[:3] == ["ping", "common", "0x01"]
    status = next(line for line in lines if line.startswith("fmcb.status "))
    assert "0x21" in status and "fmcb" in status
    identify = next(line for line in lines if line.startswith("identify "))
    assert "0x60" in identify and identify.endswith("(new)")


# --- helpers ------------------------------------------------------------------------------------


def test_jsonable() -> None:
    assert handbus.jsonable({"a": b"\x01\xff", "b": [bytearray(b"\x02"), (1, 2)]}) == {
        "a": "01ff", "b": ["02", [1, 2]],
    }


def test_cli_values() -> None:
    from protocol.messages import CATALOGUE

    assert parse_value("0x2a") == 42
    assert parse_value("1,2,3") == [1, 2, 3]
    assert parse_value("1.5") == 1.5
    assert parse_value("abc") == "abc"
    con = CATALOGUE["fmcb.control"].request
    assert build_fields(con, ["mode=0"]) == {"mode": 0, "args": {}}
    assert build_fields(con, ["mode=2", "args.target=1,2,3"]) == {
        "mode": 2, "args": {"target": [1, 2, 3]},
    }
    assert build_fields(CATALOGUE["fmcb.set_home"].request, ["offset=7"]) == {"offset": [7]}
    assert build_fields(CATALOGUE["fmcb.param_set"].request, ["value=0x0000803f"]) == {
        "value": bytes.fromhex("0000803f"),
    }
    with pytest.raises(FieldValueError):
        build_fields(con, ["mode"])
