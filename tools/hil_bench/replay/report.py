"""What ``hil-bench replay`` prints, writes with ``--json`` and puts in ``--report DIR``
(``replay.md``, ``replay.json`` and PNG plots of the channels that parted, in the style of
the bench's reports: :mod:`tools.hil_bench.report`).  The JSON keys are documented in
docs/HIL_BENCH.md ("Replay")."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Final

from tools.hil_bench.replay.compare import Channel
from tools.hil_bench.replay.session import ReplayResult

#: Channels plotted in a report at most (those that parted first, else the largest errors,
#: then those whose recorded values moved most).
MAX_PLOTS: Final = 6
#: Channels named in the one-line summary at most.
NAMED: Final = 8


def _channel(c: Channel, series: bool) -> dict[str, Any]:
    out: dict[str, Any] = {"tolerance": c.tolerance, "samples": len(c.t), "rms": c.rms,
                           "max": c.max_abs, "first_exceeded_t": c.first_exceeded_t,
                           "within": c.within}
    if series:
        out["t"] = c.t
        out["recorded"] = c.recorded
        out["replayed"] = c.replayed
    return out


def as_json(result: ReplayResult) -> dict[str, Any]:
    """The replay as one JSON object (keys: docs/HIL_BENCH.md); the channels that parted
    carry their series (``t``, ``recorded``, ``replayed``)."""
    rec = result.recording
    spec = rec.spec
    return {
        "recording": rec.path,
        "links": sorted(t.link for t in rec.links.values()),
        "emulator": {"config": spec.config, "seed": spec.seed, "sensors": spec.sensors,
                     "scene": spec.scene, "ready": spec.ready, "physics": spec.physics},
        "from_recording": rec.emulated,
        "assumed": rec.assumed,
        "truncated": rec.truncated,
        "notes": result.notes,
        "duration_s": rec.duration_s,
        "sim_s": result.sim_s,
        "cpu_s": result.cpu_s,
        "sim_s_per_cpu_s": result.sim_s / result.cpu_s if result.cpu_s > 0 else None,
        "exchanges": result.exchanges,
        "within": result.within,
        "failing": result.failing,
        "channels": {name: _channel(c, not c.within)
                     for name, c in sorted(result.channels.items())},
    }


def _part(c: Channel) -> str:
    return f"{c.name} (from {c.first_exceeded_t:.3f} s, max {c.max_abs:.6g})"


def summary_line(result: ReplayResult) -> str:
    """One line: agreement, or the channels that parted (first first)."""
    total = len(result.channels)
    if result.within:
        return (f"replay agrees: {total} channels within tolerance over "
                f"{result.recording.duration_s:.2f} s ({result.exchanges} requests)")
    failing = result.failing
    named = ", ".join(_part(result.channels[n]) for n in failing[:NAMED])
    more = f" and {len(failing) - NAMED} more" if len(failing) > NAMED else ""
    return f"replay disagrees: {len(failing)} of {total} channels part: {named}{more}"


def text_lines(result: ReplayResult) -> list[str]:
    """What ``hil-bench replay`` prints without ``--json``: the notes, then the summary."""
    rec = result.recording
    spec = rec.spec
    lines = [f"{rec.path}: replayed on the {spec.config!r} emulator (seed {spec.seed}, "
             f"sensors {spec.sensors}, scene {spec.scene}): {result.sim_s:.2f} simulated s "
             f"in {result.cpu_s:.2f} CPU s"]
    lines += [f"note: {a}" for a in rec.assumed]
    if rec.truncated:
        lines.append(f"note: {rec.truncated}")
    lines += [f"note: {n}" for n in result.notes]
    lines.append(summary_line(result))
    return lines


def _plotted(result: ReplayResult) -> list[Channel]:
    if not result.within:
        return [result.channels[n] for n in result.failing[:MAX_PLOTS]]
    def spread(c: Channel) -> float:
        return max(c.recorded, default=0.0) - min(c.recorded, default=0.0)

    ranked = sorted(result.channels.values(), key=lambda c: (-c.max_abs, -spread(c), c.name))
    return ranked[:MAX_PLOTS]


def plot_channel(c: Channel, path: Path) -> Path:
    """Recorded and replayed values over time (top) and the error with its tolerance
    (bottom), the first parting marked."""
    from tools.hil_bench.report import _pyplot

    plt = _pyplot()
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 4.5), sharex=True)
    top.step(c.t, c.recorded, where="post", label="recorded")
    top.step(c.t, c.replayed, where="post", label="replayed", ls="--")
    top.legend(fontsize=6, loc="upper right")
    top.set_title(c.name, fontsize=9)
    bottom.step(c.t, c.errors, where="post", color="black", lw=0.8, label="replayed − recorded")
    for bound in (c.tolerance, -c.tolerance):
        bottom.axhline(bound, color="grey", lw=0.8, ls=":")
    if c.first_exceeded_t is not None:
        for ax in (top, bottom):
            ax.axvline(c.first_exceeded_t, color="red", lw=1.2)
    bottom.set_ylabel("error")
    bottom.set_xlabel("time (s, the recording's clock)")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def _file_name(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "._-" else "_" for ch in name) + ".png"


def write_report(result: ReplayResult, out_dir: str | Path) -> list[Path]:
    """``replay.md``, ``replay.json`` and the plots into ``out_dir``; returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    data = as_json(result)
    paths = [out / "replay.json"]
    paths[0].write_text(json.dumps(data, indent=1), encoding="utf-8")
    plots = [plot_channel(c, out / _file_name(c.name)) for c in _plotted(result)]
    rec = result.recording
    lines = [f"# Replay of {Path(rec.path).name}", "",
             f"Emulator: `{rec.spec.config}`, seed {rec.spec.seed}, sensors "
             f"`{rec.spec.sensors}`, scene `{rec.spec.scene}` "
             f"({'as the recording names it' if rec.emulated else 'assumed'}).  "
             f"{rec.duration_s:.2f} s of recording, {result.exchanges} requests, "
             f"{result.sim_s:.2f} simulated s in {result.cpu_s:.2f} CPU s.", "",
             f"**{summary_line(result)}**", ""]
    for note in [*rec.assumed, *([rec.truncated] if rec.truncated else []), *result.notes]:
        lines.append(f"- {note}")
    lines += ["", "## Channels", "",
              "| channel | samples | tolerance | RMS | max | first parts (s) |",
              "|---|---:|---:|---:|---:|---:|"]
    ordered = sorted(result.channels.values(),
                     key=lambda c: (c.within, c.first_exceeded_t or 0.0, c.name))
    for c in ordered:
        first = "" if c.first_exceeded_t is None else f"{c.first_exceeded_t:.4f}"
        lines.append(f"| `{c.name}` | {len(c.t)} | {c.tolerance:g} | {c.rms:.6g} | "
                     f"{c.max_abs:.6g} | {first} |")
    lines += ["", "## Plots", ""]
    lines += [f"![{p.stem}]({p.name})" for p in plots]
    paths.append(out / "replay.md")
    paths[-1].write_text("\n".join(lines) + "\n", encoding="utf-8")
    return paths + plots
