"""One microcontroller: its HAL, its flash, and which program runs on it.

At power-up and after every reset the bootloader runs.  When it boots the application it
calls :meth:`Mcu.boot` with the application name recorded in the verified image header;
the program registered under that name then runs on the same HAL.  The application can
reset the node (:meth:`Mcu.reset`) and so return to the bootloader.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Protocol

from firmware_py.errors import ConfigError
from firmware_py.hal import Hal
from firmware_py.identity import Identity, read_identity
from protocol.image import Version


class Program(Protocol):
    """A program a node runs (its bootloader or an application)."""

    def start(self) -> None:
        """Begin: register receivers and timers on the HAL."""


ProgramFactory = Callable[[Hal, "Mcu"], Program]


class Mcu:
    """A microcontroller that runs ``bootloader`` after reset and applications from ``apps``.

    ``apps`` maps an image's application name (``"fmcb"``, ``"f2"``, …) to a factory.
    """

    def __init__(self, hal: Hal, bootloader: ProgramFactory,
                 apps: Mapping[str, ProgramFactory]) -> None:
        self.hal = hal
        self._bootloader_factory = bootloader
        # Kept as given (not copied): sim.boards.make_node passes a table that imports lazily.
        self.apps: Mapping[str, ProgramFactory] = apps
        self.program: Program | None = None
        self.program_name: str | None = None
        self.powered = False
        self.boots = 0
        self.resets = 0
        hal.on_reset = self.reset  # type: ignore[attr-defined]

    @property
    def identity(self) -> Identity:
        """The identity in this node's flash."""
        return read_identity(self.hal.flash)

    @property
    def in_bootloader(self) -> bool:
        """True while the bootloader runs."""
        return self.powered and self.program_name == "bootloader"

    def power_on(self) -> None:
        """Supply comes up: the bootloader starts with the clock at zero."""
        if self.powered:
            return
        self.powered = True
        self._start_bootloader()

    def power_off(self) -> None:
        """Supply gone: everything stops; an unfinished flash write is lost."""
        if not self.powered:
            return
        self.powered = False
        self.hal.halt(restart_clock=True)
        power_loss = getattr(self.hal.flash, "power_loss", None)
        if power_loss is not None:
            power_loss()
        self.program = None
        self.program_name = None

    def reset(self) -> None:
        """Reset: the running program stops and the bootloader starts again."""
        if not self.powered:
            return
        self.resets += 1
        self._start_bootloader()

    def boot(self, app_name: str, version: Version | None = None) -> None:
        """Jump to the application ``app_name`` (called by the bootloader only).

        ``version`` is the booted image's: the program reports it (its ``fw_version``, what
        ``identify`` answers), as a real build carries the version it was built as.
        """
        factory = self.apps.get(app_name)
        if factory is None:
            raise ConfigError(f"no application called {app_name!r} on this board")
        self.hal.halt(restart_clock=False)
        self.boots += 1
        self.program_name = app_name
        self.program = factory(self.hal, self)
        if version is not None and hasattr(self.program, "fw_version"):
            setattr(self.program, "fw_version",  # noqa: B010 (Program does not declare it)
                    (version.major, version.minor, version.patch))
        self.program.start()

    def install_programs(self, bootloader: ProgramFactory,
                         apps: Mapping[str, ProgramFactory]) -> None:
        """Replace the bootloader and the application table (a factory reflash over JTAG);
        they run from the next reset or power-up."""
        self._bootloader_factory = bootloader
        self.apps = apps

    def _start_bootloader(self) -> None:
        self.hal.halt(restart_clock=True)
        self.program_name = "bootloader"
        self.program = self._bootloader_factory(self.hal, self)
        self.program.start()
