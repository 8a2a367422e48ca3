"""The emulated robot's construction: its rigs, its MuJoCo plant and its scene on one clock.

:class:`EmulatedRobot` builds one of the :data:`CONFIGS`:

``full``          the hand on the arm's wrist;
``hand``          the hand on a fixed stand with an object to grasp;
``arm``           the arm alone;
``loose-finger``  one finger module on a bench (the original's 'loose finger' cable):
                  ``fingers[0]``.

Every node runs its real ``firmware_py`` program on a :class:`~firmware_py.sim.virtual_hal.VirtualHal`
driven by one :class:`~firmware_py.scheduler.Scheduler` (integer µs); the plant
(:mod:`hil_emulator.plant`) ticks on the same clock.  A ``seed`` makes a run repeatable: the
rigs and plant parts draw from generators seeded from it in a fixed order.  The robot also
offers what acts on it from outside the wire (a finger pulled off, a tendon contact
opening), for the faults.  Its host ports and their serving are
:class:`~hil_emulator.emulator.Emulator`'s.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Final

import mujoco
import numpy as np

from firmware_py.mcu import Mcu
from firmware_py.scheduler import Scheduler
from hil_emulator import imperfections, scene_model
from hil_emulator.arm import model as arm_model
from hil_emulator.arm.plant import ArmPlant
from hil_emulator.arm.rig import ArmRig
from hil_emulator.errors import EmulatorConfigError
from hil_emulator.hand import model as hand_model
from hil_emulator.hand.finger_plant import FingerParams, FingerPlant, PalmPlant
from hil_emulator.hand.rig import HandRig, LooseFinger
from hil_emulator.hand_profile import check_sensors as check_profile_sensors
from hil_emulator.imperfections import DEFAULT_SENSORS, AccelTruth, PlantedTruth
from hil_emulator.plant import Plant, PlantPart, new_spec
from hil_emulator.profile import RobotProfile, as_profile
from hil_emulator.scene_model import SCENES, SceneObject
from protocol.robot import HAND_ON_FLANGE_POSITION_M, HAND_ON_FLANGE_QUAT

#: The configurations :class:`EmulatedRobot` can build.
CONFIGS: Final = ("full", "hand", "arm", "loose-finger")
#: Height of the hand's stand in the ``hand`` configuration (m); the palm faces up.
STAND_Z_M: Final = 0.4


class EmulatedRobot:
    """One emulated robot, powered on.

    ``layout`` names the hand layout (:data:`hil_emulator.hand.model.LAYOUTS`); ``physics``
    False leaves the MuJoCo plant out (firmware and buses only); ``scene`` adds things to
    the world (:data:`hil_emulator.scene_model.SCENES`: ``"none"``, ``"mug"`` — a table and
    a coffee mug in front of the arm, ``"calibration"`` — the touch calibration's rig;
    configurations with the arm only); ``sensors``
    (:data:`hil_emulator.imperfections.SENSOR_MODES`) ``"realistic"`` (the default) builds
    the robot as a real one is, its sensors imperfect and its links off by a laser-cut
    build's tolerances (:mod:`hil_emulator.imperfections`; what was drawn:
    :attr:`planted`), ``"ideal"`` exact sensors on the nominal geometry; ``profile`` (a
    :class:`~hil_emulator.profile.RobotProfile` or its file's path) gives the robot the
    physical parameters of a particular one (:mod:`hil_emulator.profile`).
    """

    def __init__(self, config: str = "full", *, seed: int = 0, layout: str | None = None,
                 physics: bool = True, scene: str = "none",
                 sensors: str = DEFAULT_SENSORS,
                 profile: RobotProfile | str | None = None) -> None:
        if config not in CONFIGS:
            raise EmulatorConfigError(
                f"unknown configuration {config!r}; choose one of {', '.join(CONFIGS)}")
        if seed < 0:
            raise EmulatorConfigError(f"the seed must be >= 0, got {seed}")
        layout = layout or hand_model.DEFAULT_LAYOUT
        if layout not in hand_model.LAYOUTS:
            raise EmulatorConfigError(f"unknown hand layout {layout!r}; choose one of "
                                      f"{', '.join(hand_model.LAYOUTS)}")
        if scene not in SCENES:
            raise EmulatorConfigError(f"unknown scene {scene!r}; choose one of "
                                      f"{', '.join(SCENES)}")
        if scene != "none" and config not in ("full", "arm"):
            raise EmulatorConfigError(f"the {scene!r} scene stands in front of the arm: use it "
                                      f"with the full or arm configuration, not {config!r}")
        #: The robot's own physical parameters (None: the nominal robot's).
        self.profile = as_profile(profile)
        self.sensors = imperfections.check_sensors(sensors)  #: ``"ideal"`` or ``"realistic"``
        if self.profile is not None:
            check_profile_sensors(self.profile.values, self.sensors)
        #: What ``sensors="realistic"`` drew for this robot (None: ideal, or no physics): the
        #: ground truth a calibration is held to, never on the wire.
        self.planted: PlantedTruth | None = None
        self.config = config
        self.scene = scene  #: the scene's name (:data:`hil_emulator.scene_model.SCENES`)
        self.seed = seed
        self.scheduler = Scheduler()
        seeds = iter(np.random.SeedSequence(seed).generate_state(16))
        self.hand: HandRig | None = None
        self.arm: ArmRig | None = None
        self.loose: LooseFinger | None = None
        if config in ("full", "arm"):
            self.arm = ArmRig(self.scheduler, seed=int(next(seeds)),
                              serial=imperfections.arm_serial(seed, self.sensors))
        if config in ("full", "hand"):
            self.hand = HandRig(self.scheduler, imperfections.hand_uid_base(seed, self.sensors),
                                line_model=True, seed=int(next(seeds)), record=False)
        if config == "loose-finger":
            self.loose = LooseFinger(self.scheduler, line_model=True, seed=int(next(seeds)),
                                     record=False)
        self.layout = layout  #: the hand layout's name
        self.plant: Plant | None = None
        #: Each finger module's physics, by finger index (empty without physics).
        self.finger_plants: list[FingerPlant] = []
        #: The arm's physics (None without an arm or without physics).
        self.arm_plant: ArmPlant | None = None
        #: The scene's object trackers (:class:`hil_emulator.scene_model.MugTracker`,
        #: :class:`hil_emulator.calibration_scene.RigTruth`).
        self.scene_parts: list[SceneObject] = []
        if physics:
            self.plant = self._build_plant(layout, seeds)
            self.plant.attach(self.scheduler)
        # Supplies on: the palm and the loose finger start their bootloaders; arm nodes run.
        if self.hand is not None:
            self.hand.power_on()
        if self.loose is not None:
            self.loose.power_on()

    def _build_plant(self, layout: str, seeds: Iterator[np.uint32]) -> Plant:
        def rng() -> np.random.Generator:
            return np.random.default_rng(int(next(seeds)))

        spec = new_spec(f"hil-{self.config}")
        parts: list[PlantPart] = []
        truth = PlantedTruth() if self.sensors == "realistic" else None
        self.planted = truth
        hand_parent = None
        if self.arm is not None:
            base = spec.worldbody.add_body(name="arm_base",
                                           pos=[0.0, 0.0, arm_model.MOUNT_HEIGHT_M])
            hand_parent = arm_model.add_arm(spec, base, prefix="arm/")
            params = None
            if truth is not None:
                imperfections.draw_arm_assembly(self.seed, truth)
                params = imperfections.arm_params(truth)
            if self.profile is not None:
                params = self.profile.arm_params(params)
            self.arm_plant = ArmPlant("arm/", self.arm.stepper_hals, self.arm.servo_hals,
                                      rng(), params)
            parts.append(self.arm_plant)
        if self.hand is not None:
            if hand_parent is None:
                hand_parent = spec.worldbody.add_body(name="stand", pos=[0.0, 0.0, STAND_Z_M])
                # An object resting on the palm, ready to be grasped.
                hand_model.add_grasp_object(spec, spec.worldbody,
                                            pos=(0.0, 0.012, STAND_Z_M + 0.036))
            if self.arm is not None:  # on the wrist flange, the palm facing away from it
                hand_model.add_hand(spec, hand_parent, layout=layout, prefix="hand/",
                                    pos=HAND_ON_FLANGE_POSITION_M, quat=HAND_ON_FLANGE_QUAT)
            else:
                hand_model.add_hand(spec, hand_parent, layout=layout, prefix="hand/")
            if truth is None:
                parts.append(PalmPlant("hand/", self.hand.palm, rng()))
            else:
                parts.append(PalmPlant("hand/", self.hand.palm, rng(),
                                       imperfections.palm_params(),
                                       imperfections.palm_errors(self.seed, truth,
                                                                 adjust=self._accel_adjust)))
            for finger in self.hand.fingers:
                fp = self._finger_plant(f"hand/finger{finger.index}/", finger.index,
                                        finger.fmcb, finger.f2, finger.f3, rng(), truth)
                self.finger_plants.append(fp)
                parts.append(fp)
        if self.loose is not None:
            bench = spec.worldbody.add_body(name="bench_clamp", pos=[0.0, 0.0, 0.3])
            hand_model.add_finger(spec, bench, "finger0/")
            f = self.loose.finger
            fp = self._finger_plant("finger0/", 0, f.fmcb, f.f2, f.f3, rng(), truth)
            self.finger_plants.append(fp)
            parts.append(fp)
        if truth is not None:
            self._as_built(spec, truth)
        self.scene_parts = scene_model.add_scene(spec, self.scene, self.seed)
        parts.extend(self.scene_parts)
        return Plant(spec, parts)

    def _finger_plant(self, prefix: str, index: int, fmcb: Mcu, f2: Mcu, f3: Mcu,
                      rng: np.random.Generator, truth: PlantedTruth | None) -> FingerPlant:
        """Finger module ``index``'s plant part, its sensors as built when ``truth`` is given,
        with the profile's parameters of it."""
        params = FingerParams() if truth is None else imperfections.finger_params()
        if self.profile is not None:
            params = self.profile.finger_params(index, params)
        if truth is None:
            return FingerPlant(prefix, fmcb, f2, f3, rng, params)
        return FingerPlant(prefix, fmcb, f2, f3, rng, params,
                           imperfections.finger_errors(self.seed, index, truth,
                                                       adjust=self._accel_adjust))

    def _accel_adjust(self, board: str, drawn: AccelTruth) -> AccelTruth:
        """Board ``board``'s drawn accelerometer with the profile's values of it."""
        return drawn if self.profile is None else self.profile.accel(board, drawn)

    def _as_built(self, spec: mujoco.MjSpec, truth: PlantedTruth) -> None:
        """Move the arm's joint bodies and flange (and its tubes' ends), the palm and each finger module's mount and
        phalanges from their nominal places by a laser-cut build's tolerances."""
        arm = [body.name for body in spec.bodies
               if body.name.startswith("arm/") and (len(body.joints) or body.name == "arm/flange")]
        if arm:
            imperfections.perturb_bodies(spec, arm, imperfections.part_rng(self.seed, "arm geometry"),
                                         truth)
            imperfections.lengthen_arm_tubes(spec, truth)
        hand = [body.name for body in spec.bodies if body.name == "hand/palm"
                or body.name.endswith(("/F0", "/F2", "/F3"))]
        if hand:
            imperfections.perturb_bodies(spec, hand,
                                         imperfections.part_rng(self.seed, "hand geometry"), truth)

    # ------------------------------------------------------------------ parts
    def rig(self, link: str) -> HandRig | ArmRig | LooseFinger:
        """The rig behind host link ``link`` (``palm``, ``arm``, ``finger0``)."""
        rig = {"palm": self.hand, "arm": self.arm, "finger0": self.loose}.get(link)
        if rig is None:
            raise EmulatorConfigError(f"the {self.config!r} configuration has no host link "
                                      f"{link!r}")
        return rig

    def require_hand(self) -> HandRig:
        """The hand's rig; :class:`EmulatorConfigError` in a configuration without it."""
        if self.hand is None:
            raise EmulatorConfigError(f"the {self.config!r} configuration has no hand")
        return self.hand

    def require_arm_plant(self) -> ArmPlant:
        """The arm's physics; :class:`EmulatorConfigError` without an arm or physics."""
        if self.arm_plant is None:
            raise EmulatorConfigError(f"the {self.config!r} emulator has no arm plant (no arm, "
                                      "or physics off)")
        return self.arm_plant

    def scene_stats(self) -> dict[str, dict[str, float]]:
        """Ground truth of the scene's objects (``{"mug": MugTracker.summary()}``), empty
        without a scene or physics."""
        return {part.name: part.summary() for part in self.scene_parts}

    # ------------------------------------------------------------------ outside the wire
    def break_away(self, finger: int) -> None:
        """Finger ``finger`` leaves its pogo pins (overload): no link, no power, motors
        coast in the plant."""
        hand = self.require_hand()
        hand.break_away(finger)
        if self.finger_plants:
            self.finger_plants[finger].attached = False

    def reattach(self, finger: int, bounce: bool = True) -> None:
        """Finger ``finger`` is pushed back on, with contact bounce unless ``bounce`` is
        False; it gets the palm's power state once the contacts settle."""
        hand = self.require_hand()
        hand.reattach(finger, bounce=bounce)
        if self.finger_plants:
            self.finger_plants[finger].attached = True

    def tendon_glitch(self, finger: int, duration_us: int) -> None:
        """Finger ``finger``'s tendon contact opens for ``duration_us`` µs."""
        self.require_hand().tendon_glitch(finger, duration_us)
