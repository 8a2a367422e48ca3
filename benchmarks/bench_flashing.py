"""Flashing all twelve finger nodes with 64 KiB images, against the wire's bound.

The flashing engine (:func:`bootloader.batch.run_plan`) runs on the in-process emulator
(``physics`` off): its time is the simulation clock's, and the emulator's timing is the
wire's (every frame arrives at its last bit, every page program takes the flash's time), so
the seconds reported are real-time-equivalent whatever the machine.

The lower bound is what the links must carry: every node's image pages (a 256-byte header
page and 256 payload pages), each in one ``bl.write_page`` frame (7 bytes of framing, the u32
page number, 256 bytes) — envelopes, routing headers, replies, hashes and boot windows not
counted.  The host link carries all twelve nodes' pages, each finger's pogo link its three
nodes', each tendon bus its two phalanges' (Manchester: twice the time); each link's bytes
over its rate give its time, and the slowest link governs.

Sequential: the same engine flashing one finger after another (parallelism 1), on the same
kind of hand.  Targets: within 1.5× of the bound, and at least 3× faster than sequential.
Rates are image bytes per simulated second (KiB/s).  These run the one-slot way
(``--one-slot``: every node halted in its bootloader and written).

The two-slot update (the default): the same twelve images downloaded into the secondary
slots while the applications run, then swapped, checked and confirmed.  Its total time is
compared with the same wire bound (download only: the swaps are flash time on the nodes);
the downtime of each node is from its swap (a phalange: its fmcb's) to the first answer of
its new application, on the simulation clock, with a target of one reboot for an fmcb (the
node's own swap of the image's pages, :func:`one_reboot_s`, plus 0.1 s); a phalange's also
holds the autoboot window it boots through behind its rebooted fmcb.  Then the time of
``--rollback`` of all twelve nodes (each swaps its previous image back and is confirmed).
"""

from __future__ import annotations

import hashlib
import math
import time

from benchmarks.harness import Result
from bootloader.batch import RunReport, run_plan, run_rollback
from bootloader.plan import make_plan, rollback_plan
from firmware_py.sim.virtual_hal import PAGE_WRITE_US
from hil_emulator.emulator import Emulator
from hil_emulator.inprocess import EmulatorTransport, bring_up
from host.hand.session import HandSession
from protocol.framing import OVERHEAD
from protocol.image import FLASH, BoardType, FirmwareImage
from protocol.messages.boot_program import AUTOBOOT_WINDOW_US
from protocol.topology import (
    FINGERS,
    HOST_LINK_BAUD,
    POGO_BAUD,
    TENDON_BAUD,
    TENDON_MANCHESTER,
    wire_time_us,
)

BOARDS = (BoardType.FMCB, BoardType.F2, BoardType.F3)
#: Payload of each image (bytes).
IMAGE_PAYLOAD = 64 * 1024


def images(version: str) -> dict[BoardType, FirmwareImage]:
    """A 64 KiB image per finger board (deterministic, incompressible filler)."""
    out = {}
    for board in BOARDS:
        payload = b"".join(hashlib.sha256(bytes([board, i & 0xFF, i >> 8])).digest()
                           for i in range(IMAGE_PAYLOAD // 32))
        out[board] = FirmwareImage.build(payload, board, version, board.name.lower())
    return out


def bound(image: FirmwareImage) -> tuple[float, str]:
    """The wire's lower bound (s) for all twelve nodes, and how it was computed."""
    pages = len(image.pages())
    frame = OVERHEAD + 4 + FLASH.page_size
    per_node = pages * frame
    links = {
        "host link": wire_time_us(FINGERS * len(BOARDS) * per_node, HOST_LINK_BAUD),
        "pogo (each finger)": wire_time_us(len(BOARDS) * per_node, POGO_BAUD),
        "tendon bus (each finger)": wire_time_us(2 * per_node, TENDON_BAUD,
                                                  manchester=TENDON_MANCHESTER),
    }
    slowest = max(links, key=lambda k: links[k])
    how = (f"{pages} pages × {frame} B per node; " + ", ".join(
        f"{name} {t / 1e6:.2f} s" for name, t in links.items()) + f"; {slowest} governs")
    return links[slowest] / 1e6, how


def one_reboot_s(image: FirmwareImage) -> float:
    """Flash time (s) of an fmcb's swap of ``image`` over an image of the same size: three
    copies of each page, a status record per copy of a chunk, the activation and the trial
    record (:mod:`firmware_py.slot_swap`), at the flash's page time."""
    pages = len(image.pages())
    writes = 3 * pages + 3 * math.ceil(pages / FLASH.scratch_pages) + 2
    return writes * PAGE_WRITE_US / 1e6


def _slot_update() -> tuple[RunReport, RunReport, float]:
    """Update all twelve nodes through their slots, then roll them back; (update report,
    rollback report, wall s)."""
    emu = Emulator("hand", physics=False, can="none")
    bring_up(emu)
    wall = time.perf_counter()
    try:
        with HandSession(EmulatorTransport(emu, "palm")) as session:
            update = run_plan(session, make_plan(images("2.0.0")))
            if not update.ok:
                failed = [r.to_dict() for r in update.nodes if r.result != "flashed"]
                raise RuntimeError(f"the two-slot update failed: {failed}")
            back = run_rollback(session, rollback_plan())
            if not back.ok:
                raise RuntimeError(f"the rollback failed: {[r.to_dict() for r in back.nodes]}")
    finally:
        emu.close()
    return update, back, time.perf_counter() - wall


def _flash(fingers: list[list[int]], version: str) -> tuple[float, float, list[RunReport]]:
    """Flash each group of ``fingers`` in turn on a fresh hand; (sim s, wall s, reports)."""
    emu = Emulator("hand", physics=False, can="none")
    bring_up(emu)
    sim = 0.0
    reports = []
    wall = time.perf_counter()
    try:
        with HandSession(EmulatorTransport(emu, "palm")) as session:
            for group in fingers:
                report = run_plan(session, make_plan(images(version), group, slots=False))
                if not report.ok:
                    failed = [r.to_dict() for r in report.nodes if r.result == "failed"]
                    raise RuntimeError(f"flashing fingers {group} failed: {failed}")
                sim += report.total_seconds
                reports.append(report)
    finally:
        emu.close()
    return sim, time.perf_counter() - wall, reports


def run(quick: bool) -> list[Result]:
    image = images("2.0.0")[BoardType.FMCB]
    total_kib = FINGERS * len(BOARDS) * len(image.payload) / 1024
    bound_s, how = bound(image)
    parallel_s, parallel_wall, reports = _flash([list(range(FINGERS))], "2.0.0")
    slowest = max(reports[0].nodes, key=lambda r: r.seconds)
    sequential_s, sequential_wall, _ = _flash([[k] for k in range(FINGERS)], "2.0.0")
    group = "flashing"
    name = "wire bound, 12 × 64 KiB"
    return [
        Result(group, name, total_kib / bound_s, "KiB", note=f"{bound_s:.2f} s: {how}"),
        Result(group, "engine, 4 fingers at once", total_kib / parallel_s, "KiB",
               baseline=name, target=total_kib / (1.5 * bound_s),
               note=f"{parallel_s:.2f} s simulated ({parallel_s / bound_s:.2f}× the bound; "
                    f"slowest node {slowest.job.name} {slowest.seconds:.2f} s), "
                    f"{parallel_wall:.0f} s wall; ≥ 3× sequential: "
                    f"{'met' if sequential_s >= 3 * parallel_s else 'MISSED'} "
                    f"({sequential_s / parallel_s:.1f}×)"),
        Result(group, "engine, one finger at a time", total_kib / sequential_s, "KiB",
               baseline=name,
               note=f"{sequential_s:.2f} s simulated, {sequential_wall:.0f} s wall"),
        *_slot_results(image, total_kib, bound_s, name),
    ]


def _slot_results(image: FirmwareImage, total_kib: float, bound_s: float,
                  bound_name: str) -> list[Result]:
    update, back, wall = _slot_update()
    group = "flashing"
    reboot = one_reboot_s(image)
    fmcb = [r for r in update.nodes if r.job.board == BoardType.FMCB]
    phalanges = [r for r in update.nodes if r.job.board != BoardType.FMCB]
    worst_fmcb = max(fmcb, key=lambda r: r.downtime_s or 0.0)
    worst_phalange = max(phalanges, key=lambda r: r.downtime_s or 0.0)
    per_finger = ", ".join(
        f"{f}: {max(r.downtime_s or 0.0 for r in update.nodes if r.job.finger == f):.2f} s"
        for f in range(FINGERS))
    slowest_back = max(back.nodes, key=lambda r: r.rollback_s or 0.0)
    return [
        Result(group, "two-slot update, 4 fingers at once", total_kib / update.total_seconds,
               "KiB", baseline=bound_name,
               note=f"{update.total_seconds:.2f} s simulated "
                    f"({update.total_seconds / bound_s:.2f}× the bound), {wall:.0f} s wall "
                    "with the rollback below"),
        Result(group, "two-slot update: fmcb downtime (finger motion)",
               worst_fmcb.downtime_s or math.nan, "s", at_most=True, target=reboot + 0.1,
               note=f"worst {worst_fmcb.job.name}; one reboot = its swap's flash time "
                    f"{reboot:.2f} s + 0.1 s; each finger's worst node: {per_finger}"),
        Result(group, "two-slot update: phalange downtime (sensors)",
               worst_phalange.downtime_s or math.nan, "s", at_most=True,
               note=f"worst {worst_phalange.job.name}: its fmcb's reboot, its autoboot "
                    f"window behind it ({AUTOBOOT_WINDOW_US / 1e6:g} s), then its own swap"),
        Result(group, "rollback of 12 nodes", back.total_seconds, "s", at_most=True,
               note=f"slowest node {slowest_back.job.name} "
                    f"{slowest_back.rollback_s or 0.0:.2f} s from its request to its "
                    "previous application; each swaps back and is confirmed"),
    ]
