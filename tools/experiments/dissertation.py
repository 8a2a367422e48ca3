"""``hil-bench experiments``: the dissertation's measurements, repeated on the emulator.

Every experiment runs the emulator in process, in fast mode, and drives the robot through
the wire with the host library (:class:`host.arm.facade.Arm`, :class:`host.hand.facade.Hand` on
``EmulatorTransport(Emulator(...), link)``); the plant is used only where the dissertation used an
instrument (an optical tracker on the flange, masses hung on it, a hand pushing a joint, a
coin dropped on a pad).  One table comes out: quantity, dissertation, emulator, tolerance,
pass.  ``--report DIR`` writes it as Markdown with PNG plots (figure 5.8's step responses,
figure 5.7's repeatability scatter, figure 6.11's tactile trace).

Chapters 4 (the hand's inertial estimates, calibrated and not: ``calibration``), 5 (the arm)
and 6 (the hand) of the dissertation; tolerances are ±10 % unless a
row says otherwise.  A row is *not comparable* when the emulator cannot measure what the
dissertation did, with the reason; the command exits 0 only when every other row passes.

    python -c "import tools.experiments.dissertation as b; b.main(['--json'])"
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any, Final

import numpy as np

from hil_emulator.emulator import Emulator
from hil_emulator.inprocess import EmulatorTransport, bring_up
from host.arm.facade import Arm
from host.arm.joint_loop import JointController, PidGains, TrackingLog
from host.arm.state import N_JOINTS
from host.arm.trajectory import Trajectory, timed_path
from host.errors import StallError
from protocol.robot import (
    ARM_ENCODER_COUNTS_PER_REV,
    STEPPER_HOLDING_MARGIN,
    encoder_counts_to_rad,
    max_velocity_counts_per_s,
    microsteps_to_rad,
)
from tools.cli.numeric import read_negative_numbers
from tools.cli.output import guard_output
from tools.experiments.outcome import Outcome, Row, report, table, within

#: Seed of every experiment's emulator unless given.
DEFAULT_SEED: Final = 1
#: The optical tracker's resolution (m): flange positions are rounded to it (figure 5.7).
TRACKER_M: Final = 1e-4
#: The hanging arm's outstretched pose: J2 horizontal (rad).
OUTSTRETCHED: Final = (0.0, math.pi / 2, 0.0, 0.0, 0.0, 0.0, 0.0)
#: Feed-forward only (the route coupling, no PID): an "open-loop" joint move.
OPEN_LOOP: Final = PidGains(kp=(0.0,) * N_JOINTS, ki=(0.0,) * N_JOINTS)


# ----------------------------------------------------------------------------- helpers


def open_arm(seed: int) -> tuple[Emulator, Arm]:
    """An arm-only emulator and the host's :class:`Arm` on its bus (fast mode)."""
    emulator = Emulator("arm", seed=seed)
    return emulator, Arm.on(EmulatorTransport(emulator, "arm"))


def go(control: JointController, goal: Sequence[float], speed: float = 0.4,
       settle_s: float = 1.5, log: TrackingLog | None = None,
       until: Callable[[Any], bool] | None = None, smooth: bool = False) -> Any:
    """A timed joint-space path from where the arm is to ``goal`` (rad), then hold; with
    ``smooth`` a minimum-jerk one (slowing into the goal)."""
    state = control.state or control.start()
    start = np.array(state.joints)
    trajectory = Trajectory(timed_path([start, np.asarray(goal, dtype=float)], speed,
                                       smooth=smooth), smooth=smooth)
    return control.run(trajectory, trajectory.duration + settle_s, log, until=until)


# ----------------------------------------------------------------------------- the arm


def lift_unloaded(seed: int = DEFAULT_SEED) -> Outcome:
    """Closed loop with the coupling feed-forward: hanging → J2 horizontal → back."""
    emulator, arm = open_arm(seed)
    control = JointController(arm)
    log = TrackingLog()
    state = go(control, OUTSTRETCHED, log=log)
    error = abs(state.joints[1] - OUTSTRETCHED[1])
    go(control, (0.0,) * N_JOINTS, log=log)
    slips = int(emulator.require_arm_plant().slips().sum())
    ok = not log.stall_events and slips == 0 and error < math.radians(0.5)
    return Outcome("lift", [Row(
        "arm lifts to horizontal, unloaded (closed loop, feed-forward)", "yes",
        f"{'yes' if ok else 'no'}: {len(log.stall_events)} STALLED, {slips} slips, "
        f"J2 off by {math.degrees(error):.2f}°", "no trip, no slip, J2 within 0.5°", ok)])


def stall_still_trips(seed: int = DEFAULT_SEED) -> Outcome:
    """The nodes' protection with the host compensating: a real stall (a hand holding the
    forearm while the elbow is driven) still latches STALLED."""
    emulator, arm = open_arm(seed)
    control = JointController(arm)
    go(control, OUTSTRETCHED)
    emulator.require_arm_plant().push(3, -25.0)  # more than the elbow stepper can move against
    goal = list(OUTSTRETCHED)
    goal[3] = 0.6
    log = TrackingLog()
    gave_up = ""
    try:
        go(control, goal, speed=0.3, settle_s=1.0, log=log)
    except StallError as exc:  # the controller stops re-enabling a joint that stays held
        gave_up = exc.joint
    emulator.require_arm_plant().push(3, 0.0)
    tripped = "J4" in log.stall_events and gave_up in ("", "J4")
    return Outcome("stall", [Row(
        "elbow held against its stepper: node latches STALLED", "trips (§5.3.2)",
        "trips" if tripped else "does not trip", "trips", tripped)])


def holding_ratio(seed: int = DEFAULT_SEED) -> Outcome:
    """Elbow stepper: torque at which it slips standing still and moving slowly, pushed by
    hand (ArmPlant.push ramped) with the arm hanging."""
    results = []
    for moving in (False, True):
        emulator, arm = open_arm(seed)
        plant = emulator.require_arm_plant()
        arm.torque(True)
        clock = arm.transport
        if moving:  # the elbow stepping slowly away (0.02 rad/s) while pushed back
            # one goal, then no traffic while the hand pushes: the command watchdog would
            # stop the slow move (and measure the standstill again), so it is off here
            arm.set_watchdog(0)
            arm.cycle([arm.make_position(3, 1.0, speed=0.02)])
        peak, torque = 0.0, 0.0
        while not plant.slips()[3] and torque < 60.0:
            torque += 0.05
            plant.push(3, -torque)
            clock.sleep(0.005)
            peak = max(peak, abs(float(plant.coupling_torques()[3])))
        results.append(peak)
    hold, move = results
    ratio = hold / move
    return Outcome("holding", [
        Row("elbow holding torque at standstill (N·m)", "—", f"{hold:.1f}", "—", None,
            "the dissertation gives only the ratio", hold),
        Row("holding / maximum moving torque (§5.3.2)", "≈ 1.6", f"{ratio:.2f}", "±10 %",
            within(ratio, STEPPER_HOLDING_MARGIN), value=ratio)])


def payload(seed: int = DEFAULT_SEED, low: float = 1.6, high: float = 2.4,
            rounds: int = 4) -> Outcome:
    """Mass at the flange until a stepper slips while the outstretched arm moves slowly
    (open loop: the stepper goals follow a slow cosine path through horizontal, with the
    route feed-forward); bisection, a fresh arm per trial."""
    first_slip: dict[float, str] = {}

    def trial(kg: float) -> bool:
        emulator, arm = open_arm(seed)
        plant = emulator.require_arm_plant()
        control = JointController(arm, gains=OPEN_LOOP)
        below = list(OUTSTRETCHED)
        below[1] = math.pi / 2 - 0.45
        go(control, below, speed=0.4, settle_s=1.0)
        clock = arm.transport
        t0 = clock.now()

        def ramp_payload(_state: object) -> bool:  # the mass hung on over the run
            plant.set_payload(min(kg, kg * (clock.now() - t0)))
            return False

        control.run(lambda _t: (np.array(below), np.zeros(N_JOINTS)), 1.5, until=ramp_payload)
        span, seconds = 0.9, 9.0  # J2 from 45 to 135 ... via horizontal, slowly

        def path(t: float) -> tuple[np.ndarray, np.ndarray]:
            a = min(max(t / seconds, 0.0), 1.0)
            q = np.array(below)
            q[1] += span * (1 - math.cos(math.pi * a)) / 2
            qd = np.zeros(N_JOINTS)
            qd[1] = span * math.pi / (2 * seconds) * math.sin(math.pi * a) if a < 1 else 0.0
            return q, qd

        control.run(path, seconds, until=lambda _s: bool(plant.slips().any()))
        slips = plant.slips()
        if slips.any():
            first_slip[kg] = "J" + str(int(np.argmax(slips > 0)) + 1)
        return bool(slips.any())

    for _ in range(rounds):
        mid = (low + high) / 2
        if trial(mid):
            high = mid
        else:
            low = mid
    kg = (low + high) / 2
    joint = first_slip.get(high, "none")
    return Outcome("payload", [
        Row("payload before a stepper slips, outstretched, moving slowly (§5.6)", "2.0 kg",
            f"{kg:.2f} kg (±{(high - low) / 2:.2f})", "±10 %", within(kg, 2.0), value=kg),
        Row("the joint that slips first", "shoulder (J2)", joint, "J2", joint == "J2")])


def max_speed(seed: int = DEFAULT_SEED) -> Outcome:
    """The outstretched arm lifted at the controllers' maximum step rate (J2's path at the
    rate the node caps it to), the flange's speed from the plant (an optical tracker):
    the arc length's slope while J2's step generator runs at its cap."""
    emulator, arm = open_arm(seed)
    plant = emulator.require_arm_plant()
    stepper = emulator.arm.stepper_hals[1].stepper() if emulator.arm else None
    control = JointController(arm)
    start = list(OUTSTRETCHED)
    start[1] = math.pi / 2 - 0.5
    go(control, start)
    top = list(start)
    top[1] = math.pi / 2 + 0.6
    fastest = encoder_counts_to_rad(max_velocity_counts_per_s(1))
    times: list[float] = []
    points: list[np.ndarray] = []
    capped: list[bool] = []
    rate_cap = max_velocity_counts_per_s(1) * arm.steppers[1].microsteps_per_count

    def track(_state: Any) -> bool:
        times.append(arm.transport.now())
        points.append(plant.flange_position())
        capped.append(stepper is not None
                      and abs(stepper.commanded_rate()) >= 0.99 * rate_cap)
        return False

    go(control, top, speed=fastest, settle_s=0.5, until=track)
    t = np.array(times)
    p = np.array(points)
    arc = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))))
    mask = np.array(capped)
    speed = float(np.polyfit(t[mask], arc[mask], 1)[0]) if mask.sum() > 5 else 0.0
    window = 10
    peak = float(np.max(np.linalg.norm(p[window:] - p[:-window], axis=1)
                        / (t[window:] - t[:-window])))
    slips = int(plant.slips().sum())
    return Outcome("speed", [
        Row("max end-effector speed at the controllers' maximum step rate (§5.6)",
            "1.5 m/s", f"{speed:.2f} m/s (peak over 0.1 s {peak:.2f}; {slips} slips)",
            "±10 %", within(speed, 1.5) and slips == 0, value=speed)],
        {"speed": (t.tolist(), arc.tolist())})


def base_step(seed: int = DEFAULT_SEED, steps: int = 10) -> Outcome:
    """The outstretched arm; J1's goal advanced by one microstep at a time (command_goal,
    1/16 count) ``steps`` times; the flange's travel per step (tracker, 0.1 mm)."""
    emulator, arm = open_arm(seed)
    plant = emulator.require_arm_plant()
    control = JointController(arm)
    state = go(control, OUTSTRETCHED, settle_s=2.0)
    clock = arm.transport
    start = plant.flange_position()
    goal = state.steppers[0].goal
    one = microsteps_to_rad(0, 1)
    for _ in range(steps):
        goal += one
        arm.cycle([arm.make_position(0, goal)])
        for _ in range(30):
            clock.sleep(0.01)
            arm.cycle()
    travel = float(np.linalg.norm(plant.flange_position() - start))
    per_step = round(travel / TRACKER_M) * TRACKER_M / steps * 1000
    count_mm = 2 * math.pi / ARM_ENCODER_COUNTS_PER_REV * float(
        np.linalg.norm(start[:2] - np.array([0.0, 0.0]))) * 1000
    return Outcome("resolution", [
        Row("base stepper: smallest commanded change at the end effector (§5.6)", "0.52 mm",
            f"{per_step:.2f} mm", "±10 %", within(per_step, 0.52), value=per_step),
        Row("base encoder: one count at the outstretched flange (§5.6)", "0.64 mm",
            f"{count_mm:.2f} mm", "±10 %", within(count_mm, 0.64), value=count_mm)])


def _holding(goal: Sequence[float]) -> Callable[[float], tuple[np.ndarray, np.ndarray]]:
    """A trajectory standing at ``goal`` (rad)."""
    q = np.array(goal, dtype=float)

    def trajectory(_t: float) -> tuple[np.ndarray, np.ndarray]:
        return q, np.zeros(N_JOINTS)

    return trajectory


def _ringing_frequency(t: np.ndarray, x: np.ndarray) -> float:
    """Frequency (Hz) of a decaying oscillation from its crossings of the final value (the
    mean of the last quarter; two full periods from the first crossing)."""
    x = x - float(np.mean(x[-max(len(x) // 4, 5):]))
    sign = np.sign(x)
    at = np.flatnonzero(sign[1:] * sign[:-1] < 0)
    if len(at) < 5:
        return float("nan")
    crossings = t[at] + x[at] / (x[at] - x[at + 1]) * (t[at + 1] - t[at])
    return float(2.0 / (crossings[4] - crossings[0]))


def stepper_modes(emulator: Emulator, locked: Sequence[int] = ()) -> list[float]:
    """Natural frequencies (Hz) of the plant's J1..J4 about its present pose, steppers
    standing still, RX-64s rigid: ``K = (I − C)ᵀ·diag(k)·(I − C)`` plus gravity's
    stiffness, ``M`` the joint-space inertia; ``locked`` joints (0..3) held."""
    import mujoco

    plant = emulator.plant
    arm = emulator.require_arm_plant()
    assert plant is not None
    model, data = plant.model, plant.data
    work = mujoco.MjData(model)
    work.qpos[:] = data.qpos
    mujoco.mj_forward(model, work)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, work, full)
    dof = int(model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "arm/J1")])
    n = 4
    mass = full[dof:dof + n, dof:dof + n]
    p = arm.params
    coupled = np.eye(n) - p.coupling
    stiffness = coupled.T @ np.diag(p.stiffness) @ coupled
    gravity = np.zeros((n, n))
    for j in range(n):  # d(bias)/dq by central differences
        for sign in (1.0, -1.0):
            work.qpos[:] = data.qpos
            work.qpos[dof + j] += sign * 1e-5
            mujoco.mj_forward(model, work)
            gravity[:, j] += sign * work.qfrc_bias[dof:dof + n] / 2e-5
    free = [j for j in range(n) if j not in locked]
    k = (stiffness + gravity)[np.ix_(free, free)]
    m = mass[np.ix_(free, free)]
    eig = np.linalg.eigvals(np.linalg.solve(m, k))
    return sorted(float(np.sqrt(max(e.real, 0.0)) / (2 * np.pi)) for e in eig)


def elbow_frequency(seed: int = DEFAULT_SEED) -> Outcome:
    """The forearm plucked (pushed 4 N·m by hand, released) with the elbow stepper standing
    still; the joint read back to back over the bus (~700 Hz).  Held: J2 driven against its
    lower stop (the upper arm cannot move: the single-joint case the dissertation computed,
    f0 = sqrt(k/I)/2π with the forearm's 0.083 kg·m², hanging 20° from vertical, amplitude
    ~2°).  Hanging: J2 held only by its own coupling (200 N·m/rad): the elbow's motion is
    coupled with J2's, two modes (the model's, linearised, reported)."""
    found: dict[str, float] = {}
    traces: dict[str, Any] = {}
    modes: list[float] = []
    for case in ("held", "hanging"):
        emulator, arm = open_arm(seed)
        plant = emulator.require_arm_plant()
        control = JointController(arm, gains=OPEN_LOOP)
        pose = [0.0] * N_JOINTS
        if case == "held":
            pose[1] = -0.40  # 0.05 rad past the stop at -0.35: the coupling presses it there
        go(control, pose, speed=0.3, settle_s=1.5)
        if case == "hanging":
            modes = stepper_modes(emulator, locked=(0, 2))  # J2 and J4, in one plane
        clock = arm.transport
        for k in range(40):
            plant.push(3, 4.0 * (k + 1) / 40)
            clock.sleep(0.005)
        clock.sleep(0.3)
        plant.push(3, 0.0)
        t0 = clock.now()
        times, angles = [], []
        while clock.now() - t0 < 1.5:
            state = arm.cycle()
            times.append(state.t - t0)
            angles.append(state.steppers[3].angle)
        t = np.array(times)
        x = np.array(angles)
        found[case] = _ringing_frequency(t, x)
        traces[case] = (t.tolist(), np.degrees(x).tolist())
    held, hanging = found["held"], found["hanging"]
    mode_text = " and ".join(f"{f:.1f}" for f in modes)
    seen = "too damped to count" if math.isnan(hanging) else f"{hanging:.2f} Hz"
    return Outcome("elbow", [
        Row("elbow natural frequency, upper arm held (§5.3.4)", "5.1 Hz", f"{held:.2f} Hz",
            "±10 %", within(held, 5.1), value=held),
        Row("elbow ringing with J2 on its own coupling (arm hanging)",
            "— (single-joint model)", f"{seen} (J2–J4 modes {mode_text} Hz)", "—",
            None, "the dissertation's f0 assumes the upper arm fixed; hanging, the elbow "
            "couples with J2 (200 N·m/rad, the whole arm's inertia): two modes share the "
            "motion, and the polyurethane's hysteresis and the bearings' stiction damp it "
            "within a period or two", hanging)],
        {"elbow": traces})


def step_responses(seed: int = DEFAULT_SEED) -> Outcome:
    """Figure 5.8: a 10° shoulder step, a 15° elbow step (open loop: the node's own move to
    the goal, feed-forward only; closed loop: the host's PID), a 10° wrist-yaw step (RX-64,
    closed loop in the servo).  Timescales as in the figure: 6 s, 3 s, 0.5 s."""
    cases = (("shoulder", 1, 10.0, 6.0, (0.0, 0.6, 0.0, 0.6, 0.0, 0.0, 0.0)),
             ("elbow", 3, 15.0, 3.0, (0.0, 0.6, 0.0, 0.6, 0.0, 0.0, 0.0)),
             ("wrist yaw", 6, 10.0, 0.5, (0.0, 0.6, 0.0, 0.6, 0.0, 0.0, 0.0)))
    rows: list[Row] = []
    series: dict[str, Any] = {}
    for name, joint, step_deg, window, pose in cases:
        curves = {}
        for loop in (("closed",) if joint >= 4 else ("open", "closed")):
            emulator, arm = open_arm(seed)
            control = JointController(arm, gains=OPEN_LOOP if loop == "open" else None,
                                      rate_hz=None if joint >= 4 else 100.0)
            go(control, pose, settle_s=2.0)
            target = list(pose)
            target[joint] += math.radians(step_deg)
            log = TrackingLog()
            control.run(_holding(target), window, log)
            t = np.array(log.t) - log.t[0]
            angle = np.degrees(np.array(log.measured)[:, joint] - pose[joint])
            curves[loop] = (t.tolist(), angle.tolist())
            final = float(np.mean(angle[t >= 0.8 * window]))
            reached = np.flatnonzero(angle >= 0.9 * final)
            rise = float(t[reached[0]]) if len(reached) else float("inf")
            ok = math.isfinite(rise) and rise < window
            if loop == "closed":
                ok = ok and abs(final - step_deg) <= 0.1 * step_deg
            rows.append(Row(
                f"{name} {step_deg:.0f}° step, {loop} loop: 90 % rise; final (last 20 %)",
                f"reaches the step within the {window:g} s shown (fig. 5.8)",
                f"{rise:.2f} s; {final:.1f}°", "rise < window"
                + ("; final within 10 %" if loop == "closed" else ""), ok,
                "open loop sits off the target by the coupling's sag under gravity"
                if loop == "open" else "", rise))
        series[name] = {"target": step_deg, "window": window, **curves}
    return Outcome("steps", rows, series)


#: Eight distant targets for the repeatability test (rad, J1..J7) and the home pose.
REPEAT_HOME: Final = (0.0, 1.0, 0.0, 1.2, 0.0, 0.3, 0.0)
REPEAT_TARGETS: Final = (
    (0.9, 1.6, 0.3, 0.4, 0.5, -0.3, 0.4), (-0.9, 1.6, -0.3, 0.4, -0.5, -0.3, -0.4),
    (0.6, 0.4, 0.8, 1.8, 0.0, 0.6, 0.0), (-0.6, 0.4, -0.8, 1.8, 0.0, 0.6, 0.0),
    (1.4, 2.2, 0.0, 0.9, 0.8, 0.0, 0.8), (-1.4, 2.2, 0.0, 0.9, -0.8, 0.0, -0.8),
    (0.3, 0.2, 0.5, 0.3, 1.0, -0.8, 0.2), (-0.3, 0.2, -0.5, 0.3, -1.0, -0.8, -0.2))


def repeatability(seed: int = DEFAULT_SEED, rounds: int = 1, speed: float = 0.6,
                  settle_timeout_s: float = 12.0) -> Outcome:
    """Figure 5.7: closed loop, home ↔ eight distant locations (minimum-jerk paths, slowing
    into each goal); the flange at home after each return, once the host's PID has settled
    there (encoders within two counts), from the plant rounded to the tracker's 0.1 mm.
    Repeatability as the largest distance from the points' mean (and ISO 9283's mean +
    3σ)."""
    emulator, arm = open_arm(seed)
    plant = emulator.require_arm_plant()
    control = JointController(arm)
    home = np.array(REPEAT_HOME)
    count = 2 * math.pi / ARM_ENCODER_COUNTS_PER_REV

    def settled(state: Any) -> bool:
        """The host's own test: steppers within two counts of home (the PID rests within
        its one-count deadband; the encoder reads whole counts) and still, servos within
        their compliance margin (0.34°)."""
        error = np.abs(home - np.array(state.joints))
        return bool(np.all(error[:4] <= 2.01 * count) and np.all(error[4:] <= 0.006)
                    and all(abs(s.velocity) < 0.002 for s in state.steppers))

    go(control, REPEAT_HOME, speed=speed, settle_s=3.0)
    points = []
    stalls = TrackingLog()
    unsettled = 0
    for _ in range(rounds):
        for target in REPEAT_TARGETS:
            go(control, target, speed=speed, settle_s=1.0, log=stalls, smooth=True)
            go(control, REPEAT_HOME, speed=speed, settle_s=0.0, log=stalls, smooth=True)
            state = control.run(lambda _t: (home, np.zeros(N_JOINTS)), settle_timeout_s,
                                stalls, until=settled)
            unsettled += not settled(state)
            points.append(np.round(plant.flange_position() / TRACKER_M) * TRACKER_M)
    p = np.array(points)
    distance = np.linalg.norm(p - p.mean(axis=0), axis=1) * 1000
    spread = float(distance.max())
    iso = float(distance.mean() + 3 * distance.std())
    slips = int(plant.slips().sum())
    ok = 0.0 < spread <= 3.0 and slips == 0 and not stalls.stall_events and not unsettled
    return Outcome("repeatability", [Row(
        "repeatability, home ↔ 8 distant locations, closed loop (§5.6, fig. 5.7)", "3 mm",
        f"{spread:.2f} mm (ISO 9283 {iso:.2f} mm; {slips} slips, "
        f"{len(stalls.stall_events)} stalls, {unsettled} unsettled)", "> 0 and ≤ 3 mm", ok,
        "modelled: 0.036° encoders, polyurethane hysteresis, bearing stiction, slips, RX-64 "
        "pots; not: plywood creep, temperature, cable stretch - the real arm's 3 mm bounds "
        "the emulator's from above", spread)],
        {"repeatability": ((p - p.mean(axis=0)) * 1000).tolist()})


# ----------------------------------------------------------------------------- the hand


def finger_deadband(seed: int = DEFAULT_SEED) -> Outcome:
    """Finger 0 of the hand moved to joint targets through the host (palm link): how far
    the plant's joints stop from them."""
    from host.hand.facade import Hand

    emulator = Emulator("hand", seed=seed)
    bring_up(emulator)
    hand = Hand.open(EmulatorTransport(emulator, "palm"))
    worst = 0.0
    try:
        finger = hand.fingers[0]
        plant = emulator.finger_plants[0]
        for target in ((0.0, 0.5, 0.4), (0.2, 0.9, 0.7), (-0.2, 0.3, 0.2)):
            finger.move(target, timeout=4.0, unhomed=True)
            hand.session.transport.sleep(1.0)  # the host's settle test allows a margin
            q = plant.joint_angles()
            worst = max(worst, *(abs(a - b) for a, b in zip(q, target, strict=True)))
    finally:
        hand.close()
    deg = math.degrees(worst)
    return Outcome("finger", [Row("finger joints reach their targets", "—",
                                  f"worst {deg:.2f}° off", "≤ 0.5°", deg <= 0.5,
                                  "fmcb deadband 8 hall counts", deg)])


def tactile_coin(seed: int = DEFAULT_SEED, cycles: int = 4) -> Outcome:
    """Figure 6.11: a 2 g coin (0.0196 N) put on and taken off the distal pad repeatedly;
    the taxels read through the host; the loaded step over the unloaded noise (1 σ)."""
    from host.hand.facade import Hand

    emulator = Emulator("hand", seed=seed)
    bring_up(emulator)
    hand = Hand.open(EmulatorTransport(emulator, "palm"))
    plant = emulator.finger_plants[0]
    clock = hand.session.transport
    samples: list[tuple[float, bool, list[int]]] = []
    try:
        finger = hand.fingers[0]
        for k in range(2 * cycles):
            loaded = k % 2 == 1
            plant.press("F3", 0.002 * 9.81 if loaded else 0.0)
            end = clock.now() + 1.0
            while clock.now() < end:
                state = finger.status()
                samples.append((clock.now(), loaded, list(state.tactile["distal"])))
                clock.sleep(0.02)
    finally:
        plant.press("F3", 0.0)
        hand.close()
    t = np.array([s[0] for s in samples])
    on = np.array([s[1] for s in samples])
    taxels = np.array([s[2] for s in samples], dtype=float)
    phase = np.floor((t - t[0]) / 1.0).astype(int)
    start = np.array([t[phase == k].min() for k in phase])
    settled = t - start >= 0.3  # each phase after the pad has settled
    base = taxels[~on & settled]
    load = taxels[on & settled]
    step = load.mean(axis=0) - base.mean(axis=0)
    best = int(np.argmax(np.abs(step)))
    # the noise floor: the spread within each unloaded phase (drift between phases apart)
    noise = float(np.median([taxels[(phase == k) & settled, best].std()
                             for k in sorted(set(phase[~on].tolist()))])) or 1.0
    snr = abs(float(step[best])) / noise
    return Outcome("tactile", [Row(
        "tactile: 2 g coin on the pad over the noise floor (fig. 6.11)",
        "far above the noise floor", f"{abs(step[best]):.0f} counts, {snr:.0f}× noise σ",
        "≥ 10× σ", snr >= 10.0, value=snr)],
        {"tactile": ((t - t[0]).tolist(), taxels[:, best].tolist(), on.tolist())})


#: Every experiment, in table order: name → function(seed).
def inertial_calibration(seed: int = DEFAULT_SEED) -> Outcome:
    """§4.6.1 on the hand as built: the thumb's joint estimates along a trajectory of
    held-out poses, before and after its calibration, on three seeds after ``seed + 1``
    (the calibration's tests use seeds 1 and 2): :mod:`tools.experiments.hand_calibration`."""
    from tools.experiments import hand_calibration as hc

    results = [hc.measure_seed(s) for s in range(seed + 2, seed + 5)]
    before = np.mean([r.mean_abs("before") for r in results], axis=0)
    after = np.mean([r.mean_abs("after") for r in results], axis=0)
    ratio = float(np.mean(before)) / float(np.mean(after))
    lo, hi = hc.BEFORE_RANGE_DEG
    joints = "J0/J1/J2 "
    seeds = f"seeds {results[0].seed}–{results[-1].seed}"
    return Outcome("calibration", [
        Row("thumb joint estimate, uncalibrated: mean |error|", "0.965/0.926/1.590° "
            "(PR2 Alpha, §4.6.1)", f"{float(np.mean(before)):.2f}° ({joints}"
            + "/".join(f"{v:.2f}" for v in before) + f", {seeds})", f"{lo:g}–{hi:g}°",
            lo <= float(np.mean(before)) <= hi, value=float(np.mean(before))),
        Row("thumb joint estimate, calibrated, held-out poses", "—",
            f"{float(np.mean(after)):.2f}° ({joints}" + "/".join(f"{v:.2f}" for v in after)
            + f"): {ratio:.1f}× better", f"≥{hc.IMPROVEMENT:g}× better",
            ratio >= hc.IMPROVEMENT, "the calibration rests each joint on a mechanical stop, "
            "exact in the emulator: a real build's stop tolerance adds to this "
            "(docs/decisions/calibration.md)", ratio),
    ])


def arm_calibration(seed: int = DEFAULT_SEED) -> Outcome:
    """Figure 4.4 on the arm as built: the flange's error on held-out board touches from the
    CAD model and from the touch calibration, on two seeds after ``seed + 1``
    (:mod:`tools.experiments.arm_calibration`; touches synthesised from the built arm)."""
    from tools.experiments import arm_calibration as ac

    results = [ac.run_seed(s) for s in range(seed + 2, seed + 4)]
    before = float(np.mean([r.raw_before_mean_mm for r in results]))
    after = float(np.mean([r.anchored_mean_mm for r in results]))
    worst = max(r.anchored_max_mm for r in results)
    seeds = f"seeds {results[0].seed}–{results[-1].seed}"
    d0, d1 = ac.DISSERTATION_MM
    return Outcome("arm-calibration", [
        Row("arm end effector, CAD model: mean error on held-out touches",
            f"{d0:g} mm (fig. 4.4)", f"{before:.1f} mm ({seeds})", "3–30 mm",
            3.0 <= before <= 30.0, "", before),
        Row("arm end effector, calibrated: mean error on held-out touches",
            f"{d1:g} mm (fig. 4.4)", f"{after:.2f} mm (max {worst:.2f})", "≤ 2 mm",
            after <= 2.0, "board, table and two anchor dimples (docs/HOST.md); the touches "
            "are synthesised from the built arm, not made by guarded moves", after),
    ])


EXPERIMENTS: Final[dict[str, Callable[[int], Outcome]]] = {
    "lift": lift_unloaded, "stall": stall_still_trips, "holding": holding_ratio,
    "payload": payload, "speed": max_speed, "resolution": base_step,
    "elbow": elbow_frequency, "steps": step_responses, "repeatability": repeatability,
    "finger": finger_deadband, "tactile": tactile_coin, "calibration": inertial_calibration,
    "arm-calibration": arm_calibration,
}


@guard_output("hil-bench experiments")
def main(argv: Sequence[str] | None = None) -> int:
    """``hil-bench experiments [--json] [--report DIR] [--only NAME …] [--seed N]``."""
    parser = argparse.ArgumentParser(prog="hil-bench experiments", description=__doc__.split(
        "\n")[0])
    parser.add_argument("--json", action="store_true", help="print the rows as JSON")
    parser.add_argument("--report", metavar="DIR", help="write DIR/experiments.md and plots")
    parser.add_argument("--only", nargs="+", choices=sorted(EXPERIMENTS), help="run these")
    parser.add_argument("--seed", type=int, default=DEFAULT_SEED)
    args = read_negative_numbers(parser).parse_args(argv)
    outcomes = [EXPERIMENTS[name](args.seed) for name in (args.only or EXPERIMENTS)]
    rows = [r for o in outcomes for r in o.rows]
    if args.json:
        print(json.dumps([asdict(r) for r in rows], indent=1))
    else:
        print(table(rows))
    if args.report:
        print(f"report: {report(outcomes, Path(args.report))}", file=sys.stderr)
    return 0 if all(r.passed is not False for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
