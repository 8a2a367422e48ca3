"""The in-process fuzz targets: the corpus passes, properties catch what they should."""

from __future__ import annotations

import pytest

from tools import fuzz_inprocess as fi


@pytest.mark.parametrize("target", sorted(fi.targets()))
def test_corpus_runs_clean(target: str) -> None:
    seeds = fi.corpus(target)
    assert seeds, f"tests/fuzz_corpus/{target} is empty"
    for data in seeds:
        fi.run_one(target, data)


def test_stream_property_finds_frames() -> None:
    from protocol.messages import CATALOGUE

    ping = CATALOGUE["ping"].request_frame(10)
    assert fi.fuzz_stream(b"\x02" + b"\x42\x00" + ping) == 1


@pytest.mark.parametrize("target", ["stream", "handler-fmcb", "handler-bootloader"])
def test_hypothesis_engine_runs(target: str) -> None:
    assert fi.run_hypothesis(target, 60) == 0


def test_list(capsys: pytest.CaptureFixture[str]) -> None:
    assert fi.main(["--list"]) == 0
    assert "handler-palm" in capsys.readouterr().out


@pytest.mark.parametrize("runs", ["0", "-5", "many"])
def test_runs_below_one_are_refused(runs: str, capsys: pytest.CaptureFixture[str]) -> None:
    # libFuzzer takes -runs=0 or less as "forever": the run would never end.
    with pytest.raises(SystemExit) as exc:
        fi.main(["stream", "--runs", runs, "--engine", "hypothesis"])
    assert exc.value.code == 2
    assert "--runs" in capsys.readouterr().err


def test_the_hypothesis_engine_says_what_it_ran(capsys: pytest.CaptureFixture[str]) -> None:
    assert fi.main(["stream", "--runs", "20", "--engine", "hypothesis"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("stream: ") and "inputs, no failure (hypothesis engine)" in out
