"""Wire formats of the hand and arm, and nothing else: no I/O.

- :mod:`protocol.framing`, :mod:`protocol.stream`: hand frames and their stream decoder
- :mod:`protocol.manchester`: the tendon bus line code
- :mod:`protocol.messages`: the message catalogue (:data:`protocol.messages.CATALOGUE`)
- :mod:`protocol.canlink`: hand frames on CAN
- :mod:`protocol.dynamixel`, :mod:`protocol.control_tables`: the arm bus
- :mod:`protocol.image`: firmware images and the flash geometry
- :mod:`protocol.robot`: the robot's mechanical facts (gearing, coupling, limits, layouts)
- :mod:`protocol.errors`: the one exception tree (:class:`ProtocolError`)

Importing it decides first whether the compiled core is used (:mod:`protocol.compiled_guard`).
"""

from protocol import compiled_guard as _compiled_guard

_compiled_guard.install()

from protocol.errors import ProtocolError  # noqa: E402 - after the guard, deliberately

__all__ = ["ProtocolError"]
