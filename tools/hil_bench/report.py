"""Reports of a bench run: a Markdown summary, one JSON result per run, PNG plots around
each fault (matplotlib, Agg: no display needed).

A campaign's summary opens with its pass rates: per fault class (a run counts once for
every fault class of its plan) and, for scenarios with ``campaign.vary`` overrides, per
scenario, override key and value; :data:`FAULT_RATES_PNG` and :data:`PARAMETER_RATES_PNG`
chart them.
"""

from __future__ import annotations

import json
import re
import shlex
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

#: Seconds of trace before and after a fault's start in its plot.
PLOT_BEFORE_S = 0.2
PLOT_AFTER_S = 0.8
#: Plots per run at most.
MAX_PLOTS = 4
#: The bar charts of the pass rates, per fault class and per parameter value.
FAULT_RATES_PNG: Final = "pass_rates_by_fault.png"
PARAMETER_RATES_PNG: Final = "pass_rates_by_parameter.png"
#: The class a run with an empty fault plan counts under.
NO_FAULT: Final = "(no fault)"


@dataclass(frozen=True)
class PassRate:
    """How many of ``runs`` runs of one group passed.  ``scenario``, ``key`` and ``value``
    name a parameter group (empty for a fault class, named by ``label``)."""

    label: str
    runs: int
    passed: int
    scenario: str = ""
    key: str = ""
    value: Any = None

    @property
    def rate(self) -> float:
        """The fraction of runs that passed, 0..1."""
        return self.passed / self.runs if self.runs else 0.0

    def cells(self) -> str:
        """``runs | passed | rate`` as Markdown table cells."""
        return f"{self.runs} | {self.passed} | {100.0 * self.rate:.1f} %"


def fault_classes(result: dict[str, Any]) -> list[str]:
    """The fault classes of a run: its ``faults`` (its plan's), else the faults its timeline
    shows (results written before ``faults`` was recorded); :data:`NO_FAULT` if none."""
    names = result.get("faults")
    if names is None:
        names = list(dict.fromkeys(e["fault"] for e in result.get("timeline", [])))
    return list(names) or [NO_FAULT]


def pass_rates_by_fault(results: Sequence[dict[str, Any]]) -> list[PassRate]:
    """One :class:`PassRate` per fault class, by name; a run counts for each of its classes."""
    counts: dict[str, list[int]] = {}
    for r in results:
        for name in fault_classes(r):
            runs_passed = counts.setdefault(name, [0, 0])
            runs_passed[0] += 1
            runs_passed[1] += bool(r["passed"])
    return [PassRate(name, runs, passed) for name, (runs, passed) in sorted(counts.items())]


def _value_text(value: Any) -> str:
    return json.dumps(value)


def _ordered(values: list[Any]) -> list[Any]:
    """``values`` sorted when they compare (numbers, or text), else as first seen."""
    try:
        return sorted(values)
    except TypeError:
        return values


def pass_rates_by_parameter(results: Sequence[dict[str, Any]]) -> list[PassRate]:
    """One :class:`PassRate` per scenario, override key (``faults.0.params.rate``) and value,
    for the runs with ``overrides``: by scenario, key, then value."""
    groups: dict[tuple[str, str], dict[str, tuple[Any, list[int]]]] = {}
    for r in results:
        for key, value in r.get("overrides", {}).items():
            by_value = groups.setdefault((r["scenario"], key), {})
            _, runs_passed = by_value.setdefault(_value_text(value), (value, [0, 0]))
            runs_passed[0] += 1
            runs_passed[1] += bool(r["passed"])
    rates = []
    for (scenario, key), by_value in sorted(groups.items()):
        values = _ordered([v for v, _ in by_value.values()])
        for value in values:
            runs, passed = by_value[_value_text(value)][1]
            rates.append(PassRate(f"{key} = {_value_text(value)}", runs, passed, scenario,
                                  key, value))
    return rates


def pass_rates_markdown(results: Sequence[dict[str, Any]], plots: bool = False
                        ) -> list[str]:
    """The pass-rate tables (Markdown lines); with ``plots``, the charts referenced."""
    lines = ["## Pass rate by fault class", "",
             "A run counts once for every fault class of its plan.", "",
             "| fault | runs | passed | rate |", "|---|---|---|---|"]
    lines += [f"| {p.label} | {p.cells()} |" for p in pass_rates_by_fault(results)]
    if plots and results:
        lines += ["", f"![pass rate by fault class]({FAULT_RATES_PNG})"]
    by_parameter = pass_rates_by_parameter(results)
    if by_parameter:
        lines += ["", "## Pass rate by parameter", "",
                  "| scenario | parameter | value | runs | passed | rate |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| {p.scenario} | `{p.key}` | {_value_text(p.value)} | {p.cells()} |"
                  for p in by_parameter]
        if plots:
            lines += ["", f"![pass rate by parameter]({PARAMETER_RATES_PNG})"]
    return lines


def run_name(result: dict[str, Any]) -> str:
    """A file-name-safe name of one run: scenario, seed, overrides."""
    extra = "".join(f"-{k.split('.')[-1]}{v}" for k, v in sorted(result.get("overrides",
                                                                            {}).items()))
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", f"{result['scenario']}-seed{result['seed']}{extra}")


def setting_text(key: str, value: Any) -> str:
    """``KEY=VALUE`` as ``--set`` reads it back (the value as TOML/JSON)."""
    return f"{key}={json.dumps(value)}"


def reproduce_command(result: dict[str, Any]) -> str:
    """The command line that runs ``result``'s run alone: its file, seed, profile and
    overrides."""
    args = ["hil-bench", "run", result["source"], "--seed", str(result["seed"])]
    if result.get("profile"):
        args += ["--profile", result["profile"]]
    for key, value in sorted(result.get("overrides", {}).items()):
        args += ["--set", setting_text(key, value)]
    return shlex.join(args)


def override_texts(result: dict[str, Any]) -> list[str]:
    """A run's overrides as ``key=value``, each key by its last part (``probability=0.2``)."""
    return [setting_text(k.split(".")[-1], v)
            for k, v in sorted(result.get("overrides", {}).items())]


def run_label(result: dict[str, Any]) -> str:
    """A run's scenario with its overrides (``link_loss probability=0.2``)."""
    return " ".join([result["scenario"], *override_texts(result)])


def summary_markdown(results: Sequence[dict[str, Any]], plots: bool = False,
                     planned: int | None = None) -> str:
    """The Markdown summary: the pass rates (:func:`pass_rates_markdown`; ``plots``: with
    the charts referenced), one row per run, then every failed assertion with the command
    that reproduces its run.  ``planned``: the runs the campaign had (more than the results
    when it was interrupted, which the summary then says)."""
    passed = sum(r["passed"] for r in results)
    lines = ["# HIL bench summary", "",
             f"{passed} of {len(results)} runs passed.", ""]
    if planned is not None and planned > len(results):
        lines[-1:-1] = [f"Interrupted: {len(results)} of the campaign's {planned} runs "
                        f"finished; {planned - len(results)} were not run.", ""]
    lines += pass_rates_markdown(results, plots)
    lines += ["", "## Runs", "",
              "| scenario | seed | result | assertions | simulated s | wall s |",
             "|---|---|---|---|---|---|"]
    for r in results:
        ok = sum(a["passed"] for a in r["assertions"])
        lines.append(f"| {run_label(r)} | {r['seed']} | {'pass' if r['passed'] else 'FAIL'} "
                     f"| {ok}/{len(r['assertions'])} | {r['sim_s']:.3f} | {r['wall_s']:.2f} |")
    failed = [(r, a) for r in results for a in r["assertions"] if not a["passed"]]
    if failed:
        lines += ["", "## Failed assertions", ""]
        for r, a in failed:
            lines.append(f"- {run_label(r)} (seed {r['seed']}) `{a['id']}`: {a['message']} "
                         f"— measured {json.dumps(a['measured'])}")
        lines += ["", "Each failed run alone:", ""]
        lines += [f"- `{reproduce_command(r)}`" for r in results if not r["passed"]]
    lines += ["", "## Measured figures", ""]
    for r in results:
        for a in r["assertions"]:
            if a["measured"]:
                lines.append(f"- {run_label(r)} (seed {r['seed']}) `{a['id']}`: "
                             f"{json.dumps(a['measured'])}")
    return "\n".join(lines) + "\n"


def write_report(results: Sequence[dict[str, Any]], directory: str | Path,
                 planned: int | None = None) -> list[Path]:
    """Write summary.md, the pass-rate charts (:data:`FAULT_RATES_PNG`, and
    :data:`PARAMETER_RATES_PNG` when runs have overrides), ``<run>.json`` and
    ``<run>-fault<k>.png`` into ``directory``; ``planned`` as for
    :func:`summary_markdown`."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    written = [out / "summary.md"]
    written[0].write_text(summary_markdown(results, plots=True, planned=planned),
                          encoding="utf-8")
    written += plot_pass_rates(results, out)
    for r in results:
        name = run_name(r)
        path = out / f"{name}.json"
        path.write_text(json.dumps({k: v for k, v in r.items() if k != "trace"}, indent=1),
                        encoding="utf-8")
        written.append(path)
        if "trace" in r:
            written += plot_faults(r, out, name)
    return written


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _bars(ax: Any, rates: Sequence[PassRate], labels: Sequence[str]) -> None:
    """Horizontal bars of ``rates`` (0..1), each annotated ``passed/runs``."""
    ys = range(len(rates))
    ax.barh(ys, [p.rate for p in rates], color=["tab:green" if p.rate == 1.0 else "tab:red"
                                                for p in rates])
    ax.set_yticks(list(ys), list(labels), fontsize=7)
    ax.invert_yaxis()
    ax.set_xlim(0.0, 1.15)
    for y, p in zip(ys, rates, strict=True):
        ax.text(p.rate + 0.01, y, f"{p.passed}/{p.runs}", va="center", fontsize=7)


def plot_pass_rates(results: Sequence[dict[str, Any]], out: Path) -> list[Path]:
    """:data:`FAULT_RATES_PNG` (one bar per fault class) and, when runs have overrides,
    :data:`PARAMETER_RATES_PNG` (one panel per scenario and override key, one bar per
    value) in ``out``; the paths written."""
    if not results:
        return []
    plt = _pyplot()
    paths = []
    by_fault = pass_rates_by_fault(results)
    fig, ax = plt.subplots(figsize=(8, 1.0 + 0.25 * len(by_fault)))
    _bars(ax, by_fault, [p.label for p in by_fault])
    ax.set_xlabel("pass rate")
    ax.set_title(f"Pass rate by fault class ({len(results)} runs)", fontsize=9)
    fig.tight_layout()
    paths.append(out / FAULT_RATES_PNG)
    fig.savefig(paths[-1], dpi=80)
    plt.close(fig)
    by_parameter = pass_rates_by_parameter(results)
    if by_parameter:
        panels: dict[tuple[str, str], list[PassRate]] = {}
        for p in by_parameter:
            panels.setdefault((p.scenario, p.key), []).append(p)
        heights = [1.0 + 0.25 * len(v) for v in panels.values()]
        fig, axes = plt.subplots(len(panels), 1, figsize=(8, sum(heights)), squeeze=False,
                                 gridspec_kw={"height_ratios": heights})
        for ax, ((scenario, key), rates) in zip(axes[:, 0], panels.items(), strict=True):
            _bars(ax, rates, [_value_text(p.value) for p in rates])
            ax.set_title(f"{scenario}: {key}", fontsize=9)
        axes[-1, 0].set_xlabel("pass rate")
        fig.tight_layout()
        paths.append(out / PARAMETER_RATES_PNG)
        fig.savefig(paths[-1], dpi=80)
        plt.close(fig)
    return paths


def plot_faults(result: dict[str, Any], out: Path, name: str) -> list[Path]:
    """One PNG per applied fault (at most :data:`MAX_PLOTS`): plant truth and host view
    from :data:`PLOT_BEFORE_S` before to :data:`PLOT_AFTER_S` after its start."""
    plt = _pyplot()
    trace = result["trace"]
    applies = [e for e in result["timeline"] if e["action"] == "apply"][:MAX_PLOTS]
    paths = []
    for k, event in enumerate(applies):
        t0 = event["t_s"]
        lo, hi = t0 - PLOT_BEFORE_S, t0 + PLOT_AFTER_S

        def window(rows: list[dict[str, Any]], lo: float = lo, hi: float = hi
                   ) -> list[dict[str, Any]]:
            return [s for s in rows if lo <= s["t"] <= hi]

        fig, axes = plt.subplots(2, 1, figsize=(8, 5), sharex=True)
        truth = window(trace["truth"])
        top, bottom = axes
        if truth and "attached" in truth[0]:
            for f in range(len(truth[0]["attached"])):
                top.step([s["t"] for s in truth], [s["attached"][f] + 1.5 * f for s in truth],
                         where="post", label=f"finger {f} contact")
        if truth and "arm_q" in truth[0]:
            for j in range(len(truth[0]["arm_q"])):
                top.plot([s["t"] for s in truth], [s["arm_q"][j] for s in truth],
                         label=f"J{j + 1} (rad)")
        hand = window(trace["hand"])
        if hand:
            for f in range(len(hand[0]["present"])):
                bottom.step([s["t"] for s in hand], [s["present"][f] + 1.5 * f for s in hand],
                            where="post", label=f"finger {f} answers")
        arm = [s for s in window(trace["arm"]) if "slip" in s]
        if arm:
            for j in range(len(arm[0]["slip"])):
                bottom.step([s["t"] for s in arm], [s["slip"][j] + 1.5 * j for s in arm],
                            where="post", label=f"J{j + 1} SLIP")
            bottom.step([s["t"] for s in arm], [len(s["errors"]) for s in arm], where="post",
                        label="joints with error bits")
        for e in window(trace["events"]):
            bottom.axvline(e["t"], color="grey", lw=0.8, ls=":")
        for ax in axes:
            ax.axvline(t0, color="red", lw=1.2)
            if any(not line.get_label().startswith("_") for line in ax.lines):
                ax.legend(fontsize=6, loc="upper right")
        top.set_title(f"{result['scenario']} (seed {result['seed']}): {event['label']} "
                      f"at {t0:.3f} s", fontsize=9)
        top.set_ylabel("plant")
        bottom.set_ylabel("host")
        bottom.set_xlabel("simulation time (s)")
        path = out / f"{name}-fault{k}.png"
        fig.savefig(path, dpi=80)
        plt.close(fig)
        paths.append(path)
    return paths
