"""The hand's 12-joint state-and-command cycle through the palm: wire bound and library.

One cycle = :meth:`host.hand.facade.Hand.send` of the four fingers' ``fmcb.control`` (joint
targets; each routed by ``palm.route`` in a ``txn``, the four pipelined, the palm serving
each finger on its own pogo link) + one ``palm.hand_status`` (the palm's aggregated summary:
every finger's motor positions and efforts from its polls, 98 bytes of payload for all 12
joints, against 4 × 148 bytes of routed ``fmcb.status`` that would also each wait a
finger round trip: the state that crosses the host link least).

* **Bound** (explained in the note): the palm's host link is a UART, full duplex, so a
  cycle takes at least the longer of its two directions at 2 Mbaud, 10 bits per byte
  (requests out, replies back, counted from the frames the session sent and heard), and at
  least one finger hop: the routed frame on the pogo link (2 Mbaud), the fmcb's turnaround
  (:data:`~firmware_py.palm_router.FMCB_TURNAROUND_US`, what the palm budgets) and its
  reply back (the four fingers' hops overlap each other and the host link's traffic).
* **Library, in process** (``emu://hand/palm``, fingers powered): cycles per *simulated*
  second, as a fraction of the bound.
* **Library, real time** through the emulator's palm pty (``Emulator("hand")`` run in a
  thread): cycles per wall second and failed cycles (bounded by how fast the emulator keeps
  real time on the machine).

The state is the palm's summary, as fresh as its polls of the fingers (at most
:data:`~firmware_py.palm.MAX_POLL_HZ` = 200 Hz): a fresh state in every cycle at 500 Hz
would need the palm to poll faster (a smaller poll than the 148-byte ``fmcb.status``, e.g.
``fmcb.hall_counts``) or the host to route four ``fmcb.status`` (4 × ≈ 180 bytes back:
≈ 3.6 ms, < 300 Hz).  The commands' routed request/response costs ≈ 37 bytes out and 30
back per finger; a palm message carrying all four fingers' targets (``palm.hand_command``,
≈ 60 bytes, the palm writing the four ``fmcb.control`` frames, which have no reply) would
cut the host link's bytes to ≈ 60 out and ≈ 110 back.
"""

from __future__ import annotations

import time

from benchmarks.harness import Result
from firmware_py.palm_router import FMCB_TURNAROUND_US
from hil_emulator.inprocess import bring_up, forget_shared_emulators
from host.errors import HostError
from host.hand.facade import FingerCommand, Hand
from protocol.framing import parse_frame
from protocol.messages import CATALOGUE
from protocol.topology import HOST_LINK_BAUD, POGO_BAUD, wire_time_us

JOINTS = [0.2, 0.3, 0.2] * 4
_ROUTE = CATALOGUE.by_name("palm.route")
_TXN = CATALOGUE.by_name("txn")


def cycle(hand: Hand, commands: list[FingerCommand]) -> None:
    """One state-and-command cycle: the 12 joint targets out, the hand's summary back.
    The fingers are not homed (the cycle's cost does not depend on it): ``unhomed``."""
    summary = hand.palm.start("palm.hand_status")
    hand.send(commands, unhomed=True)
    hand.session.wait(summary)


def cycle_bytes(hand: Hand, commands: list[FingerCommand]) -> dict[str, int]:
    """Bytes of one cycle: host link out and in, one finger's routed frame and reply."""
    seen: list[tuple[str, bytes]] = []

    def tap(direction: str, t: float, frame: bytes) -> None:
        seen.append((direction, frame))

    hand.session.taps.append(tap)
    try:
        cycle(hand, commands)
    finally:
        hand.session.taps.remove(tap)
    out = sum(len(f) for d, f in seen if d == "tx")
    back = sum(len(f) for d, f in seen if d == "rx")
    pogo_out = pogo_back = 0
    for direction, raw in seen:
        frame = parse_frame(raw)
        if frame.type != _TXN.type_id:
            continue
        if direction == "tx":
            txn = _TXN.parse_request(frame.payload)
            if txn["inner_type"] == _ROUTE.type_id:
                pogo_out = len(_ROUTE.parse_request(txn["inner"])["frame"])
        else:
            txn = _TXN.parse_reply(frame.payload)
            if txn["inner_type"] == _ROUTE.type_id:
                pogo_back = max(pogo_back, len(_ROUTE.parse_reply(txn["inner"])["frame"]))
    return {"out": out, "back": back, "pogo_out": pogo_out, "pogo_back": pogo_back}


def bound(counts: dict[str, int]) -> tuple[float, str]:
    """(cycles per second the wires allow, how it was computed)."""
    out_us = wire_time_us(counts["out"], HOST_LINK_BAUD)
    back_us = wire_time_us(counts["back"], HOST_LINK_BAUD)
    hop_us = (wire_time_us(counts["pogo_out"], POGO_BAUD) + FMCB_TURNAROUND_US
              + wire_time_us(counts["pogo_back"], POGO_BAUD))
    total = max(out_us, back_us, hop_us)
    note = (f"max(host link out {counts['out']} B = {out_us} µs, back {counts['back']} B = "
            f"{back_us} µs @2 Mbaud full duplex; one finger hop {counts['pogo_out']}+"
            f"{counts['pogo_back']} B @2 Mbaud + {FMCB_TURNAROUND_US} µs fmcb turnaround = "
            f"{hop_us} µs) = {total} µs/cycle")
    return 1e6 / total, note


def in_process(n_cycles: int) -> tuple[float, float, dict[str, int]]:
    """(cycles per simulated second, per wall second, one cycle's bytes) in process."""
    try:
        with Hand.open("emu://hand/palm?name=bench_hand_cycle") as hand:
            hand.power("all", "full")
            hand.session.sleep(0.3)  # the fingers boot
            commands = hand.make_commands(JOINTS)
            counts = cycle_bytes(hand, commands)
            t0, w0 = hand.session.now(), time.perf_counter()
            for _ in range(n_cycles):
                cycle(hand, commands)
            sim, wall = hand.session.now() - t0, time.perf_counter() - w0
    finally:
        forget_shared_emulators()
    return n_cycles / sim, n_cycles / wall, counts


def realtime(wall_s: float) -> tuple[float, int]:
    """(cycles per wall second, failed cycles) through the emulator's palm pty."""
    from hil_emulator.emulator import Emulator
    from tests.hil_emulator.emulator_thread import serving

    emulator = Emulator("hand", physics=False, can="none")
    bring_up(emulator)
    cycles = failures = 0
    with serving(emulator) as run, Hand.open(run.ports["palm"]) as hand:
        hand.power("all", "full")
        time.sleep(0.3)  # the fingers boot
        commands = hand.make_commands(JOINTS)
        end = time.monotonic() + wall_s
        while time.monotonic() < end:
            try:
                cycle(hand, commands)
            except HostError:
                failures += 1
            cycles += 1
    return cycles / wall_s, failures


def run(quick: bool) -> list[Result]:
    sim_rate, wall_rate, counts = in_process(100 if quick else 400)
    wire, note = bound(counts)
    group = "hand cycle"
    name = "wire bound, palm.route ×4 + status"
    results = [
        Result(group, name, wire, "cyc", target=500.0, note=note),
        Result(group, "library in process (sim time)", sim_rate, "cyc", baseline=name,
               target=0.9 * wire,
               note=f"{100 * sim_rate / wire:.1f} % of the bound; {wall_rate:.0f} cycles "
                    "per wall s"),
    ]
    rt_rate, rt_failed = realtime(2.0 if quick else 5.0)
    results.append(Result(group, "library over the pty (real time)", rt_rate, "cyc",
                          baseline=name,
                          note=f"{100 * rt_rate / wire:.1f} % of the bound; {rt_failed} "
                               "failed cycles"))
    return results
