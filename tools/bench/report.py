"""Reports of a bench run: a Markdown summary, one JSON result per run, PNG plots around
each fault (matplotlib, Agg: no display needed)."""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

#: Seconds of trace before and after a fault's start in its plot.
PLOT_BEFORE_S = 0.2
PLOT_AFTER_S = 0.8
#: Plots per run at most.
MAX_PLOTS = 4


def run_name(result: dict[str, Any]) -> str:
    """A file-name-safe name of one run: scenario, seed, overrides."""
    extra = "".join(f"-{k.split('.')[-1]}{v}" for k, v in sorted(result.get("overrides",
                                                                            {}).items()))
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", f"{result['scenario']}-seed{result['seed']}{extra}")


def summary_markdown(results: Sequence[dict[str, Any]]) -> str:
    """The Markdown summary: one row per run, then every failed assertion."""
    passed = sum(r["passed"] for r in results)
    lines = ["# HIL bench summary", "",
             f"{passed} of {len(results)} runs passed.", "",
             "| scenario | seed | result | assertions | simulated s | wall s |",
             "|---|---|---|---|---|---|"]
    for r in results:
        ok = sum(a["passed"] for a in r["assertions"])
        lines.append(f"| {r['scenario']} | {r['seed']} | {'pass' if r['passed'] else 'FAIL'} "
                     f"| {ok}/{len(r['assertions'])} | {r['sim_s']:.3f} | {r['wall_s']:.2f} |")
    failed = [(r, a) for r in results for a in r["assertions"] if not a["passed"]]
    if failed:
        lines += ["", "## Failed assertions", ""]
        for r, a in failed:
            lines.append(f"- {r['scenario']} (seed {r['seed']}) `{a['id']}`: {a['message']} "
                         f"— measured {json.dumps(a['measured'])}")
    lines += ["", "## Measured figures", ""]
    for r in results:
        for a in r["assertions"]:
            if a["measured"]:
                lines.append(f"- {r['scenario']} (seed {r['seed']}) `{a['id']}`: "
                             f"{json.dumps(a['measured'])}")
    return "\n".join(lines) + "\n"


def write_report(results: Sequence[dict[str, Any]], directory: str | Path) -> list[Path]:
    """Write summary.md, ``<run>.json`` and ``<run>-fault<k>.png`` into ``directory``."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    written = [out / "summary.md"]
    written[0].write_text(summary_markdown(results), encoding="utf-8")
    for r in results:
        name = run_name(r)
        path = out / f"{name}.json"
        path.write_text(json.dumps({k: v for k, v in r.items() if k != "trace"}, indent=1),
                        encoding="utf-8")
        written.append(path)
        if "trace" in r:
            written += plot_faults(r, out, name)
    return written


def plot_faults(result: dict[str, Any], out: Path, name: str) -> list[Path]:
    """One PNG per applied fault (at most :data:`MAX_PLOTS`): plant truth and host view
    from :data:`PLOT_BEFORE_S` before to :data:`PLOT_AFTER_S` after its start."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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
