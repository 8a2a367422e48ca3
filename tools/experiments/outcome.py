"""The experiments' results and their output: a table row against the dissertation's figure
(:class:`Row`), an experiment's rows and plotted series (:class:`Outcome`), the plain-text
table and the Markdown report with its PNG plots (``hil-bench experiments``,
:mod:`tools.experiments.dissertation`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np


@dataclass
class Row:
    """One line of the table.  ``passed`` None: not comparable (``note`` says why)."""

    quantity: str
    dissertation: str
    emulator: str
    tolerance: str
    passed: bool | None
    note: str = ""
    value: float | None = None


@dataclass
class Outcome:
    """An experiment's rows and its plots' data (name → series)."""

    name: str
    rows: list[Row]
    series: dict[str, Any] = field(default_factory=dict)


def within(value: float, target: float, rel: float = 0.10) -> bool:
    """|value − target| ≤ rel·|target|."""
    return abs(value - target) <= rel * abs(target)


def table(rows: Sequence[Row]) -> str:
    """The plain-text table."""
    head = ("quantity", "dissertation", "emulator", "tolerance", "pass")
    body = [(r.quantity, r.dissertation, r.emulator, r.tolerance,
             "n/c" if r.passed is None else "yes" if r.passed else "NO") for r in rows]
    widths = [max(len(x[i]) for x in (head, *body)) for i in range(5)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(line, widths, strict=True)).rstrip()
             for line in (head, *body)]
    lines.insert(1, "  ".join("-" * w for w in widths))
    notes = [f"  {r.quantity}: {r.note}" for r in rows if r.passed is None and r.note]
    return "\n".join(lines + (["not comparable:", *notes] if notes else []))


def _plots(outcomes: Sequence[Outcome], out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    for o in outcomes:
        if o.name == "steps":
            fig, axes = plt.subplots(3, 1, figsize=(7, 9))
            for ax, (name, s) in zip(axes, o.series.items(), strict=True):
                ax.axhline(s["target"], color="k", lw=0.8, label="Target")
                for loop in ("open", "closed"):
                    if loop in s:
                        ax.plot(s[loop][0], s[loop][1], label=f"{loop.capitalize()}-loop")
                ax.set(title=f"{name} step response", xlabel="Time (seconds)",
                       ylabel="Joint angle (degrees)", xlim=(0, s["window"]))
                ax.legend()
            fig.tight_layout()
        elif o.name == "repeatability":
            p = np.array(o.series["repeatability"])
            fig, ax = plt.subplots(figsize=(5, 5))
            ax.scatter(p[:, 0], p[:, 1])
            ax.set(title="Flange at home after each return", xlabel="x (mm)", ylabel="y (mm)")
            ax.set_aspect("equal")
        elif o.name == "tactile":
            t, v, on = o.series["tactile"]
            fig, ax = plt.subplots(figsize=(7, 3))
            ax.plot(t, v)
            ax.set(title="2 g coin on and off the distal pad", xlabel="Time (s)",
                   ylabel="Raw taxel (counts)")
        elif o.name == "elbow":
            fig, ax = plt.subplots(figsize=(7, 3))
            for case, (t, x) in o.series["elbow"].items():
                ax.plot(t, x, label=case)
            ax.set(title="Elbow ringing after a step", xlabel="Time (s)", ylabel="J4 (degrees)")
            ax.legend()
        elif o.name == "speed":
            t, arc = o.series["speed"]
            fig, ax = plt.subplots(figsize=(7, 3))
            ax.plot(np.array(t) - t[0], arc)
            ax.set(title="Flange path length, J2 at the maximum step rate", xlabel="Time (s)",
                   ylabel="Path (m)")
        else:
            continue
        name = f"{o.name}.png"
        fig.savefig(out / name, dpi=90, bbox_inches="tight")  # axis labels kept
        plt.close(fig)
        written.append(name)
    return written


def report(outcomes: Sequence[Outcome], out: Path) -> Path:
    """Markdown report with PNG plots in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    rows = [r for o in outcomes for r in o.rows]
    lines = ["# Emulator against the dissertation", "",
             "| quantity | dissertation | emulator | tolerance | pass |", "|---|---|---|---|---|"]
    lines += [f"| {r.quantity} | {r.dissertation} | {r.emulator} | {r.tolerance} | "
              f"{'not comparable: ' + r.note if r.passed is None else 'yes' if r.passed else '**no**'} |"
              for r in rows]
    lines.append("")
    for name in _plots(outcomes, out):
        lines += [f"![{name}]({name})", ""]
    path = out / "experiments.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path
