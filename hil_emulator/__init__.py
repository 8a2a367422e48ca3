"""Hardware-in-the-loop emulator: MuJoCo plant, bus fabric, virtual serial ports."""

import protocol  # noqa: F401 - first: it decides compiled core or source
