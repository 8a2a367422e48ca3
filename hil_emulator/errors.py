"""The emulator's one exception tree.

Every error also inherits the built-in a caller would catch for it: a bad configuration is a
``ValueError``, a port that cannot be made an ``OSError``, a physics model that does not build
or diverges a ``RuntimeError``::

    EmulatorError
    ├── EmulatorConfigError(ValueError)   a configuration, layout, seed or parameter
    │   └── FaultPlanError                a fault plan, a fault's parameters or a scenario
    ├── PortError(OSError)                a virtual serial port or link
    └── PlantError(RuntimeError)          the MuJoCo plant would not build, bind or stay stable
"""

from __future__ import annotations


class EmulatorError(Exception):
    """Base of every error the emulator raises on purpose."""


class EmulatorConfigError(EmulatorError, ValueError):
    """A configuration, layout, seed or parameter the emulator cannot use."""


class PortError(EmulatorError, OSError):
    """A virtual serial port or link could not be created, used or removed."""


class PlantError(EmulatorError, RuntimeError):
    """The MuJoCo plant could not be built, bound to the firmware, or went unstable."""


class FaultPlanError(EmulatorConfigError):
    """A fault plan, a fault's parameters or a scenario file the emulator cannot use; the
    message names the key (``faults[2].params.finger``)."""
