"""The demo's report: a Markdown page with PNG plots of what :mod:`tools.demo` saw.

Plots (matplotlib, Agg backend, no display needed): the arm's joint angles (rad), the
fingers' joint angles (rad), the tactile pads (sum of each finger's taxels above their
first reading, ADC counts), the motors' effort (mean |effort| per finger, 1/255 of full
PWM) and, in process, the mug's height from the physics (ground truth, m).  Vertical lines
mark where each step began.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from matplotlib.axes import Axes

    from tools.demo import Log


def _phases(ax: Axes, phases: Sequence[tuple[str, float]]) -> None:
    for name, t in phases:
        ax.axvline(t, color="0.7", linewidth=0.8)
        ax.text(t, 1.0, f" {name}", transform=ax.get_xaxis_transform(), fontsize=7,
                rotation=90, va="top", color="0.4")


def _save(fig: Any, path: Path) -> str:
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    return path.name


def write_report(log: Log, out: Path) -> Path:
    """Write ``out/report.md`` and its PNGs; returns the report's path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    images: list[tuple[str, str]] = []
    if log.arm:
        fig, ax = plt.subplots(figsize=(9, 3.5))
        t = [s.t for s in log.arm]
        for j in range(7):
            ax.plot(t, [s.joints[j] for s in log.arm], label=f"J{j + 1}", linewidth=1)
        _phases(ax, log.phases)
        ax.set_xlabel("simulated time (s)")
        ax.set_ylabel("joint angle (rad)")
        ax.legend(ncol=7, fontsize=7, loc="lower right")
        images.append(("Arm joint trajectories", _save(fig, out / "arm_joints.png")))
        plt.close(fig)
    if log.fingers:
        fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
        first: dict[tuple[int, str], list[int]] = {}
        for k in range(4):
            rows = [(t, s) for t, f, s in log.fingers if f == k]
            if not rows:
                continue
            ts = [t for t, _ in rows]
            for j in range(3):
                axes[0].plot(ts, [s.joints[j] for _, s in rows], linewidth=1,
                             label=f"finger {k} J{j}")
            touch = []
            for _, s in rows:
                total = 0
                for pad, values in s.tactile.items():
                    base = first.setdefault((k, pad), list(values))
                    total += sum(max(0, v - b) for v, b in zip(values, base, strict=False))
                touch.append(total)
            axes[1].plot(ts, touch, label=f"finger {k}")
            axes[2].plot(ts, [sum(abs(e) for e in s.effort) / 3 for _, s in rows],
                         label=f"finger {k}")
        axes[0].set_ylabel("finger joints (rad)")
        axes[0].legend(ncol=4, fontsize=6)
        axes[1].set_ylabel("tactile rise (ADC counts)")
        axes[1].legend(fontsize=7)
        axes[2].set_ylabel("mean |effort| (/255)")
        axes[2].set_xlabel("simulated time (s)")
        axes[2].legend(fontsize=7)
        for ax in axes:
            _phases(ax, log.phases)
        images.append(("Fingers: joints, tactile signals, grasp effort",
                       _save(fig, out / "hand.png")))
        plt.close(fig)
    if log.mug_z:
        fig, ax = plt.subplots(figsize=(9, 3))
        z0 = log.mug_z[0][1]
        ax.plot([t for t, _ in log.mug_z], [(z - z0) * 100 for _, z in log.mug_z])
        _phases(ax, log.phases)
        ax.set_xlabel("simulated time (s)")
        ax.set_ylabel("mug height above start (cm)")
        images.append(("The mug's height (physics ground truth)",
                       _save(fig, out / "mug_height.png")))
        plt.close(fig)

    lines = ["# Demo: picking up a coffee mug", ""]
    lines += ["| step | sim (s) | wall (s) | what |", "|---|---|---|---|"]
    lines += [f"| {step} | {sim:.1f} | {wall:.1f} | {text} |"
              for step, sim, wall, text in log.steps]
    lines += ["", "## Result", "", "```json", json.dumps(log.result, indent=2, default=str),
              "```", ""]
    for title, name in images:
        lines += [f"## {title}", "", f"![{title}]({name})", ""]
    lines += ["## Recordings", "",
              "`hand.mcap` (hand frames, states, events; `handbus decode hand.mcap`) and "
              "`arm.mcap` (arm bus bytes and every cycle's state).", ""]
    path = out / "report.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path
