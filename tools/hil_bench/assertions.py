"""The assertions a scenario can make, judged on a run's record.

Each returns ``{"check", "id", "passed", "measured": {...}, "message"}``: the figures it
measured (latencies in ms, counts) whether it passed or not.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Final

from protocol.stream import decode_all

if TYPE_CHECKING:
    from tools.hil_bench.record import RunRecord
    from tools.hil_bench.scenario import Step

Verdict = tuple[bool, dict[str, Any], str]


def judge(step: Step, record: RunRecord) -> dict[str, Any]:
    """The verdict of assertion ``step`` on ``record``."""
    passed, measured, message = CHECKS[step.kind](record, **step.params)
    return {"check": step.kind, "id": step.id, "params": step.params, "passed": passed,
            "measured": measured, "message": message}


def _first_apply(record: RunRecord, label: str) -> float | None:
    times = record.fault_times(label)
    return times[0] if times else None


def action_ok(record: RunRecord, action: str) -> Verdict:
    a = record.actions.get(action)
    if a is None:
        return False, {}, f"action {action!r} did not run"
    took = round((a["t_end"] - a["t_start"]) * 1e3, 3)
    return bool(a["ok"]), {"ms": took}, a.get("error", "ok")


def action_fails(record: RunRecord, action: str, match: str) -> Verdict:
    a = record.actions.get(action)
    if a is None:
        return False, {}, f"action {action!r} did not run"
    if a["ok"]:
        return False, {}, f"action {action!r} succeeded; it should have failed"
    error = a.get("error", "")
    ok = re.search(match, error) is not None if match else True
    return ok, {"ms": round((a["t_end"] - a["t_start"]) * 1e3, 3)}, error


def finger_event(record: RunRecord, finger: int, event: str, after: str,
                 within_ms: float) -> Verdict:
    t0 = _first_apply(record, after)
    if t0 is None:
        return False, {}, f"fault {after!r} was never applied"
    seen = [e["t"] for e in record.events if e["finger"] == finger and e["event"] == event
            and e["t"] >= t0]
    if not seen:
        return False, {"events": len(record.events)}, f"no {event!r} of finger {finger}"
    latency = round((seen[0] - t0) * 1e3, 3)
    return (latency <= within_ms, {"latency_ms": latency},
            f"{event} of finger {finger} {latency} ms after {after} (limit {within_ms} ms)")


def fingers_present(record: RunRecord, fingers: list[int], after: str,
                    settle_ms: float) -> Verdict:
    t0 = _first_apply(record, after)
    if t0 is None:
        return False, {}, f"fault {after!r} was never applied"
    samples = [s for s in record.hand_samples if s["t"] >= t0 + settle_ms / 1e3]
    missing = sum(1 for s in samples for k in fingers if not s["present"][k])
    ok = bool(samples) and missing == 0
    return (ok, {"samples": len(samples), "missing": missing},
            f"fingers {fingers} answered in {len(samples) * len(fingers) - missing} of "
            f"{len(samples) * len(fingers)} status reads after {after}")


def no_unsent_frames(record: RunRecord, link: str, min_corrupted: int) -> Verdict:
    """Every frame the device side decoded on ``link`` is one the host sent, whole or nested
    in another (a corrupted frame never got through its CRC)."""
    seen = record.links.get(link)
    if seen is None:
        return False, {}, f"link {link!r} was not recorded"
    def key(f: Any) -> tuple[int, int, bytes]:
        return f.address, f.type, bytes(f.payload)

    # What the host sent: its frames and the frames nested in them (a txn envelope carries
    # the whole inner request, which a decoder resynchronising after a corrupted envelope
    # finds and accepts: uncorrupted, and sent by the host).
    sent: set[tuple[int, int, bytes]] = set()
    todo = [f for f in decode_all(seen["sent"]) if f.crc_ok]
    while todo:
        frame = todo.pop()
        if key(frame) not in sent:
            sent.add(key(frame))
            todo += [f for f in decode_all(bytes(frame.payload)) if f.crc_ok]
    received = [f for f in decode_all(seen["received"]) if f.crc_ok]
    foreign = [f for f in received if key(f) not in sent]
    corrupted = sum(a != b for a, b in zip(seen["sent"], seen["received"], strict=False))
    ok = not foreign and corrupted >= min_corrupted
    return (ok, {"frames_sent": len(sent), "frames_accepted": len(received),
                 "foreign_frames": len(foreign), "bytes_differing": corrupted},
            f"{len(foreign)} frames accepted that the host never sent; "
            f"{corrupted} bytes differed on the way")


def flash_verified(record: RunRecord, action: str) -> Verdict:
    a = record.actions.get(action)
    if a is None or not a["ok"]:
        return False, {}, f"flash action {action!r} failed: {a and a.get('error')}"
    report = a["result"]
    done = sum(1 for n in report["nodes"] if n.get("result") in ("flashed", "skipped"))
    return (bool(report["ok"]), {"nodes": len(report["nodes"]), "done": done,
                                 "seconds": report["total_seconds"]},
            f"{done} of {len(report['nodes'])} nodes verified and running")


def arm_flag(record: RunRecord, joint: int, flag: str, after: str,
             within_ms: float) -> Verdict:
    """The host sees ``flag`` (``slip``) of stepper ``joint`` within ``within_ms`` of the
    plant's first slip event after fault ``after`` (of the fault itself without physics)."""
    t0 = _first_apply(record, after)
    if t0 is None:
        return False, {}, f"fault {after!r} was never applied"
    base = [s for s in record.truth if s["t"] <= t0 and "arm_slips" in s]
    before = base[-1]["arm_slips"][joint] if base else 0
    slipped = [s["t"] for s in record.truth if s["t"] >= t0 and "arm_slips" in s
               and s["arm_slips"][joint] > before]
    start = slipped[0] if slipped else t0
    seen = [s["t"] for s in record.arm_samples if s["t"] >= start and "slip" in s
            and flag == "slip" and s["slip"][joint]]
    if not seen:
        return False, {"samples": len(record.arm_samples)}, f"{flag} of J{joint + 1} never seen"
    latency = round((seen[0] - start) * 1e3, 3)
    measured = {"latency_ms": latency, "after_fault_ms": round((seen[0] - t0) * 1e3, 3)}
    return (latency <= within_ms, measured,
            f"{flag} of J{joint + 1} reported {latency} ms after the plant slipped "
            f"({measured['after_fault_ms']} ms after {after})")


def servo_error(record: RunRecord, joint: str, bit: str, after: str, within_ms: float,
                cleared_by: str | None) -> Verdict:
    t0 = _first_apply(record, after)
    if t0 is None:
        return False, {}, f"fault {after!r} was never applied"
    seen = [s["t"] for s in record.arm_samples if s["t"] >= t0
            and bit in s.get("errors", {}).get(joint, [])]
    if not seen:
        return False, {}, f"{bit} of {joint} never reported"
    measured: dict[str, Any] = {"latency_ms": round((seen[0] - t0) * 1e3, 3)}
    ok = measured["latency_ms"] <= within_ms
    message = f"{bit} of {joint} reported {measured['latency_ms']} ms after {after}"
    if cleared_by is not None:
        end = record.actions[cleared_by]["t_end"]
        later = [s for s in record.arm_samples if s["t"] > end and "errors" in s]
        still = sum(1 for s in later if bit in s["errors"].get(joint, []))
        measured.update(samples_after_clear=len(later), still_reported=still)
        ok = ok and bool(later) and still == 0
        message += f"; {still} of {len(later)} reads after {cleared_by} still report it"
    return ok, measured, message


def arm_torque_drift(record: RunRecord, joint: int, after: str, min_ratio: float,
                     window_ms: float, tolerance: float) -> Verdict:
    """The host's torque estimate of stepper ``joint`` (0..3; nominal stiffness × the
    node's deflection) drifts while fault ``after`` lasts: its mean over the last
    ``window_ms`` before the fault is cleared (or the run ends) differs from its mean over
    ``window_ms`` before the fault by a ratio of at least ``min_ratio`` (either way); and,
    once cleared, its mean over the run's last ``window_ms`` is back within ``tolerance``
    (a fraction) of the value before."""
    t0 = _first_apply(record, after)
    if t0 is None:
        return False, {}, f"fault {after!r} was never applied"
    cleared = record.fault_times(after, "clear")
    samples = [(s["t"], s["torques"][joint]) for s in record.arm_samples if "torques" in s]
    if not samples:
        return False, {}, "no arm_stream samples"
    window = window_ms / 1e3

    def mean(start: float, end: float) -> float | None:
        values = [v for t, v in samples if start <= t < end]
        return sum(values) / len(values) if values else None

    t_end = cleared[0] if cleared else samples[-1][0] + 1e-9
    before, during = mean(t0 - window, t0), mean(t_end - window, t_end)
    if before is None or during is None or before == 0.0:
        return (False, {"samples": len(samples)},
                f"no torque samples {window_ms} ms before {after} and before its end")
    ratio = during / before
    measured: dict[str, Any] = {"before_nm": round(before, 4), "during_nm": round(during, 4),
                                "ratio": round(ratio, 4)}
    ok = ratio >= min_ratio or (ratio > 0.0 and 1.0 / ratio >= min_ratio)
    message = (f"J{joint + 1}'s torque estimate {before:.3f} → {during:.3f} N·m (× "
               f"{ratio:.3f}) during {after}")
    if cleared:
        last = samples[-1][0]
        restored = mean(last - window, last + 1e-9) if last - window >= cleared[0] else None
        if restored is None:
            return False, measured, message + f"; the run ends within {window_ms} ms of the clear"
        measured["after_nm"] = round(restored, 4)
        ok = ok and abs(restored / before - 1.0) <= tolerance
        message += f", {restored:.3f} N·m after it was cleared"
    return ok, measured, message


def arm_holds(record: RunRecord, action: str, since: str, within_deg: float) -> Verdict:
    """From action ``action``'s ``since`` (``start`` or ``end``) to the end of the run, on
    the plant's and the nodes' truth: no arm joint moved more than ``within_deg`` from
    where it was then (none fell, none drove on), no node latched an alarm, and every
    joint's torque stayed as it was."""
    a = record.actions.get(action)
    if a is None:
        return False, {}, f"action {action!r} did not run"
    t0 = a["t_start"] if since == "start" else a["t_end"]
    rows = [r for r in record.truth if r["t"] >= t0 and "arm_q" in r]
    if not rows:
        return False, {}, f"no truth samples of the arm after {action}'s {since}"
    first = rows[0]
    moved = [max(abs(r["arm_q"][j] - first["arm_q"][j]) for r in rows)
             for j in range(len(first["arm_q"]))]
    worst = max(range(len(moved)), key=lambda j: moved[j])
    latched = sorted({f"J{j + 1}" for r in rows
                      for j, x in enumerate(r.get("arm_node_alarm", ())) if x})
    dropped = sorted({f"J{j + 1}" for r in rows
                      for j, x in enumerate(r.get("arm_node_torque", ()))
                      if x < first["arm_node_torque"][j]})
    deg = math.degrees(moved[worst])
    measured = {"max_move_deg": round(deg, 3), "joint": f"J{worst + 1}",
                "latched": latched, "torque_dropped": dropped,
                "seconds": round(rows[-1]["t"] - rows[0]["t"], 3)}
    ok = deg <= within_deg and not latched and not dropped
    return (ok, measured,
            f"from {action}'s {since}: J{worst + 1} moved {deg:.2f}° at most (limit "
            f"{within_deg}°) over {measured['seconds']} s; latched: {latched or 'none'}; "
            f"torque dropped: {dropped or 'none'}")


def fault_applied(record: RunRecord, label: str, count: int) -> Verdict:
    n = len(record.fault_times(label))
    return n == count, {"applied": n}, f"{label} applied {n} times (expected {count})"


def node_state(record: RunRecord, node: str, state: str) -> Verdict:
    """At the end: ``state`` is ``running``, ``bootloader`` or ``off``."""
    info = record.nodes.get(node)
    if info is None:
        return False, {}, f"no node {node!r}"
    actual = ("off" if not info["powered"] else
              "bootloader" if info["program"] == "bootloader" else "running")
    return actual == state, {"state": actual}, f"{node} is {actual}"


#: A stepper joint at rest: |velocity| below this (rad/s, the plant's truth).
REST_SPEED_RAD_S: Final = 0.02


def arm_held(record: RunRecord, action: str, within_ms: float, max_fall_deg: float,
             max_drive_on_deg: float, rest_within_ms: float | None) -> Verdict:
    """After the host of ``action`` (``arm_move_vanish``) went silent, on the plant's truth:
    every stepper motor stopped within ``within_ms`` and stayed so, no joint went back from
    where it was (or, not moving, strayed either way) more than ``max_fall_deg``, no stepper
    joint drove on more than ``max_drive_on_deg`` (a servo: its goal), nothing latched
    (SLIP/STALLED, a plant slip) and every stepper's torque stayed on, to the run's end.
    ``joints_rest_ms`` (measured) is when every stepper *joint* was last faster than
    :data:`REST_SPEED_RAD_S` (the elastic joints ring after their motors stop; -1: still
    moving at the run's end, a sample every 10 ms); ``rest_within_ms`` (None: only measured)
    bounds it."""
    a = record.actions.get(action)
    if a is None or not a.get("ok"):
        return False, {}, f"action {action!r} {'failed' if a else 'did not run'}"
    t0, goals = a["result"]["vanished_s"], a["result"]["goals"]
    rows = [r for r in record.truth if r["t"] >= t0 and "arm_step_rates" in r]
    if len(rows) < 2:
        return False, {"samples": len(rows)}, "no plant samples after the host vanished"
    q0 = rows[0]["arm_q"]
    moving = [0 if abs(g - q) < 0.01 else (1 if g > q else -1) for g, q in zip(goals, q0, strict=True)]
    still = [r["t"] for r in rows if any(r["arm_step_rates"])]
    rest_ms = round(((still[-1] if still else t0) - t0) * 1e3, 1)
    n_steppers = len(rows[0]["arm_step_rates"])
    fast = [r["t"] for r in rows
            if any(abs(v) >= REST_SPEED_RAD_S for v in r.get("arm_qd", [])[:n_steppers])]
    joints_rest_ms = (-1.0 if fast and fast[-1] == rows[-1]["t"]
                      else round(((fast[-1] if fast else t0) - t0) * 1e3, 1))
    fall = [0.0] * len(q0)
    on = [0.0] * len(q0)
    for r in rows:
        for j, (q, q_0) in enumerate(zip(r["arm_q"], q0, strict=True)):
            d = math.degrees(q - q_0) * (moving[j] or 1)
            fall[j] = max(fall[j], -d if moving[j] else abs(d))
            on[j] = max(on[j], d if moving[j] else 0.0)
    drive_limits = [max_drive_on_deg if j < len(rows[0]["arm_step_rates"])
                    else math.degrees(abs(goals[j] - q0[j])) + max_fall_deg
                    for j in range(len(q0))]
    slips = [b - a_ for a_, b in zip(rows[0]["arm_slips"], rows[-1]["arm_slips"], strict=True)]
    latched = [j for j in range(len(rows[-1]["arm_latched"]))
               if any(r["arm_latched"][j] for r in rows)]
    torque_off = [j for j in range(len(rows[-1]["arm_torque_on"]))
                  if not all(r["arm_torque_on"][j] for r in rows)]
    measured = {"rest_ms": rest_ms, "joints_rest_ms": joints_rest_ms, "fall_deg": [round(x, 2) for x in fall],
                "drive_on_deg": [round(x, 2) for x in on], "plant_slips": slips,
                "latched": [f"J{j + 1}" for j in latched],
                "torque_off": [f"J{j + 1}" for j in torque_off]}
    problems = []
    if rest_ms > within_ms:
        problems.append(f"motors still stepping {rest_ms} ms after the host vanished")
    if rest_within_ms is not None and not 0 <= joints_rest_ms <= rest_within_ms:
        problems.append("stepper joints not at rest "
                        + ("by the run's end" if joints_rest_ms < 0
                           else f"until {joints_rest_ms} ms")
                        + " after the host vanished")
    problems += [f"J{j + 1} fell {fall[j]:.2f}°" for j in range(len(q0))
                 if fall[j] > max_fall_deg]
    problems += [f"J{j + 1} drove on {on[j]:.2f}°" for j in range(len(q0))
                 if on[j] > drive_limits[j]]
    problems += [f"J{j + 1} latched" for j in latched]
    problems += [f"J{j + 1} torque off" for j in torque_off]
    problems += [f"J{j + 1} slipped" for j, n in enumerate(slips) if n]
    if problems:
        return False, measured, "; ".join(problems)
    return True, measured, (f"held: motors still {rest_ms} ms after the host vanished, "
                            f"worst fall {max(fall):.2f}°, nothing latched")


CHECKS: dict[str, Callable[..., Verdict]] = {
    "action_ok": action_ok, "action_fails": action_fails, "finger_event": finger_event,
    "fingers_present": fingers_present, "no_unsent_frames": no_unsent_frames,
    "flash_verified": flash_verified, "arm_flag": arm_flag, "servo_error": servo_error,
    "fault_applied": fault_applied, "node_state": node_state,
    "arm_torque_drift": arm_torque_drift, "arm_held": arm_held, "arm_holds": arm_holds,
}
