"""Run one scenario on the in-process emulator (fast mode) and judge its assertions.

:func:`run_scenario` builds the emulator of the scenario's configuration and seed, brings
the hand up (``ready``), loads the fault plan (its times count from there), performs the
host actions through the host library (``host.hand.facade``, ``host.arm.facade``, the ``bootloader``
engine) on the emulator's in-process transports, and records: the fault timeline, each
action's outcome and times, finger events, the host's status samples (``stream``,
``arm_stream``) and, every 10 ms, the plant's truth (finger contacts and power, arm joint
angles).  Then each assertion is judged on that record, with the figures it measured.

Times in results are simulation seconds from the moment the plan was loaded.  A result is
plain data (JSON), equal for equal (scenario, seed) whichever process ran it.
"""

from __future__ import annotations

import math
import time
from functools import partial
from typing import Any, Final

from hil_emulator.emulator import Emulator
from hil_emulator.faults import FaultInjector, targets
from hil_emulator.inprocess import EmulatorTransport, bring_up
from hil_emulator.profile import RobotProfile
from host.errors import HostError
from protocol.control_tables import STEPPER_TABLE, StepperFlag
from protocol.topology import FINGERS, STEPPER_IDS
from protocol.topology import board as board_row
from tools.hil_bench.assertions import judge
from tools.hil_bench.record import RunRecord
from tools.hil_bench.scenario import FINGER_BOARDS, Scenario, Step, parse_scenario

#: Period of the plant-truth samples (µs).
TRUTH_PERIOD_US: Final = 10_000
#: A reader on its own adapter sends its READs this far apart (µs): a READ and its reply
#: take about 270 µs of the 1 Mbaud line, and a stock SDK turns round in the rest.
ADAPTER_READ_SPACING_US: Final = 500
#: A stepper node's latches (status_flags bits), read as the nodes' truth.
_LATCHES: Final = int(StepperFlag.SLIP | StepperFlag.STALLED | StepperFlag.HARDWARE_ERROR)
_STEPPER_MODEL: Final = STEPPER_TABLE["model_number"].default


class Bench:
    """The emulator and the host objects one scenario's actions use."""

    def __init__(self, scenario: Scenario, profile: RobotProfile | None = None) -> None:
        self.scenario = scenario
        self.emu = Emulator(scenario.config, seed=scenario.seed, physics=scenario.physics,
                            can="none", profile=profile)
        #: The scenario's fault plan is applied through it (the bench owns it).
        self.faults = FaultInjector(self.emu)
        self.record = RunRecord()
        self._hand: Any = None
        self._arm: Any = None

    # ------------------------------------------------------------------ clock
    def now_s(self) -> float:
        """Simulation time (s) from the plan's start."""
        return (self.emu.scheduler.now_us() - self.record.t0_us) / 1e6

    def _sample_truth(self) -> None:
        emu = self.emu
        row: dict[str, Any] = {"t": round(self.now_s(), 6)}
        if emu.hand is not None:
            row["attached"] = [int(f.attached and f.data_contact) for f in emu.hand.fingers]
            row["fmcb_on"] = [int(f.fmcb.powered) for f in emu.hand.fingers]
        if emu.arm_plant is not None:
            row["arm_q"] = [round(float(q), 5) for q in emu.arm_plant.joint_angles()]
            row["arm_qd"] = [round(float(v), 4) for v in emu.arm_plant.joint_velocities()]
            row["arm_slips"] = [int(n) for n in emu.arm_plant.slips()]
            row.update(self._stepper_truth())
        if emu.arm is not None:  # the nodes' own registers: latches, torque
            nodes = [app for _, app in (emu.arm.nodes[i] for i in sorted(emu.arm.nodes))]
            row["arm_node_alarm"] = [int(bool(a.get("status_flags") & _LATCHES))
                                     if a.get("model_number") == _STEPPER_MODEL
                                     else int(bool(getattr(a, "shutdown", False)))
                                     for a in nodes]
            row["arm_node_torque"] = [int(a.get("torque_enable")) for a in nodes]
        self.record.truth.append(row)

    def _stepper_truth(self) -> dict[str, Any]:
        """The stepper nodes as they are: each motor's step rate (microsteps/s), its
        SLIP/STALLED latches and its torque enable (``arm_held`` judges them)."""
        arm = self.emu.arm
        if arm is None:
            return {}
        apps = [arm.app(dxl_id) for dxl_id in STEPPER_IDS]
        latches = int(StepperFlag.SLIP | StepperFlag.STALLED)
        return {"arm_step_rates": [round(h.stepper().rate, 3) for h in arm.stepper_hals],
                "arm_latched": [int(a.get("status_flags") & latches) for a in apps],
                "arm_torque_on": [a.get("torque_enable") for a in apps]}

    # ------------------------------------------------------------------ host objects
    @property
    def hand(self) -> Any:
        if self._hand is None:
            from host.hand.facade import Hand
            from host.hand.session import HandSession

            self._hand = Hand(HandSession(EmulatorTransport(self.emu, "palm"), retries=1))
            self._hand.subscribe(self._event)
        return self._hand

    def _event(self, event: Any) -> None:
        self.record.events.append({"t": round(event.t - self.record.t0_us / 1e6, 6),
                                   "finger": event.finger, "event": event.event})

    @property
    def arm(self) -> Any:
        if self._arm is None:
            from host.arm.facade import Arm

            self._arm = Arm.open(EmulatorTransport(self.emu, "arm"))
        return self._arm

    # ------------------------------------------------------------------ running
    def run(self) -> RunRecord:
        emu, s = self.emu, self.scenario
        if s.ready and (emu.hand is not None or emu.loose is not None):
            bring_up(emu)
        for a in s.assertions:
            if a.kind == "no_unsent_frames":
                emu.link_tap(a.params["link"]).record = True
        self.record.t0_us = emu.scheduler.now_us()
        emu.scheduler.call_every(TRUTH_PERIOD_US, self._sample_truth)
        self.faults.load(s.faults)
        for step in s.actions:
            self._act(step)
        for ev in self.faults.timeline:
            d = ev.to_dict()
            d["t_s"] = round((ev.t_us - self.record.t0_us) / 1e6, 6)
            self.record.timeline.append(d)
        for name, tap in emu.taps.items():
            if tap.record:
                self.record.links[name] = {"sent": bytes(tap.sent),
                                           "received": bytes(tap.received)}
        self.record.nodes = self._node_states()
        return self.record

    def _node_states(self) -> dict[str, dict[str, Any]]:
        out: dict[str, dict[str, Any]] = {}
        if self.emu.hand is not None:
            for k in range(FINGERS):
                for board in FINGER_BOARDS:
                    mcu = targets.node(self.emu, f"finger{k}.{board}").mcu
                    assert mcu is not None
                    out[f"finger{k}.{board}"] = {
                        "powered": mcu.powered, "program": mcu.program_name,
                        "version": ".".join(map(str, getattr(mcu.program, "fw_version", ())))}
        return out

    def _act(self, step: Step) -> None:
        entry: dict[str, Any] = {"kind": step.kind, "t_start": round(self.now_s(), 6)}
        try:
            entry["result"] = getattr(self, f"_do_{step.kind}")(**step.params)
            entry["ok"] = True
        except HostError as exc:
            entry["ok"] = False
            entry["error"] = f"{type(exc).__name__}: {exc}"
        entry["t_end"] = round(self.now_s(), 6)
        self.record.actions[step.id] = entry

    # ------------------------------------------------------------------ actions
    def _do_wait(self, seconds: float) -> None:
        """Let ``seconds`` pass as a host does: listening on the hand's link, so events are
        taken in (and timed) when they arrive, not when the next action reads."""
        if self._hand is None:
            self.emu.step(round(seconds * 1e6))
            return
        transport = self._hand.session.transport
        deadline = transport.now() + seconds
        while (left := deadline - transport.now()) > 0:
            self._hand.session.pump(left)

    def _do_power(self, finger: int | str, state: str) -> list[str]:
        return list(self.hand.power(finger, state))

    def _do_ping(self, node: str) -> dict[str, Any]:
        if node.startswith("arm"):
            self.arm.bus.ping(int(node.split(".")[1]))
            return {}
        if node == "palm":
            return dict(self.hand.palm.identify().to_dict())
        finger, board = node.removeprefix("finger").split(".")
        hop = board_row(board).hop
        assert hop is not None
        return dict(self.hand.fingers[int(finger)].nodes[hop].identify().to_dict())

    def _do_poll(self, rate_hz: int) -> None:
        self.hand.set_poll_rate(rate_hz)

    def _do_stream(self, seconds: float, rate_hz: float) -> dict[str, Any]:
        """Read the hand's status ``rate_hz`` times a second for ``seconds``; a read that
        fails is recorded (no finger present) and the stream goes on."""
        hand, t0 = self.hand, self.record.t0_us / 1e6
        start = hand.session.now()
        n = failed = 0
        while n / rate_hz <= seconds:
            wait = start + n / rate_hz - hand.session.now()
            if wait > 0:
                hand.session.sleep(wait)
            try:
                state = hand.status()
            except HostError as exc:
                failed += 1
                self.record.hand_samples.append({"t": round(hand.session.now() - t0, 6),
                                                 "present": [0] * FINGERS, "error": str(exc)})
            else:
                self.record.hand_samples.append({
                    "t": round(state.t - t0, 6),
                    "present": [int(f.present) for f in state.fingers],
                    "joints": [[round(q, 4) for q in f.joints] for f in state.fingers]})
            n += 1
        return {"samples": n, "failed": failed}

    def _do_move(self, targets: dict[str, list[float]], effort: int | None, timeout: float,
                 unhomed: bool) -> dict[str, Any]:
        result = self.hand.move_fingers({int(k): v for k, v in targets.items()},
                                        effort=effort, timeout=timeout, unhomed=unhomed)
        return {"settled": result.settled, "stalled": result.stalled,
                "elapsed_s": round(result.elapsed_s, 4)}

    def _do_grasp(self, fingers: list[int], closure: float, effort: int,
                  timeout: float) -> dict[str, Any]:
        pose = [closure * 0.2, closure, closure]
        result = self.hand.move_fingers({k: pose for k in fingers}, effort=effort,
                                        timeout=timeout, unhomed=True)
        return {"settled": result.settled, "stalled": result.stalled,
                "elapsed_s": round(result.elapsed_s, 4)}

    def _do_home(self, finger: int | None) -> list[str]:
        return [str(r) for r in self.hand.home(finger)]

    def _do_flash(self, version: str, fingers: list[int], all_or_nothing: bool
                  ) -> dict[str, Any]:
        from bootloader.batch import run_plan
        from bootloader.plan import make_plan
        from protocol.image import BoardType, FirmwareImage

        images = {b: FirmwareImage.build(bytes(range(256)) * 9 + version.encode()
                                         + b.name.encode(), b, version, b.name.lower())
                  for b in (BoardType.FMCB, BoardType.F2, BoardType.F3)}
        report = run_plan(self.hand.session, make_plan(images, fingers,
                                                       all_or_nothing=all_or_nothing))
        return dict(report.to_dict())

    def _do_arm_open(self) -> dict[str, Any]:
        return {"joints": len(self.arm.steppers) + len(self.arm.servos)}

    def _do_arm_torque(self, on: bool) -> None:
        self.arm.torque(on)

    def _do_arm_move(self, angles: list[float], duration: float, timeout: float,
                     interrupt_s: float | None) -> dict[str, Any]:
        """``Arm.move``; with ``interrupt_s``, interrupted that long after it starts as
        Ctrl-C would (a KeyboardInterrupt in the host's loop) and the arm held, as
        ``with Arm.open(...)`` does on the way out."""
        arm = self.arm
        if interrupt_s is None:
            state, settled = arm.move(angles, duration=duration, timeout=timeout)
            return {"errors": state.errors, "settled": settled}
        stop_at = arm.transport.now() + interrupt_s
        fired = False

        def ctrl_c(_state: Any) -> None:
            nonlocal fired
            if not fired and arm.transport.now() >= stop_at:
                fired = True
                raise KeyboardInterrupt

        arm.state_taps.append(ctrl_c)
        try:
            state, settled = arm.move(angles, duration=duration, timeout=timeout)
        except KeyboardInterrupt:
            held = arm.hold()
            return {"interrupted": True, "held": list(held.joints),
                    "at": [round(q, 5) for q in held.state.joints]}
        finally:
            arm.state_taps.remove(ctrl_c)
        return {"interrupted": False, "errors": state.errors, "settled": settled}

    def _do_arm_home(self) -> dict[str, Any]:
        self.arm.torque(True, hold=True)
        return {"offsets": list(self.arm.home().offsets)}

    def _do_arm_play(self, waypoints: list[dict[str, Any]], time_scale: float
                     ) -> dict[str, Any]:
        """``play_waypoints`` of ``waypoints`` (``{t = s, joints = [7 rad]}`` each)."""
        from host.arm.trajectory import Waypoint
        from host.arm.waypoints import play_waypoints

        points = [Waypoint(float(w["t"]), tuple(float(q) for q in w["joints"]))
                  for w in waypoints]
        state = play_waypoints(self.arm, points, time_scale=time_scale)
        return {"joints": [round(q, 5) for q in state.joints]}

    def _do_arm_stream(self, seconds: float, rate_hz: float) -> dict[str, Any]:
        arm, transport = self.arm, self.arm.transport
        end = transport.now() + seconds
        period = 1.0 / rate_hz
        n = 0
        while transport.now() < end:
            due = transport.now() + period
            try:
                state = arm.cycle()
            except HostError as exc:
                self.record.arm_samples.append({"t": round(self.now_s(), 6),
                                                "error": str(exc)})
            else:
                self.record.arm_samples.append({
                    "t": round(state.t - self.record.t0_us / 1e6, 6),
                    "angles": [round(q, 5) for q in state.joints],
                    "slip": [int(s) for s in state.slip],
                    "torques": [round(x, 4) for x in state.torques],
                    "errors": {k: list(v) for k, v in state.errors.items()}})
            n += 1
            wait = due - transport.now()
            if wait > 0:
                transport.sleep(wait)
        return {"cycles": n}

    def _do_arm_clear_errors(self) -> None:
        self.arm.clear_errors()

    def _do_arm_move_vanish(self, angles: list[float], duration: float, after_s: float,
                            reader_ms: float | None, read_for_s: float,
                            reader_adapter: bool) -> dict[str, Any]:
        """Start the move :meth:`host.arm.facade.Arm.move` makes (speeds for ``duration``, goals
        every 10 ms), then stop sending goals ``after_s`` into it, as a host killed
        mid-move does; the result says when (``vanished_s``, from the plan's start).  With
        ``reader_ms``, another program on the bus READs the seven joints' positions every
        ``reader_ms`` (ms) through the move and for ``read_for_s`` (s) after the host went
        (a monitor: plain READs, no writes): through the host's own bus client, its READs
        between the host's cycles, or with ``reader_adapter`` from its own adapter on the
        line (:meth:`hil_emulator.arm.rig.ArmRig.add_adapter`), on the simulation clock,
        whenever it is due: its frames then collide with the host's (the result counts the
        host's ``retries`` and ``timeouts``, and the reader's ``reader_reads``)."""
        from host.arm.facade import MOVE_MIN_SPEED

        arm, clock = self.arm, self.arm.transport
        now = arm.state().joints
        speeds = [max(abs(a - b) / duration, MOVE_MIN_SPEED)
                  for a, b in zip(angles, now, strict=True)]
        if reader_adapter and reader_ms is not None:
            return self._vanish_with_an_adapter_reader(angles, speeds, after_s, reader_ms,
                                                       read_for_s)
        arm.set_positions(angles, speeds)
        next_read = clock.now()

        def poll() -> None:
            nonlocal next_read
            if reader_ms is not None and clock.now() >= next_read:
                next_read += reader_ms / 1000
                for j in arm.joints:  # present_position: 32 (steppers), 36 (RX-64s)
                    arm.bus.read(j.dxl_id, 32 if j.kind == "stepper" else 36,
                                 4 if j.kind == "stepper" else 2)

        end = clock.now() + after_s
        while clock.now() < end:
            clock.sleep(0.01)
            arm.set_positions(angles)
            poll()
        vanished = round(self.now_s(), 6)
        if reader_ms is not None:
            stop = clock.now() + read_for_s
            while clock.now() < stop:
                # at least 1 ms: a sleep shorter than the clock's µs would not advance it
                clock.sleep(max(0.001, min(next_read, stop) - clock.now()))
                poll()
        return {"vanished_s": vanished, "goals": list(angles)}

    def _vanish_with_an_adapter_reader(self, angles: list[float], speeds: list[float],
                                       after_s: float, reader_ms: float,
                                       read_for_s: float) -> dict[str, Any]:
        """:meth:`_do_arm_move_vanish` with the reader on its own adapter: every
        ``reader_ms`` it sends the seven READs one after the other, each
        :data:`ADAPTER_READ_SPACING_US` after the one before (a stock SDK waits for each
        reply), whatever else is on the line."""
        from protocol.dynamixel import make_read

        rig = self.emu.arm
        assert rig is not None
        arm, clock = self.arm, self.arm.transport
        adapter = rig.add_adapter()
        adapter.set_receiver(lambda data, t_us: None)  # a monitor: what it reads is its own
        sent = [0]
        reads = [make_read(j.dxl_id, 32 if j.kind == "stepper" else 36,
                           4 if j.kind == "stepper" else 2).encode() for j in arm.joints]

        def poll() -> None:
            for k, packet in enumerate(reads):
                rig.scheduler.call_later(k * ADAPTER_READ_SPACING_US,
                                         partial(adapter.send, packet))
            sent[0] += len(reads)

        before = (arm.bus.stats.retries, arm.bus.stats.timeouts)
        timer = rig.scheduler.call_every(int(reader_ms * 1000), poll)
        try:
            arm.set_positions(angles, speeds)
            end = clock.now() + after_s
            while clock.now() < end:
                clock.sleep(0.01)
                arm.set_positions(angles)
            vanished = round(self.now_s(), 6)
            clock.sleep(read_for_s)
        finally:
            timer.cancel()
        return {"vanished_s": vanished, "goals": list(angles), "reader_reads": sent[0],
                "retries": arm.bus.stats.retries - before[0],
                "timeouts": arm.bus.stats.timeouts - before[1]}


def run_scenario(raw: dict[str, Any], source: str = "<scenario>",
                 keep_trace: bool = False, profile: RobotProfile | None = None
                 ) -> dict[str, Any]:
    """Run the scenario table ``raw`` on the robot of ``profile`` (None: the nominal one);
    its result as plain data: ``passed``, one entry per
    assertion (``passed``, ``measured``, ``message``), the actions, the timeline, ``faults``
    (the fault classes of the plan, each once, in plan order: what a campaign report counts
    the run under), ``profile`` (the file it was read from, or None) and, with
    ``keep_trace``, the samples for plots.  ``wall_s`` is the only field that varies
    between equal runs."""
    scenario = parse_scenario(raw, source)
    started = time.perf_counter()
    bench = Bench(scenario, profile)
    try:
        record = bench.run()
    finally:
        bench.emu.close()
    results = [judge(a, record) for a in scenario.assertions]
    out: dict[str, Any] = {
        "scenario": scenario.name, "source": source, "seed": scenario.seed,
        "config": scenario.config,
        "profile": profile.source or "(in memory)" if profile is not None else None,
        "faults": list(dict.fromkeys(e.fault.name for e in scenario.faults)),
        "passed": all(r["passed"] for r in results),
        "assertions": results,
        "actions": record.actions,
        "timeline": record.timeline,
        "sim_s": round(bench.now_s(), 6),
        "wall_s": round(time.perf_counter() - started, 3),
    }
    if keep_trace:
        out["trace"] = {"truth": record.truth, "hand": record.hand_samples,
                        "arm": record.arm_samples, "events": record.events}
    return _plain(out)


def _plain(value: Any) -> Any:
    """``value`` with tuples as lists and non-finite floats as None (strict JSON)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
