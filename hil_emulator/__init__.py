"""Hardware-in-the-loop emulator: MuJoCo plant, bus fabric, virtual serial ports."""
