"""The arm's seven bus nodes on one half-duplex RS-485 line, and the host's adapter on it.

IDs 1–4 are the series-elastic stepper joints (:class:`~firmware_py.arm_stepper.StepperNodeApp`,
each programmed at the factory with its joint's reduction,
:data:`protocol.robot.STEPPER_REDUCTIONS`), IDs 5–7 the RX-64
servos (:class:`~firmware_py.rx64.Rx64ServoApp`).  All share one
:class:`~hil_emulator.lines.rs485_bus.Rs485Bus` at 1 Mbaud with the host's USB–RS-485 adapter, so
a host frame and a node's reply occupy the same line, take its wire time, and collide when
they overlap, as on the arm (dissertation §5.5: one bus and one protocol for all joints).

More adapters can join the line (:meth:`ArmRig.add_adapter`): a second program on its own
USB–RS-485 adapter on the same bus.  Each adapter hears every frame on the line but its own
(a USB–RS-485 adapter switches its receiver off while it drives the line, so it does not
hear its own echo), and what it sends collides with anything it overlaps, the host's frames
and the nodes' replies alike.
"""

from __future__ import annotations

from typing import Final

from firmware_py.dynamixel_slave import DynamixelSlave, LineAudience
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import make_arm_node
from firmware_py.sim.virtual_hal import VirtualHal
from firmware_py.sim.virtual_ports import VirtualUart
from hil_emulator.lines.rs485_bus import Rs485Bus
from hil_emulator.ports.host_side import HostSide
from protocol.control_tables import ARM_SERIAL_UNSET
from protocol.image import BoardType
from protocol.robot import STEPPER_REDUCTIONS, reduction_x100
from protocol.topology import ARM_BUS_BAUD, SERVO_IDS, STEPPER_IDS

#: Time from the last bit of a frame to the receivers having it (µs): transceiver delay.
ARM_TURNAROUND_US: Final = 2


class ArmRig(HostSide):
    """The arm's nodes and the host adapter on one :class:`Rs485Bus`.

    ``serial`` is the arm's serial number, programmed into every stepper node's
    ``arm_serial`` at assembly.  ``host_uart`` is the host adapter's UART on the line: what the host writes goes out with
    :meth:`send_from_host`; what the nodes answer reaches ``on_host_bytes`` (bytes, arrival µs).
    """

    def __init__(self, scheduler: Scheduler | None = None, seed: int = 0,
                 baud: int = ARM_BUS_BAUD, serial: int = ARM_SERIAL_UNSET) -> None:
        super().__init__(scheduler or Scheduler())
        self.bus = Rs485Bus(self.scheduler, baud=baud, turnaround_us=ARM_TURNAROUND_US,
                            seed=seed)
        self.nodes: dict[int, tuple[VirtualHal, DynamixelSlave]] = {}
        for dxl_id, reduction in zip(STEPPER_IDS, STEPPER_REDUCTIONS, strict=True):
            hal, app = make_arm_node(self.scheduler, BoardType.ARM_STEPPER, dxl_id)
            value = reduction_x100(reduction)
            app.factory["gear_reduction_x100"] = value  # what the factory programmed
            app.set("gear_reduction_x100", value)
            app.factory["arm_serial"] = serial  # programmed at assembly, in every node
            app.set("arm_serial", serial)
            self._attach(dxl_id, hal, app)
        for dxl_id in SERVO_IDS:
            hal, app = make_arm_node(self.scheduler, BoardType.RX64, dxl_id)
            self._attach(dxl_id, hal, app)
        self.host_uart = VirtualUart(self.scheduler, baud, name="host")
        self.host_uart.keep_sent = False
        self.bus.attach(self.host_uart, "host")
        # The nodes' verdicts on a packet in one call per packet, not one per node.
        uarts = [hal.uart("bus") for hal, _ in self.nodes.values()]
        self.bus.set_audience(uarts, LineAudience(
            [(app, uart) for (_, app), uart in zip(self.nodes.values(), uarts, strict=True)]
        ).picked)
        self.host_uart.set_receiver(self._to_host)
        #: The adapters added after the host's (:meth:`add_adapter`), in order.
        self.adapters: list[VirtualUart] = []

    def add_adapter(self) -> VirtualUart:
        """Another USB–RS-485 adapter on the line: returns its UART, named ``adapter2``,
        ``adapter3``, … (the host's is the first).  What it sends (``send``) goes on the
        line; every frame on the line but its own reaches its receiver (``set_receiver``:
        bytes, arrival µs)."""
        uart = VirtualUart(self.scheduler, self.bus.baud, name=f"adapter{len(self.adapters) + 2}")
        uart.keep_sent = False
        self.bus.attach(uart, uart.name)
        self.adapters.append(uart)
        return uart

    def _attach(self, dxl_id: int, hal: VirtualHal, app: DynamixelSlave) -> None:
        uart = hal.uart("bus")
        uart.keep_sent = False
        # A status packet reaches only the host and the node whose BULK_READ turn it ends.
        self.bus.attach(uart, f"id{dxl_id}", hears=app.acts_on)
        self.nodes[dxl_id] = (hal, app)

    @property
    def stepper_hals(self) -> list[VirtualHal]:
        """HALs of the stepper joints J1–J4, in joint order."""
        return [self.nodes[i][0] for i in STEPPER_IDS]

    @property
    def servo_hals(self) -> list[VirtualHal]:
        """HALs of the RX-64 servos J5–J7, in joint order."""
        return [self.nodes[i][0] for i in SERVO_IDS]

    def app(self, dxl_id: int) -> DynamixelSlave:
        """The application of node ``dxl_id``."""
        return self.nodes[dxl_id][1]

    def send_from_host(self, data: bytes) -> None:
        """The host adapter drives ``data`` onto the line now."""
        self.host_uart.send(data)
