"""hil-bench campaign reports: pass rates per fault class and per parameter value, exact in
the Markdown, with their bar charts; a ``campaign.vary`` run reported per parameter."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tools.hil_bench.campaign import expand, run_jobs
from tools.hil_bench.report import (
    FAULT_RATES_PNG,
    NO_FAULT,
    PARAMETER_RATES_PNG,
    pass_rates_by_fault,
    pass_rates_by_parameter,
    summary_markdown,
    write_report,
)
from tools.hil_bench.scenario import scenario_dir


def _result(scenario: str, seed: int, passed: bool, faults: list[str],
            overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """A hand-made run result: what the report reads of one."""
    return {"scenario": scenario, "source": f"{scenario}.toml", "seed": seed, "config": "hand",
            "faults": faults, "passed": passed,
            "assertions": [{"id": "a0", "check": "action_ok", "passed": passed,
                            "message": "" if passed else "it failed", "measured": {}}],
            "actions": {}, "timeline": [], "sim_s": 0.5, "wall_s": 0.1,
            "overrides": overrides or {}}


#: Three runs of a loss campaign at two rates (one fails), a run with two fault classes,
#: one with none.
RESULTS = [
    _result("loss", 0, True, ["bus_frame_loss"], {"faults.0.params.probability": 0.01}),
    _result("loss", 1, True, ["bus_frame_loss"], {"faults.0.params.probability": 0.01}),
    _result("loss", 0, False, ["bus_frame_loss"], {"faults.0.params.probability": 0.5}),
    _result("loss", 1, True, ["bus_frame_loss"], {"faults.0.params.probability": 0.5}),
    _result("pair", 0, False, ["break_away", "bus_frame_loss"]),
    _result("quiet", 0, True, []),
]


def test_a_run_counts_for_every_fault_class_of_its_plan() -> None:
    rates = {p.label: (p.runs, p.passed) for p in pass_rates_by_fault(RESULTS)}
    assert rates == {"break_away": (1, 0), "bus_frame_loss": (5, 3), NO_FAULT: (1, 1)}


def test_results_without_a_faults_list_count_the_faults_their_timeline_shows() -> None:
    old = _result("old", 0, False, [])
    del old["faults"]
    old["timeline"] = [{"fault": "line_cut", "action": "apply"},
                       {"fault": "line_cut", "action": "clear"}]
    assert [(p.label, p.runs, p.passed) for p in pass_rates_by_fault([old])] \
        == [("line_cut", 1, 0)]


def test_pass_rates_per_parameter_value_are_exact_and_ordered_by_value() -> None:
    rates = [(p.scenario, p.key, p.value, p.runs, p.passed)
             for p in pass_rates_by_parameter(RESULTS)]
    assert rates == [("loss", "faults.0.params.probability", 0.01, 2, 2),
                     ("loss", "faults.0.params.probability", 0.5, 2, 1)]


def test_the_summary_opens_with_the_rate_tables() -> None:
    text = summary_markdown(RESULTS)
    assert "4 of 6 runs passed." in text
    assert "| bus_frame_loss | 5 | 3 | 60.0 % |" in text
    assert "| break_away | 1 | 0 | 0.0 % |" in text
    assert f"| {NO_FAULT} | 1 | 1 | 100.0 % |" in text
    assert "| loss | `faults.0.params.probability` | 0.01 | 2 | 2 | 100.0 % |" in text
    assert "| loss | `faults.0.params.probability` | 0.5 | 2 | 1 | 50.0 % |" in text
    # the rates come before the per-run table and the failed assertions
    assert text.index("## Pass rate by fault class") < text.index("## Pass rate by parameter") \
        < text.index("## Runs") < text.index("## Failed assertions")
    assert FAULT_RATES_PNG not in text  # charts only referenced where they are written


def test_no_overrides_no_parameter_table_nor_chart(tmp_path: Path) -> None:
    plain = [r for r in RESULTS if not r["overrides"]]
    assert "## Pass rate by parameter" not in summary_markdown(plain)
    written = write_report(plain, tmp_path)
    assert tmp_path / FAULT_RATES_PNG in written
    assert not (tmp_path / PARAMETER_RATES_PNG).exists()


def test_the_report_writes_and_references_both_charts(tmp_path: Path) -> None:
    written = write_report(RESULTS, tmp_path)
    for name in (FAULT_RATES_PNG, PARAMETER_RATES_PNG):
        assert tmp_path / name in written
        assert (tmp_path / name).read_bytes()[:4] == b"\x89PNG"
    text = (tmp_path / "summary.md").read_text()
    assert f"]({FAULT_RATES_PNG})" in text and f"]({PARAMETER_RATES_PNG})" in text


def test_a_vary_campaign_is_reported_per_parameter_value(tmp_path: Path) -> None:
    """A glitch within the phalanges' 2 ms hold-up is ridden through; one beyond it reboots
    them, and the scenario's ``node_state`` assertion fails: 1 of 1 and 0 of 1."""
    path = tmp_path / "vary.toml"
    text = (scenario_dir() / "tendon_glitch_short.toml").read_text()
    head, sep, rest = text.partition("[[faults]]")
    path.write_text(head + '[campaign]\nseeds = [6]\n'
                    'vary = { "faults.0.params.duration_us" = [8000, 1500] }\n' + sep + rest)
    results = run_jobs(expand([path]))
    assert [r["faults"] for r in results] == [["tendon_glitch"], ["tendon_glitch"]]
    write_report(results, tmp_path / "report")
    summary = (tmp_path / "report" / "summary.md").read_text()
    assert "| tendon_glitch | 2 | 1 | 50.0 % |" in summary
    key = "`faults.0.params.duration_us`"
    assert f"| tendon_glitch_short | {key} | 1500 | 1 | 1 | 100.0 % |" in summary
    assert f"| tendon_glitch_short | {key} | 8000 | 1 | 0 | 0.0 % |" in summary
    assert summary.index("| 1500 |") < summary.index("| 8000 |")
    assert (tmp_path / "report" / PARAMETER_RATES_PNG).exists()
