"""The demo's report: a Markdown page with PNG plots of what :mod:`tools.demo` saw.

Plots (matplotlib, Agg backend, no display needed): the arm's joint angles (rad), the
fingers' joint angles (rad), the tactile pads (sum of each finger's taxels above their
reading before the grasp, ADC counts: what the log's "holding" lines report), the motors'
effort (mean |effort| per finger, 1/255 of full PWM) and, in process, the mug's height and
the palm's from the physics (ground truth, cm) with the mug's slip in the hand.  Every plot
spans the whole session (simulated time); a line breaks where nothing was read for
:data:`GAP_S`, rather than joining the readings on either side.  Vertical lines mark where
each step began.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

from host.arm.state import ArmState
from host.hand.state import FingerState, HandState

if TYPE_CHECKING:
    from matplotlib.axes import Axes


@dataclass
class Log:
    """What the demo saw, for the report: arm states, finger readings (t, finger, state),
    hand states, the steps (name, sim s, wall s, text) and, in process, the physics' ground
    truth of the mug and the palm (``truth``)."""

    arm: list[ArmState] = field(default_factory=list)
    fingers: list[tuple[float, int, FingerState]] = field(default_factory=list)
    hands: list[HandState] = field(default_factory=list)
    steps: list[tuple[str, float, float, str]] = field(default_factory=list)
    phases: list[tuple[str, float]] = field(default_factory=list)
    result: dict[str, Any] = field(default_factory=dict)
    #: In process: the mug and the palm (t, mug z, palm z, slip; s, m) from the physics.
    truth: list[tuple[float, float, float, float]] = field(default_factory=list)
    #: Each finger's reading when the grasp began: the tactile plot's baseline.
    touch_baseline: dict[int, FingerState] = field(default_factory=dict)


#: Readings further apart than this (s) are not joined by a line.
GAP_S: Final = 0.5


def _gapped(ts: Sequence[float], ys: Sequence[float]) -> tuple[list[float], list[float]]:
    """``ts``, ``ys`` with a NaN between readings more than :data:`GAP_S` apart."""
    out_t: list[float] = []
    out_y: list[float] = []
    for i, (t, y) in enumerate(zip(ts, ys, strict=True)):
        if i and t - ts[i - 1] > GAP_S:
            out_t.append((t + ts[i - 1]) / 2)
            out_y.append(float("nan"))
        out_t.append(t)
        out_y.append(y)
    return out_t, out_y


def _span(log: Log) -> tuple[float, float]:
    """The session's first and last moment (s, simulated)."""
    times = [t for _, t in log.phases] + [sim for _, sim, _, _ in log.steps]
    times += [s.t for s in log.arm[-1:]] + [t for t, _, _ in log.fingers[-1:]]
    return (min(times), max(times)) if times else (0.0, 1.0)


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
    span = _span(log)
    if log.arm:
        fig, ax = plt.subplots(figsize=(9, 3.5))
        t = [s.t for s in log.arm]
        for j in range(7):
            ax.plot(*_gapped(t, [s.joints[j] for s in log.arm]), label=f"J{j + 1}",
                    linewidth=1)
        ax.set_xlim(*span)
        _phases(ax, log.phases)
        ax.set_xlabel("simulated time (s)")
        ax.set_ylabel("joint angle (rad)")
        ax.legend(ncol=7, fontsize=7, loc="lower right")
        images.append(("Arm joint trajectories", _save(fig, out / "arm_joints.png")))
        plt.close(fig)
    if log.fingers:
        fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
        from tools.demo.watch import touch

        for k in range(4):
            rows = sorted(((t, s) for t, f, s in log.fingers if f == k and s.tactile),
                          key=lambda row: row[0])
            if not rows:
                continue
            ts = [t for t, _ in rows]
            for j in range(3):
                axes[0].plot(*_gapped(ts, [s.joints[j] for _, s in rows]), linewidth=1,
                             label=f"finger {k} J{j}")
            baseline = log.touch_baseline.get(k, rows[0][1])
            axes[1].plot(*_gapped(ts, [touch(s, baseline)[0] for _, s in rows]),
                         label=f"finger {k}")
            axes[2].plot(*_gapped(ts, [sum(abs(e) for e in s.effort) / 3 for _, s in rows]),
                         label=f"finger {k}")
        axes[0].set_ylabel("finger joints (rad)")
        axes[0].legend(ncol=4, fontsize=6)
        axes[1].set_ylabel("tactile rise since\nthe grasp began (ADC counts)")
        axes[1].legend(fontsize=7)
        axes[2].set_ylabel("mean |effort| (/255)")
        axes[2].set_xlabel("simulated time (s)")
        axes[2].legend(fontsize=7)
        for ax in axes:
            ax.set_xlim(*span)
            _phases(ax, log.phases)
        images.append(("Fingers: joints, tactile signals, grasp effort",
                       _save(fig, out / "hand.png")))
        plt.close(fig)
    if log.truth:
        fig, (ax, slip_ax) = plt.subplots(2, 1, figsize=(9, 5), sharex=True,
                                          gridspec_kw={"height_ratios": [2, 1]})
        samples = sorted(log.truth)
        times = [t for t, _, _, _ in samples]
        z0 = samples[0][1]
        grasp = next((t for name, t in log.phases if name == "grasp"), times[0])
        palm0 = min(samples, key=lambda row: abs(row[0] - grasp))[2]
        ax.plot(*_gapped(times, [(z - z0) * 100 for _, z, _, _ in samples]), label="mug")
        ax.plot(*_gapped(times, [(p - palm0) * 100 for _, _, p, _ in samples]), linewidth=0.8,
                linestyle="--", label="palm (from its height at the grasp)")
        ax.set_ylabel("height above start (cm)")
        ax.legend(fontsize=7, loc="upper left")
        slip_ax.plot(*_gapped(times, [s * 100 for _, _, _, s in samples]))
        slip_ax.set_ylabel("mug moved in\nthe hand (cm)")
        slip_ax.set_xlabel("simulated time (s)")
        for axis in (ax, slip_ax):
            axis.set_xlim(*span)
            _phases(axis, log.phases)
        images.append(("The mug and the palm (physics ground truth)",
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
