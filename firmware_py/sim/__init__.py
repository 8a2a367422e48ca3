"""The simulated hardware under the firmware: the virtual HAL and the boards built on it.

Nothing in the firmware proper (``firmware_py/*.py``) imports this package: firmware sees
only :mod:`firmware_py.hal`.  Tests and the emulator build nodes here
(:func:`~firmware_py.sim.boards.make_node`, :func:`~firmware_py.sim.boards.make_arm_node`)
and drive the hardware's inputs through its plant side (see :mod:`firmware_py.sim.virtual_hal`).
"""
