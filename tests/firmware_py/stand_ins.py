"""Stand-in programs for the boot program's tests: the least an application can be."""

from __future__ import annotations

from firmware_py.hal import Hal
from firmware_py.hand_node import HandNode
from firmware_py.mcu import Mcu


class TinyApp(HandNode):
    """A stand-in fmcb application on the pogo UART that answers the common messages (reset
    included)."""

    node_kind = "fmcb"

    def __init__(self, hal: Hal, mcu: Mcu) -> None:
        super().__init__(hal)

    def start(self) -> None:
        self.listen(self.hal.uart("pogo"))
