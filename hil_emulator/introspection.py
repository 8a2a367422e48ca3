"""What a fuzzer may ask the emulator that the wire cannot tell: its internal invariants.

:class:`EmulatorIntrospection` answers the optional introspection interface of the
live-target fuzzer (``tools.fuzz.oracles.Introspection``, matched by shape: this package
never imports ``tools``).  A run against a real board has no such object and keeps to the
wire-level oracles.
"""

from __future__ import annotations

import hashlib
from typing import Final

from firmware_py.boot_program import inspect_image
from firmware_py.mcu import Mcu
from firmware_py.sim.virtual_hal import VirtualHal
from hil_emulator.emulator import Emulator
from hil_emulator.imperfections import PlantedTruth
from hil_emulator.lines.rs485_bus import Rs485Bus
from protocol.image import FLASH, BoardType
from protocol.messages.boot_program import ImageStatus

#: A transmission still on a line this long after now (µs) means a driver left on.
STUCK_DRIVER_US: Final = 50_000


class EmulatorIntrospection:
    """Internal views of one :class:`Emulator`: motors driven, protected flash, invariants."""

    def __init__(self, emulator: Emulator) -> None:
        self.emulator = emulator

    # --- what exists ------------------------------------------------------------------------
    def mcus(self) -> dict[str, Mcu]:
        """Every hand microcontroller by name (``palm``, ``fmcb0``, ``f2_0`` …)."""
        out: dict[str, Mcu] = {}
        if self.emulator.hand is not None:
            out["palm"] = self.emulator.hand.palm
            for finger in self.emulator.hand.fingers:
                k = finger.index
                out.update({f"fmcb{k}": finger.fmcb, f"f2_{k}": finger.f2, f"f3_{k}": finger.f3})
        if self.emulator.loose is not None:
            finger = self.emulator.loose.finger
            out.update({"fmcb0": finger.fmcb, "f2_0": finger.f2, "f3_0": finger.f3})
        return out

    def _hals(self) -> dict[str, VirtualHal]:
        hals: dict[str, VirtualHal] = {}
        for name, mcu in self.mcus().items():
            if isinstance(mcu.hal, VirtualHal):
                hals[name] = mcu.hal
        if self.emulator.arm is not None:
            for dxl_id, (hal, _app) in self.emulator.arm.nodes.items():
                hals[f"arm{dxl_id}"] = hal
        return hals

    def _buses(self) -> dict[str, Rs485Bus]:
        buses: dict[str, Rs485Bus] = {}
        if self.emulator.arm is not None:
            buses["arm"] = self.emulator.arm.bus
        fingers = list(self.emulator.hand.fingers) if self.emulator.hand is not None else []
        if self.emulator.loose is not None:
            fingers.append(self.emulator.loose.finger)
        for finger in fingers:
            if finger.tendon_bus is not None:
                buses[f"tendon{finger.index}"] = finger.tendon_bus
        return buses

    def planted_truth(self) -> PlantedTruth | None:
        """What ``--sensors realistic`` drew for this robot (each board's accelerometer and
        mounting, pad and gauge offsets, each moved body), the ground truth a calibration is
        held to; None for ``ideal`` sensors or without physics."""
        return self.emulator.planted

    # --- the interface --------------------------------------------------------------------
    def motors_driven(self) -> list[str]:
        """Motors the firmware drives now: a bridge on with a non-zero duty, a stepper
        commanded to a non-zero step rate (names such as ``fmcb0.motor1``, ``arm2.stepper``)."""
        driven: list[str] = []
        for name, hal in self._hals().items():
            for i, motor in enumerate(hal.motors):
                if motor.bridge_enabled() and motor.commanded_duty() != 0.0:
                    driven.append(f"{name}.motor{i}")
            try:
                stepper = hal.stepper()
            except Exception:  # noqa: BLE001 - a board without a stepper
                continue
            if stepper.commanded_rate() != 0.0:
                driven.append(f"{name}.stepper")
        return driven

    def protected_digest(self) -> bytes:
        """SHA-256 over every hand node's bootloader pages (identity included)."""
        digest = hashlib.sha256()
        size = FLASH.page_size
        for name, mcu in sorted(self.mcus().items()):
            flash = mcu.hal.flash
            digest.update(name.encode())
            for page in FLASH.bootloader_pages:
                digest.update(flash.read(FLASH.flash_base + page * size, size))
        return digest.digest()

    def state_digest(self) -> bytes:
        """SHA-256 of what a frame could change that the host could later observe: every
        node's whole flash, which program it runs, and the motors driven."""
        digest = hashlib.sha256()
        for name, mcu in sorted(self.mcus().items()):
            flash = mcu.hal.flash
            digest.update(f"{name}:{mcu.program_name}:{mcu.powered}".encode())
            digest.update(flash.read(FLASH.flash_base, FLASH.page_size * FLASH.page_count))
        if self.emulator.arm is not None:
            for dxl_id, (_hal, app) in sorted(self.emulator.arm.nodes.items()):
                app.sync_image()
                digest.update(bytes([dxl_id]) + bytes(app.image))
        digest.update(",".join(self.motors_driven()).encode())
        return digest.digest()

    def invariant_violations(self) -> list[str]:
        """Broken internal invariants: a node running its application from an image that
        does not verify, a line driven far beyond any frame's end."""
        problems: list[str] = []
        for name, mcu in self.mcus().items():
            if mcu.powered and mcu.program is not None and not mcu.in_bootloader:
                check = inspect_image(mcu.hal.flash, BoardType(mcu.identity.board))
                if check.status != ImageStatus.VALID:
                    problems.append(f"{name} runs {mcu.program_name} from an image that is "
                                    f"{check.status.name.lower()} ({check.reason})")
        now = self.emulator.scheduler.now_us()
        for name, bus in self._buses().items():
            stuck = [t for t in bus._on_air if t.end_us - now > STUCK_DRIVER_US]
            if stuck:
                problems.append(f"the {name} line is driven until "
                                f"{max(t.end_us for t in stuck)} µs (now {now} µs)")
        return problems
