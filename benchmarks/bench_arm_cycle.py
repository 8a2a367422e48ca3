"""The arm's full read-and-command cycle: this library against the wire's bound and the SDK.

One cycle = SYNC_WRITE of the seven goals (stepper goals and servo goals: two packets, the
models' goal registers differ) + BULK_READ of the seven nodes' state (what
:class:`host.arm.facade.Arm` reads: the 13-byte cycle block per stepper node, 6 bytes per RX-64 -
8, with voltage and temperature, one cycle in ten), nodes in fast mode (return delay 0):
193 bytes per cycle with the stepper command block, 199 on the slow cycles (199 every
cycle when each read the RX-64s' voltage and temperature, ≈ 498 cycles/s; 211 before the
stepper nodes had the cycle block, ≈ 470 cycles/s).

* **Bound**: the cycle's bytes at 1 Mbaud, 10 bits per byte, plus one 2 µs turnaround per
  reply and one back to the host, plus the return delays (0 here): the most cycles per
  second the wire allows with these registers, over ten cycles (one slow).
* **Library, in process**: :meth:`Arm.cycle` on ``emu://arm/arm`` (MuJoCo plant on), cycles
  per *simulated* second: what the library achieves on the wire (host time is free on the
  simulation clock), as a fraction of the bound (target ≥ 90 %).
* **Real time over the pty** (``hil-emulator --config arm`` in its own process): the stock
  dynamixel-sdk 4.1.0 (GroupSyncWrite ×2 + seven reads of the same registers, the RX-64s' voltage and temperature every cycle: its
  GroupBulkRead raises TypeError under protocol 1.0) against this library's same cycle on
  the same pty, cycles per wall second.  Both pay the pty and the emulator's pacing.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.harness import Result
from hil_emulator.inprocess import forget_shared_emulators
from host.arm.bus import BITS_PER_BYTE, MIN_PACKET_SIZE, TURNAROUND_US
from host.arm.facade import (
    SERVO_READ_AT,
    SERVO_SLOW_READ_LEN,
    SLOW_READ_EVERY,
    STEPPER_READ_AT,
    STEPPER_READ_LEN,
    Arm,
)
from host.errors import HostError
from protocol.control_tables import RX64_TABLE, STEPPER_TABLE

ROOT = Path(__file__).resolve().parents[1]
BAUD = 1_000_000
HOLD = [0.0] * 7


def cycle_bound(arm: Arm, return_delay_units: int = 0, slow: bool = False
                ) -> tuple[int, float]:
    """(bytes per cycle, cycles per second the wire allows) for ``arm``'s cycle: the
    ordinary one, or with ``slow`` the one in :data:`SLOW_READ_EVERY` that also reads the
    RX-64s' voltage and temperature."""
    packets = arm.packets_for(arm.make_positions(HOLD))
    out = sum(len(p.encode()) for p in packets) + len(arm.bulk_reads[slow].encode())
    replies = [MIN_PACKET_SIZE + e.length for e in arm.expected_replies[slow]]
    n_bytes = out + sum(replies)
    seconds = (n_bytes * BITS_PER_BYTE / BAUD
               + ((len(replies) + 1) * TURNAROUND_US + len(replies) * 2 * return_delay_units)
               / 1e6)
    return n_bytes, 1.0 / seconds


def mean_cycle_bound(arm: Arm) -> tuple[int, int, float]:
    """(bytes of the ordinary cycle, of the slow one, cycles per second the wire allows
    over :data:`SLOW_READ_EVERY` cycles, one of them slow)."""
    fast_bytes, fast_rate = cycle_bound(arm)
    slow_bytes, slow_rate = cycle_bound(arm, slow=True)
    seconds = (SLOW_READ_EVERY - 1) / fast_rate + 1 / slow_rate
    return fast_bytes, slow_bytes, SLOW_READ_EVERY / seconds


def library_in_process(n_cycles: int) -> tuple[float, float, Arm]:
    """(cycles per simulated second, cycles per wall second) of Arm.cycle in process."""
    arm = Arm.open("emu://arm/arm?name=bench_arm_cycle")
    arm.torque(True)
    commands = arm.make_positions(HOLD)
    t0, w0 = arm.transport.now(), time.perf_counter()
    for _ in range(n_cycles):
        arm.cycle(commands)
    sim, wall = arm.transport.now() - t0, time.perf_counter() - w0
    arm.close()
    forget_shared_emulators()
    return n_cycles / sim, n_cycles / wall, arm


def _sdk_cycle_rate(path: str, wall_s: float) -> tuple[float, int]:
    import dynamixel_sdk as sdk

    port = sdk.PortHandler(path)
    port.openPort()
    port.setBaudRate(BAUD)
    handler = sdk.PacketHandler(1.0)
    for dxl_id in range(1, 8):  # fast mode, as the library's run
        handler.write1ByteTxRx(port, dxl_id, 5, 0)
        handler.write1ByteTxRx(port, dxl_id, 24, 1)
    goals = sdk.GroupSyncWrite(port, handler, STEPPER_TABLE["goal_position"].address, 4)
    servo_goals = sdk.GroupSyncWrite(port, handler, RX64_TABLE["goal_position"].address, 2)
    for dxl_id in range(1, 5):
        goals.addParam(dxl_id, [0, 0, 0, 0])
    for dxl_id in range(5, 8):
        servo_goals.addParam(dxl_id, [0x00, 0x02])
    cycles, failures = 0, 0
    end = time.monotonic() + wall_s
    while time.monotonic() < end:
        goals.txPacket()
        servo_goals.txPacket()
        for dxl_id in range(1, 8):
            at, n = ((STEPPER_READ_AT, STEPPER_READ_LEN) if dxl_id <= 4
                     else (SERVO_READ_AT, SERVO_SLOW_READ_LEN))
            _, result, _ = handler.readTxRx(port, dxl_id, at, n)
            failures += result != sdk.COMM_SUCCESS
        cycles += 1
    port.closePort()
    return cycles / wall_s, failures


def _library_cycle_rate(path: str, wall_s: float) -> tuple[float, int]:
    time.sleep(0.1)  # let late replies to the SDK's last requests pass
    with Arm.open(path) as arm:
        arm.torque(True)
        commands = arm.make_positions(HOLD)
        cycles = failures = 0
        end = time.monotonic() + wall_s
        while time.monotonic() < end:
            try:
                arm.cycle(commands)
            except HostError:
                failures += 1
            cycles += 1
    return cycles / wall_s, failures


def realtime_rates(wall_s: float) -> dict[str, tuple[float, int]]:
    """Cycles per wall second of the SDK and of this library over the emulator's arm pty."""
    with tempfile.TemporaryDirectory(prefix="bench_arm_") as tmp:
        proc = subprocess.Popen([sys.executable, "-m", "tools.cli.serve_emulator", "--config",
                                 "arm", "--can", "none", "--link-dir", tmp], cwd=ROOT,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert proc.stdout is not None
            info: dict[str, Any] = json.loads(proc.stdout.readline())
            path = info["arm"]
            rates = {"sdk": _sdk_cycle_rate(path, wall_s),
                     "library": _library_cycle_rate(path, wall_s)}
        finally:
            proc.terminate()
            try:
                proc.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    return rates


def run(quick: bool) -> list[Result]:
    sim_rate, wall_rate, arm = library_in_process(300 if quick else 1000)
    fast_bytes, slow_bytes, bound = mean_cycle_bound(arm)
    group = "arm cycle"
    results = [
        Result(group, "wire bound, 1 Mbaud, delay 0", bound, "cyc", target=500.0,
               note=f"{fast_bytes} bytes/cycle ({slow_bytes} one cycle in "
                    f"{SLOW_READ_EVERY}) × 10 bit + turnarounds"),
        Result(group, "library in process (sim time)", sim_rate, "cyc",
               baseline="wire bound, 1 Mbaud, delay 0", target=0.9 * bound,
               note=f"{100 * sim_rate / bound:.1f} % of the bound; "
                    f"{wall_rate:.0f} cycles per wall s with the MuJoCo plant"),
    ]
    rates = realtime_rates(2.0 if quick else 5.0)
    (sdk_rate, sdk_failed), (lib_rate, lib_failed) = rates["sdk"], rates["library"]
    results += [
        Result(group, "dynamixel-sdk over the pty (real time)", sdk_rate, "cyc",
               note=f"2 GroupSyncWrite + 7 reads (its BulkRead fails on protocol 1.0); "
                    f"{sdk_failed} failed reads"),
        Result(group, "library over the pty (real time)", lib_rate, "cyc",
               baseline="dynamixel-sdk over the pty (real time)",
               note=f"{lib_failed} failed cycles; both limited by how fast the emulator "
                    "keeps real time on this machine"),
    ]
    return results
