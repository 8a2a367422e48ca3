"""``make demo``: the robot picks up a coffee mug, on the built-in emulator.

::

    python -m tools.demo [--out DIR] [--seed N] [--sensors realistic|ideal] [--realtime]
                         [--view [--view-port N]]

On the emulator's ``full`` configuration (the hand on the arm's wrist) with the ``mug``
scene (a table in front of the arm, a 0.3 kg coffee mug on it), the demo does what a user
would, with the host library and the command-line tools:

1. **emulator**: starts it (the hand brought up: thirteen MCUs running);
2. **firmware**: builds demo images with ``fwimage build`` (version :data:`FW_VERSION`) and
   flashes all twelve finger MCUs with ``flash-all-fingers``;
3. **homing**: the arm at its encoders' index marks (``Arm.home``), then the hand from its
   accelerometers (``Hand.home``) in two wrist tilts (:data:`protocol.robot.HOMING_WRIST_TILTS`): the three
   parallel fingers' axes are observable in one, the thumb's in the other.  In each tilt,
   before homing them, the fingers' accelerometers are calibrated
   (:func:`host.hand.calibration.calibrate_fingers`: each finger through its poses and onto
   its stops; the fit of every board's mounting, bias and scale, used by the homing and
   written to ``OUT/calibration.json``); on an emulator with ``--sensors ideal`` there is
   nothing to calibrate;
4. **reach**: the hanging arm turns its upper arm and wrist, raises the hand to a ready
   pose in front of the table's edge (joint moves), and brings it to the mug from the side
   (``Arm.moveto``): the palm upright, its face towards the mug, the fingers open along the
   mug's side and the thumb beside it, then in until the mug's body is between them;
5. **grasp**: a prismatic grasp (the finger pads against the thumb) closing until the
   tactile pads report contact (``Hand.grasp(..., until_contact=True)``; the fingers, then
   the thumb), then squeezing (:func:`host.hand.grasp.squeeze`: each finger's proximal flexion
   motor sent :data:`SQUEEZE_RAD` past the contact, so its effort cap keeps the grip through
   the lift and the hold);
6. **lift**: the flange up :data:`LIFT_M`, held :data:`HOLD_S`; **put down**: lowered,
   feeling for the table with the stepper joints' torques (:data:`SET_DOWN_FROM_M`), the
   hand opened and withdrawn; **park**: back to the ready pose and hanging;
7. **report**: the session's MCAP recordings (hand frames, states, finger readings and
   events, arm bus and states; from the firmware step on, the hand's state read at
   :data:`tools.demo.watch.HAND_STATE_HZ` while the arm moves) and a Markdown report with
   plots over the whole session (:mod:`tools.demo.report`).  In process, the mug's slip in
   the hand is watched on the physics (:class:`tools.demo.watch.MugInHand`): more than
   :data:`tools.demo.watch.SLIP_M` fails the demo.

Every step prints one line with the simulated and the wall time.  By default the emulator
runs in this process on the simulation clock (``emu://…``: deterministic, and as reliable
on a busy machine as on an idle one); ``--realtime`` runs the same script against a
``hil-emulator`` subprocess through its ptys, paced to the wall clock, after identifying
the thirteen hand MCUs and pinging the arm with the stock dynamixel-sdk over the wire.
``--view`` serves a live view of the robot (the hand on the arm) in a browser while the
demo runs and prints its address (:mod:`host.view.live`).

Success is judged on the plant's ground truth (the mug's height in the physics, not what
the robot's sensors say): the mug rose at least :data:`MIN_LIFT_M` and stands on the table
again.  The last line is ``demo: OK (...)`` (exit 0) or ``demo: FAILED (<step>: <reason>)``
(exit 1); never a traceback.

**Torque.**  The plan keeps every stepper joint well inside what it holds: the nodes latch
STALLED (the OVERLOAD alarm) when the elastic deflection passes ``deflection_limit`` (150
counts: 8.1 N·m at the elbow J4, 18.8 N·m at the shoulder J2), which a horizontal forearm
with the 1 kg hand and the mug nearly reaches.  So the upper arm is rolled (J3) and the
forearm hangs steeply, the wrist holding the palm upright (:data:`GRASP_SEED_Q` picks that
arm configuration): the mug up, J4 carries about 4.7 N·m, J2 8 N·m, J3 5 N·m.  Moves are
slow (:data:`JOINT_SPEED_RAD_S`, :data:`NEAR_SPEED_RAD_S`), so dynamics add little.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from host.arm.facade import Arm
from host.arm.joint_loop import JointController, TrackingLog
from host.arm.kinematics import forward, solve_ik
from host.arm.recording import ArmRecorder
from host.arm.state import ArmState
from host.arm.trajectory import Trajectory, timed_path
from host.estimation.calibration_file import save_section
from host.estimation.hand_calibration import FingerFit, HandCalibration
from host.hand.calibration import calibrate_fingers
from host.hand.facade import Hand
from host.hand.grasp import squeeze
from host.hand.homing import FingerMovingError, HomeResult
from host.hand.recording import HandRecorder
from host.hand.state import FingerState, HandState
from host.hand.synergies import finger_roles
from host.view.live import RobotView, open_view
from protocol.control_tables import STEPPER_TABLE
from protocol.robot import HOMING_WRIST_TILTS
from protocol.topology import FINGER_BOARDS, FINGERS
from tools.demo.plan import (
    APPROACH_M,
    FW_VERSION,
    GRASP_AMOUNT,
    GRASP_EFFORT,
    GRASP_SEED_Q,
    GRASP_SPEED_RAD_S,
    GRASP_SYNERGY,
    HOLD_S,
    HOMING_ATTEMPTS,
    HOMING_RETRY_S,
    JOINT_SPEED_RAD_S,
    LIFT_M,
    MIN_LIFT_M,
    NEAR_SPEED_RAD_S,
    READY_BACK_M,
    READY_UP_M,
    SET_DOWN_FROM_M,
    SET_DOWN_HOLD_S,
    SET_DOWN_LOAD_NM,
    SET_DOWN_M,
    SET_DOWN_PRESS_M,
    SET_DOWN_SPEED_RAD_S,
    SET_DOWN_TILT_RAD,
    SQUEEZE_RAD,
    STEPPER_CURRENT_MA,
    THUMB_CLEAR_Q,
    FlangePose,
    flange_pose,
)
from tools.demo.report import Log, write_report
from tools.demo.watch import SLIP_M, HandSampler, MugInHand, felt
from tools.errors import DemoFailed

#: The hand's calibration file the demo writes in its output directory.
CALIBRATION_FILE = "calibration.json"
#: The hand's fall reported for the put-down: the most it fell in this long (s).
FALL_WINDOW_S = 0.3


def ready_joints() -> tuple[float, ...]:
    """Joint angles (rad) of the ready pose (:data:`READY_BACK_M`, :data:`READY_UP_M`), in
    the grasp's arm configuration (:data:`GRASP_SEED_Q`); :class:`DemoFailed` if the
    inverse kinematics cannot reach it."""
    grasp = flange_pose()
    at_mug = solve_ik(grasp.xyz, grasp.rpy, q0=GRASP_SEED_Q)
    ready = flange_pose(READY_BACK_M, READY_UP_M)
    ik = solve_ik(ready.xyz, ready.rpy, q0=at_mug.q)
    if not (at_mug.converged and ik.converged):
        raise DemoFailed("reach", "no joint angles reach the ready pose in the grasp's arm "
                                  "configuration")
    return tuple(float(q) for q in ik.q)




class Demo:
    """One run: the robot's links, the log, the step printer."""

    def __init__(self, hand: Hand, arm: Arm, out: Path, *, truth: Any = None,
                 palm_port: str = "", reopen_hand: Callable[[], Hand] | None = None) -> None:
        self.hand = hand
        #: Through a pty the palm port is the demo's own (an exclusive lock): it closes its
        #: hand while ``flash-all-fingers`` has the port, as a user would, and opens it again
        #: with this.  None: the port can be shared (the in-process emulator).
        self.reopen_hand = reopen_hand
        self.arm = arm
        self.out = out
        self.truth = truth  # a MugTracker (in process) or None (ground truth at the end)
        self.palm_port = palm_port
        self.log = Log()
        self.wall0 = time.monotonic()
        self.step = "start"
        self.sampler = HandSampler(hand)
        #: Calibrate the hand's accelerometers before homing it (the robot as built); an
        #: emulated robot with ideal sensors needs none.
        self.calibrate = True
        #: The arm's kinematic calibration the Cartesian moves use (``armctl calibrate``'s
        #: file): None for this arm's own file when there is one, ``"none"`` for the CAD
        #: model, or a file's path (:meth:`host.arm.facade.Arm.load_calibration`).
        self.arm_calibration: str | None = None
        self.mug_in_hand: MugInHand | None = None
        #: The session's hand recording (:func:`run_session`), kept on the hand when its
        #: link is opened again.
        self.hand_recorder: HandRecorder | None = None
        arm.state_taps.append(self._on_arm)
        self._watch_hand()

    def _watch_hand(self) -> None:
        """Take every reading of :attr:`hand` (again, after its link was opened again)."""
        self.sampler = HandSampler(self.hand)
        self.hand.state_taps.append(self._on_hand)
        self.hand.finger_taps.append(self._on_fingers)
        if self.hand_recorder is not None and self.hand_recorder.hand is not self.hand:
            self.hand_recorder.attach(self.hand)

    # ------------------------------------------------------------------ printing, logging
    def now(self) -> float:
        return self.hand.session.now()

    def say(self, text: str) -> None:
        wall = time.monotonic() - self.wall0
        sim = self.now()
        self.log.steps.append((self.step, sim, wall, text))
        print(f"[sim {sim:6.1f} s | wall {wall:6.1f} s] {self.step}: {text}", flush=True)

    def begin(self, step: str, text: str) -> None:
        self.step = step
        self.log.phases.append((step, self.now()))
        self.say(text)

    def _on_arm(self, state: ArmState) -> None:
        self.log.arm.append(state)
        self._sample_truth(state.t)
        self.sampler.poll()  # the hand's state while the arm moves (never waited for)

    def _sample_truth(self, t: float) -> None:
        if self.mug_in_hand is not None:
            self.mug_in_hand.sample(t)

    def _on_hand(self, state: HandState) -> None:
        self.log.hands.append(state)
        for f in state.fingers:
            if f.present:
                self.log.fingers.append((state.t, f.index, f))
        self._sample_truth(state.t)

    def _on_fingers(self, t: float, states: Mapping[int, FingerState]) -> None:
        for k, s in states.items():
            self.log.fingers.append((t, k, s))
        self._sample_truth(t)

    def rest(self, seconds: float, rate_hz: float = 100.0) -> None:
        """Let ``seconds`` pass (the link's clock) with the arm cycling at ``rate_hz``:
        it holds (or hangs), and its state and the hand's are recorded meanwhile."""
        t_end = self.now() + seconds
        while (left := t_end - self.now()) > 1e-6:
            self.arm.cycle()
            self.hand.session.sleep(min(left, 1.0 / rate_hz))

    def sample_hand(self, seconds: float, rate_hz: float = 20.0) -> None:
        """Read the hand's state at ``rate_hz`` for ``seconds`` (the recording and the log
        take each read); the arm keeps holding (one cycle per reading)."""
        self.sampler.finish()
        t_end = self.now() + seconds
        while self.now() < t_end:
            self.hand.status()
            self.arm.cycle()
            self.hand.session.sleep(max(0.0, 1.0 / rate_hz - 0.01))

    # ------------------------------------------------------------------ steps
    def firmware(self) -> None:
        from tools.cli import flash_all_fingers, fwimage

        self.begin("firmware", f"building demo images {FW_VERSION} (fwimage build)")
        fw = self.out / "firmware"
        fw.mkdir(parents=True, exist_ok=True)
        args: list[str] = []
        for board in (b.app for b in FINGER_BOARDS):
            payload = fw / f"{board}.bin"
            payload.write_bytes((f"{board} demo firmware {FW_VERSION}\n".encode() * 64)[:4096])
            image = fw / f"{board}.img"
            status, _ = _quiet(fwimage.main, ["build", "--board", board, "--version",
                                              FW_VERSION, "--input", str(payload),
                                              "-o", str(image)])
            if status != 0:
                raise DemoFailed("firmware", f"fwimage build --board {board} failed")
            args += [f"--{board}", str(image)]
        self.say("flashing all twelve finger MCUs (flash-all-fingers)")
        if self.reopen_hand is not None:
            self.sampler.finish()
            self.hand.close()  # flash-all-fingers takes the port for itself
        try:
            status, text = _quiet(flash_all_fingers.main, ["--port", self.palm_port, "--json",
                                                           *args])
        finally:
            if self.reopen_hand is not None:
                self.hand = self.reopen_hand()
                self._watch_hand()
        try:
            report = json.loads(text.strip().splitlines()[-1])
        except (ValueError, IndexError):
            report = {}
        if status != 0:
            raise DemoFailed("firmware", f"flash-all-fingers exit status {status}: "
                                         f"{text.strip()[-300:]}")
        nodes = report.get("nodes", [])
        results = sorted({str(n.get("result")) for n in nodes})
        self.say(f"{len(nodes)} nodes now run {FW_VERSION} ({', '.join(results)}; "
                 f"{report.get('total_seconds', 0):.1f} s)")
        self.log.result["flashed_nodes"] = len(nodes)
        # The fingers rebooted into the new images: power their phalanges and start the
        # fmcbs' polling of them again, as after power-up.
        for finger in self.hand.fingers:
            finger.motor.request("fmcb.phalange_power", {"on": 1})
        self.rest(3.5)
        for finger in self.hand.fingers:
            finger.motor.request("fmcb.autopoll", {"on": 1})

    def home(self) -> None:
        arm = self.arm
        self.begin("homing", f"arm: steppers at {STEPPER_CURRENT_MA} mA, torque on, "
                             "searching each stepper's index mark")
        current = STEPPER_CURRENT_MA.to_bytes(2, "little")
        for register in ("run_current", "holding_current"):
            arm.bus.sync_write(STEPPER_TABLE[register].address, 2,
                               {j.dxl_id: current for j in arm.steppers})
        arm.torque(True)
        calibration = arm.home()
        self.say("arm homed; index offsets (rad): "
                 + ", ".join(f"{o:+.3f}" for o in calibration.offsets[:4]))
        chosen = arm.load_calibration(self.arm_calibration)
        for warning in chosen.warnings:
            self.say(f"arm: warning: {warning}")
        self.say(f"arm: {chosen.summary()}")
        self.log.result["arm_calibration"] = chosen.to_dict()
        homed: dict[int, bool] = {}
        hand_cal = HandCalibration(source=str(self.out / CALIBRATION_FILE))
        fits: dict[int, FingerFit] = {}
        for (j6, j7), fingers in HOMING_WRIST_TILTS:
            self._move((0.0, 0.0, 0.0, 0.0, 0.0, j6, j7), 4.0)
            self.rest(2.0)  # the elastic arm and the fingers come to rest
            fitted: dict[int, FingerFit] = {}
            if self.calibrate:
                found, fitted = calibrate_fingers([self.hand.fingers[k] for k in fingers])
                hand_cal.boards.update(found.boards)
                fits.update(fitted)
                self.hand.calibration = hand_cal
            for k in fitted:
                tilts = ", ".join(f"{b} {math.degrees(float(np.linalg.norm(c.rotation_vector))):.1f}°"
                                  for b, c in fitted[k].boards.items())
                self.say(f"hand: finger {k}'s accelerometers calibrated "
                         f"({fitted[k].poses} poses, residual {fitted[k].rms_counts:.1f} mg; "
                         f"mounting tilts {tilts})")
            for k in fingers:
                result = self._home_finger(k)
                homed[k] = result.homed
                q = ", ".join(f"{v:+.2f}" for v in result.joints or ())
                self.say(f"hand: wrist tilted J6 {j6:+.1f} J7 {j7:+.1f} rad; finger {k} "
                         f"homed from its accelerometers at ({q}) rad")
        missing = [k for k, ok in homed.items() if not ok]
        if missing:
            raise DemoFailed("homing", f"fingers {missing} not homed")
        if not self.calibrate:
            self.say("hand: ideal sensors, nothing to calibrate")
            return
        serial = self.hand.serial()
        save_section(self.out / CALIBRATION_FILE, serial, "hand",
                     hand_cal.to_section(fits=fits), replace_other_robot=True)
        self.say(f"hand: calibration of robot {serial} written to "
                 f"{self.out / CALIBRATION_FILE}")

    def _home_finger(self, k: int) -> HomeResult:
        """Home finger ``k``; a finger still swaying after the wrist's tilt
        (:class:`FingerMovingError`) is given :data:`HOMING_RETRY_S` more to rest, up to
        :data:`HOMING_ATTEMPTS` tries, as one would at the bench."""
        for attempt in range(1, HOMING_ATTEMPTS + 1):
            try:
                return self.hand.home(k)[0]
            except FingerMovingError as exc:
                if attempt == HOMING_ATTEMPTS:
                    raise
                self.say(f"hand: finger {k} still moving ({exc}); "
                         f"waiting {HOMING_RETRY_S:.0f} s")
                self.rest(HOMING_RETRY_S)
        raise AssertionError("unreachable")

    def _move(self, pose: tuple[float, ...], timeout: float) -> None:
        """A joint-space move of the nodes themselves at :data:`JOINT_SPEED_RAD_S` on every
        joint (for the servos' homing tilts: the steppers stay where they are), through the
        arm's gate (:mod:`host.arm.gate`) like every motion."""
        self.arm.move(list(pose), speed=JOINT_SPEED_RAD_S, timeout=timeout)
        self._check_arm()

    def _joint_path(self, pose: tuple[float, ...], settle_s: float = 4.0) -> None:
        """A straight joint-space move to ``pose`` (rad) under the host's joint controller
        (the fastest joint at :data:`JOINT_SPEED_RAD_S`, every joint arriving together),
        then held until the joints are still there.  The controller, not the nodes' own
        goals: it cancels the belt and cable routes' coupling (rolling the upper arm turns
        the elbow's capstan) and keeps the nodes' stall watch on the elastic elements."""
        control = JointController(self.arm)
        state = control.start()
        log = TrackingLog()
        trajectory = Trajectory(timed_path([state.joints, pose], JOINT_SPEED_RAD_S))
        control.run(trajectory, trajectory.duration, log)
        goal = np.asarray(pose, dtype=float)

        def still(s: ArmState) -> bool:
            near = float(np.max(np.abs(np.asarray(s.joints) - goal))) < 0.02
            return near and all(abs(j.velocity) < 0.05 for j in s.steppers)

        control.run(lambda _t: (goal, np.zeros(len(goal))), settle_s, log, until=still)
        self._check_arm(log)

    def _check_arm(self, log: TrackingLog | None = None) -> None:
        """:class:`DemoFailed` if a joint reports an alarm now, or stalled during a
        controlled move (``log``; the controller clears a stall and goes on)."""
        state = self.arm.state()
        errors = {k: v for k, v in state.errors.items() if v}
        stalls = [] if log is None else log.stall_events
        for name in sorted(set(stalls)):
            errors.setdefault(name, []).append(
                f"STALLED {stalls.count(name)}× (cleared by the controller)")
        if errors:
            raise DemoFailed(self.step, f"arm alarms {errors} (joints "
                             f"{[round(q, 2) for q in state.joints]} rad)")

    def _moveto(self, target: FlangePose, what: str,
                speed: float = NEAR_SPEED_RAD_S,
                controller: JointController | None = None) -> None:
        log = TrackingLog()
        result = self.arm.moveto(list(target.xyz), list(target.rpy), speed=speed, log=log,
                                 controller=controller)
        self._check_arm(log)
        if not result.reached and result.position_error > 0.01:
            raise DemoFailed(self.step, f"{what}: the flange stopped "
                             f"{result.position_error * 1000:.0f} mm from its target")
        self.say(f"{what}: flange at {_fmt(target.xyz)} m (base frame), "
                 f"{result.position_error * 1000:.1f} mm off")

    def _thumb_clear(self) -> None:
        """Bend the opposing finger back (:data:`THUMB_CLEAR_Q`)."""
        roles = finger_roles(self.hand.layout)
        self.hand.move_fingers({k: THUMB_CLEAR_Q for k, role in enumerate(roles)
                                if role == "opposing"})

    def _truth(self) -> None:
        """In process: where the mug is (the physics' ground truth)."""
        if self.truth is not None:
            moved = self.truth.position - self.truth.start
            self.say(f"mug {_fmt(moved * 100)} cm from its place, tilted "
                     f"{math.degrees(self.truth.tilt_rad):.0f}° (ground truth)")

    def reach(self) -> None:
        ready = ready_joints()
        wrist = (0.0, 0.0, ready[2], 0.0, *ready[4:])
        self.begin("reach", "upper arm rolled and wrist turned while hanging, then the hand "
                            "raised to the ready pose in front of the table")
        self._joint_path(wrist)
        self._joint_path(ready)
        self.hand.grasp("open", 1.0, speed=2.0)
        self._thumb_clear()
        self._moveto(flange_pose(APPROACH_M), "beside the mug, the palm facing it",
                     speed=0.4)
        self._moveto(flange_pose(), "round the mug")
        self._truth()

    def grasp(self) -> None:
        self.begin("grasp", f"{GRASP_SYNERGY} grasp, closing at {GRASP_SPEED_RAD_S} rad/s "
                            "until the tactile pads report contact: the fingers on the "
                            "mug's side first, then the thumb against it")
        roles = finger_roles(self.hand.layout)
        fingers = [k for k, role in enumerate(roles) if role != "opposing"]
        thumbs = [k for k, role in enumerate(roles) if role == "opposing"]
        contacts: dict[int, str] = {}
        self.sampler.finish()
        self.log.touch_baseline = self.hand.finger_states(range(FINGERS))
        for group in (fingers, thumbs):
            result = self.hand.grasp(GRASP_SYNERGY, GRASP_AMOUNT, speed=GRASP_SPEED_RAD_S,
                                     fingers=group, until_contact=True, effort=GRASP_EFFORT)
            contacts.update(result.contacts)
        for k in range(FINGERS):
            self.say(f"finger {k} closing: "
                     f"{contacts.get(k, 'reached its target without feeling contact')}")
        if not contacts:
            raise DemoFailed("grasp", "no finger felt the mug")
        self.log.result["contacts"] = dict(contacts)
        # Contact stops a finger where it touched, and a finger at its target presses with
        # no force: squeeze, every finger's proximal flexion motor sent past its pose (the
        # mug stops it), so it presses with its effort cap through the lift and the hold.
        self.say(f"squeezing ({SQUEEZE_RAD:g} rad of J1 past the contact, effort "
                 f"{GRASP_EFFORT}/255)")
        squeeze(self.hand, None, SQUEEZE_RAD, effort=GRASP_EFFORT)
        held = felt(self.hand.finger_states(range(FINGERS)), self.log.touch_baseline)
        for k, text in held.items():
            self.say(f"finger {k} holding: {text} (against its reading before the grasp)")
        self.log.result["holding"] = {str(k): text for k, text in held.items()}
        self._truth()

    def lift(self) -> None:
        self.begin("lift", f"up {LIFT_M * 100:.0f} cm")
        self._moveto(flange_pose(up_m=LIFT_M), "lifted")
        self.say(f"holding {HOLD_S:g} s")
        self.sample_hand(HOLD_S)
        if self.truth is not None:
            lift = float(self.truth.position[2] - self.truth.start[2])
            self.log.result["held_lift_m"] = lift
            self.say(f"mug {lift * 100:+.1f} cm from its place on the table (ground truth)")
            if lift < MIN_LIFT_M:
                raise DemoFailed("lift", f"the mug is not in the hand: {lift * 100:+.1f} cm "
                                         f"from its place, tilted "
                                         f"{math.degrees(self.truth.tilt_rad):.0f}° "
                                         f"(ground truth)")
        self.begin("put down", "lowering the mug until the table takes its weight")
        self._set_down()
        self._slip()
        self.sampler.finish()
        self.hand.grasp("open", 1.0, speed=1.5)
        self._thumb_clear()
        self.say("hand opened")
        self._moveto(flange_pose(APPROACH_M), "hand withdrawn from the mug")
        self._truth()

    def _set_down(self) -> None:
        """Lower the held mug onto the table, feeling for it (:data:`SET_DOWN_FROM_M`): a
        slow guarded move (``Arm.moveto(..., until=...)``) that stops the cycle the
        stepper joints' torques say the table carries the mug, and holds there."""
        control = JointController(self.arm)
        log = TrackingLog()
        self._moveto(flange_pose(up_m=SET_DOWN_FROM_M), "above the table",
                     controller=control)
        assert control.state is not None
        held = self._stepper_torques(control.state)

        def touched(s: ArmState) -> bool:
            return float(np.linalg.norm(self._stepper_torques(s) - held)) >= SET_DOWN_LOAD_NM

        bottom = flange_pose(up_m=-SET_DOWN_PRESS_M)
        result = self.arm.moveto(list(bottom.xyz), list(bottom.rpy),
                                 speed=SET_DOWN_SPEED_RAD_S, settle_timeout=SET_DOWN_HOLD_S,
                                 controller=control, log=log, until=touched)
        self._check_arm(log)
        height = float(forward(result.state.joints).position[2] - flange_pose().xyz[2])
        self.log.result["set_down_above_grasp_m"] = height
        if result.stopped:
            self.say(f"set down: the table took the mug with the flange {height * 1000:+.0f} "
                     f"mm from the grasp's height (the steppers' torques changed by "
                     f"{SET_DOWN_LOAD_NM:g} N·m or more)")
        else:
            self.say(f"set down: the flange {height * 1000:+.0f} mm from the grasp's height "
                     f"without feeling the table")

    @staticmethod
    def _stepper_torques(state: ArmState) -> np.ndarray:
        """The stepper joints' torques in ``state`` (N·m, J1..J4, from their elastic
        deflections)."""
        return np.array([j.torque for j in state.steppers])

    def _slip(self) -> None:
        """In process: how far the mug moved in the hand while off the table, and how the
        hand itself fell (the physics' ground truth); :class:`DemoFailed` for a slip."""
        watch = self.mug_in_hand
        if watch is None:
            return
        slip = watch.slip_m
        self.log.result["slip_m"] = slip
        lifted = next((t for name, t in self.log.phases if name == "lift"), 0.0)
        fall, at = fastest_fall([row for row in watch.samples if row[0] >= lifted],
                                FALL_WINDOW_S)
        self.log.result["palm_fastest_fall_m"] = {"window_s": FALL_WINDOW_S, "fall_m": fall,
                                                  "at_s": at}
        self.say(f"the mug moved {slip * 100:.1f} cm in the hand while off the table; the "
                 f"hand fell at most {fall * 100:.1f} cm in {FALL_WINDOW_S:g} s (at sim "
                 f"{at:.1f} s) (ground truth)")
        if slip > SLIP_M:
            raise DemoFailed(self.step, f"the mug slipped {slip * 100:.1f} cm in the hand "
                                        f"(at sim {watch.slip_t:.1f} s; ground truth)")

    def park(self) -> None:
        ready = ready_joints()
        self.begin("park", "back to the ready pose, then hanging; torque off")
        self._moveto(flange_pose(READY_BACK_M, READY_UP_M), "ready pose", speed=0.4)
        self._joint_path((0.0, 0.0, ready[2], 0.0, *ready[4:]))
        self._joint_path((0.0,) * len(ready))
        self.arm.torque(False)


def _fmt(v: Any) -> str:
    return "(" + ", ".join(f"{float(x):+.3f}" for x in v) + ")"


def _quiet(main: Callable[[list[str]], int], argv: list[str]) -> tuple[int, str]:
    """Run a CLI's ``main`` capturing its standard output and error."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        try:
            status = main(argv)
        except SystemExit as exc:
            status = int(exc.code or 0)
    return status, out.getvalue()


def run_session(demo: Demo, out: Path) -> None:
    """Steps 2-6 with the hand and arm recorded to MCAP under ``out``; any error is a
    :class:`DemoFailed` naming the step it happened in."""
    try:
        with HandRecorder(demo.hand, out / "hand.mcap") as hand_rec, \
                ArmRecorder(demo.arm, out / "arm.mcap") as arm_rec:
            demo.hand_recorder = hand_rec
            recorders = (hand_rec, arm_rec)
            for step in (demo.firmware, demo.home, demo.reach, demo.grasp, demo.lift,
                         demo.park):
                step()
                for recorder in recorders:
                    recorder.check()  # a full disk stops the demo, saying so
            demo.sampler.finish()
        for recorder in recorders:
            recorder.check()
    except DemoFailed:
        raise
    except Exception as exc:  # noqa: BLE001 - said as the step's failure, not a traceback
        raise DemoFailed(demo.step, f"{type(exc).__name__}: {exc}") from exc


def fastest_fall(samples: list[tuple[float, float, float, float]], window_s: float
                 ) -> tuple[float, float]:
    """The most the palm fell (m) within ``window_s`` in ``samples`` (t, mug z, palm z,
    slip), and when it began (s)."""
    best, at = 0.0, samples[0][0] if samples else 0.0
    j = 0
    for i, (t, _mz, z, _s) in enumerate(samples):
        j = max(j, i)
        while j + 1 < len(samples) and samples[j + 1][0] - t <= window_s:
            j += 1
        low = min(row[2] for row in samples[i:j + 1])
        if z - low > best:
            best, at = z - low, t
    return best, at


def judge(summary: Mapping[str, float]) -> tuple[bool, str]:
    """Success from the mug's ground truth (:meth:`MugTracker.summary`)."""
    lift = summary["highest_lift_m"]
    back = abs(summary["lift_m"]) <= SET_DOWN_M and summary["tilt_rad"] <= SET_DOWN_TILT_RAD
    text = (f"mug lifted {lift * 100:.1f} cm (ground truth), "
            + ("set down upright" if back else
               f"ended {summary['lift_m'] * 100:+.1f} cm from its start height, tilted "
               f"{math.degrees(summary['tilt_rad']):.0f}°"))
    if lift < MIN_LIFT_M:
        return False, f"lift: {text}; needs at least {MIN_LIFT_M * 100:.0f} cm"
    if not back:
        return False, f"put down: {text}"
    return True, text


# ---------------------------------------------------------------------------- in process


def open_watch(hand: Hand, arm: Arm, view_port: int | None) -> RobotView | None:
    """One browser view of both (the hand drawn on the arm's flange) if asked for."""
    view = open_view(view_port)
    if view is not None:
        arm.watch(view)
        hand.watch(view)
    return view


def demo_url(seed: int, sensors: str | None = None, profile: Path | None = None) -> str:
    """The in-process emulator's URL of the demo, ``{}`` where the link goes: the full
    robot, the mug scene, ``seed``, ``sensors`` (None: the emulator's default) and the robot
    ``profile`` (a file; None: the nominal robot)."""
    option = "" if sensors is None else f"&sensors={sensors}"
    if profile is not None:
        option += "&profile=" + str(profile.resolve()).replace("{", "{{").replace("}", "}}")
    return f"emu://full/{{}}?scene=mug&seed={seed}{option}&name=demo"


def run_inprocess(out: Path, seed: int, view_port: int | None = None,
                  sensors: str | None = None, profile: Path | None = None,
                  arm_calibration: str | None = None) -> tuple[bool, str]:
    """The demo in this process; ``sensors`` the emulator's (None: its default),
    ``profile`` the robot's (a file; None: the nominal robot), ``arm_calibration`` as
    :attr:`Demo.arm_calibration`."""
    from hil_emulator.inprocess import EmulatorTransport
    from hil_emulator.scene_model import MugTracker

    wall0 = time.monotonic()
    url = demo_url(seed, sensors, profile)
    print(f"[sim    0.0 s | wall    0.0 s] emulator: full configuration, mug scene, in this "
          f"process on the simulation clock ({url.format('palm')})", flush=True)
    hand = Hand.open(url.format("palm"))
    arm = Arm.open(url.format("arm"))
    view = open_watch(hand, arm, view_port)
    transport = hand.session.transport
    assert isinstance(transport, EmulatorTransport)
    emulator = transport.emulator
    truth = emulator.scene_parts[0]
    assert isinstance(truth, MugTracker)  # the mug scene's
    demo = Demo(hand, arm, out, truth=truth, palm_port=url.format("palm"))
    demo.calibrate = sensors != "ideal"
    demo.arm_calibration = arm_calibration
    demo.mug_in_hand = MugInHand.from_emulator(emulator, truth)
    if demo.mug_in_hand is not None:
        demo.log.truth = demo.mug_in_hand.samples
    demo.wall0 = wall0
    demo.step = "emulator"
    demo.say("hand up (13 MCUs running), arm powered, torque off; mug on the table at "
             f"{_fmt(truth.start)} m")
    try:
        run_session(demo, out)
    finally:
        summary = emulator.scene_stats()["mug"]
        demo.log.result["mug"] = summary
        hand.close()
        arm.close()
        if view is not None:
            view.close()
        write_run_report(demo, out)
    return judge(summary)


def write_run_report(demo: Demo, out: Path) -> None:

    try:
        path = write_report(demo.log, out)
    except Exception as exc:  # noqa: BLE001 - the report must not hide the run's result
        print(f"demo: the report could not be written ({type(exc).__name__}: {exc})",
              flush=True)
        return
    print(f"report: {path}", flush=True)
    print(f"recordings: {out / 'hand.mcap'}, {out / 'arm.mcap'} "
          f"(decode: handbus decode {out / 'hand.mcap'})", flush=True)
