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
