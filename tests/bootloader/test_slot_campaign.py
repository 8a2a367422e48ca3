"""The two-slot update's interruption campaign, on the in-process emulator.

Each case runs ``flash-all-fingers``' update of all twelve nodes and breaks it once: the
host killed, a node's power cut, a finger's link dropped (at a random frame of the run:
download, swap or confirmation), a node's power cut during its swap's page copies (at a
random page write), an image that crashes at boot, or a host that never confirms.  Then,
with no re-run, the hand is left alone past every trial (the trial watchdog; or until no
node has a trial, swap, revert or boot under way, after which nothing changes), a user powers
the fingers and phalanges as after any reset, and every node must answer from an
application running its previous or its new image, confirmed: never none, and never an
image still unconfirmed after its trial.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

import pytest
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

from bootloader.batch import run_plan
from bootloader.plan import make_plan
from firmware_py.hal import Hal
from firmware_py.mcu import Mcu
from firmware_py.sim.boards import APP_PROGRAMS
from firmware_py.sim.virtual_hal import VirtualHal
from firmware_py.slot_swap import read_record
from hil_emulator.emulator import Emulator
from hil_emulator.inprocess import EmulatorTransport, bring_up
from host.errors import HostError
from host.hand.session import HandSession, Target
from protocol.image import BoardType, FirmwareImage
from protocol.messages.boot_program import AUTOBOOT_WINDOW_US
from protocol.messages.palm import FingerPower
from protocol.messages.slots import TRIAL_TIMEOUT_US, SlotState
from protocol.topology import FINGERS, Hop

BOARDS = (BoardType.FMCB, BoardType.F2, BoardType.F3)
NEW_VERSION = (2, 3, 4)
KINDS = ("host_killed", "node_power_cut", "link_dropped", "swap_page_cut", "crash_at_boot",
         "never_confirmed")


class HostKilled(BaseException):
    """The host process dies (nothing in the engine may catch it)."""


def images(crashing: BoardType | None = None) -> dict[BoardType, FirmwareImage]:
    return {b: FirmwareImage.build(bytes(range(256)) * 9 + b"2.3.4" + b.name.encode(), b,
                                   "2.3.4", "crash" if b == crashing else b.name.lower())
            for b in BOARDS}


def crashing_app(board: BoardType) -> Callable[[Hal, Mcu], Any]:
    """The board's application, but it resets itself 2 ms after it starts (a crash)."""
    module, _, attr = APP_PROGRAMS[board.name.lower()].partition(":")
    base = getattr(importlib.import_module(module), attr)

    def start(self: Any) -> None:
        base.start(self)
        self.hal.clock.call_later(2_000, self.hal.reset)

    cls = type(f"Crashing{attr}", (base,), {"start": start})
    return lambda hal, mcu: cls(hal, mcu)


def node(emu: Emulator, finger: int, board: BoardType) -> Mcu:
    assert emu.hand is not None
    f = emu.hand.fingers[finger]
    mcu: Mcu = {BoardType.FMCB: f.fmcb, BoardType.F2: f.f2, BoardType.F3: f.f3}[board]
    return mcu


def all_nodes(emu: Emulator) -> list[tuple[str, Mcu]]:
    return [(f"finger {f} {b.name.lower()}", node(emu, f, b))
            for f in range(FINGERS) for b in BOARDS]


def cut(emu: Emulator, mcu: Mcu, board: BoardType, finger: int) -> None:
    """Power lost at ``mcu`` for 20 ms (an fmcb takes its phalanges' supply with it)."""
    victims = ([node(emu, finger, b) for b in BOARDS] if board == BoardType.FMCB else [mcu])
    for victim in victims:
        victim.power_off()
    emu.scheduler.call_later(20_000, mcu.power_on)


def arm_swap_page_cut(emu: Emulator, finger: int, board: BoardType, nth: int) -> None:
    """Cut ``board``'s power at its ``nth`` page write once a swap has begun (a copy of the
    swap, or a status record), whichever swap: the update's or a revert."""
    mcu = node(emu, finger, board)
    assert isinstance(mcu.hal, VirtualHal)
    flash = mcu.hal.flash
    original = flash.write_page
    count = [0]

    def write_page(page: int, data: bytes, done: Callable[[bool], None]) -> None:
        original(page, data, done)
        if read_record(flash)[0].in_swap:
            count[0] += 1
            if count[0] == nth:
                flash.write_page = original  # type: ignore[method-assign]
                emu.scheduler.call_later(1_000, lambda: cut(emu, mcu, board, finger))

    flash.write_page = write_page  # type: ignore[method-assign]


def run_case(kind: str, finger: int, board: BoardType, after: int) -> None:
    emu = Emulator("hand", physics=False, can="none")
    try:
        bring_up(emu)
        before = {name: getattr(mcu.program, "fw_version", None) for name, mcu in all_nodes(emu)}
        crashing = board if kind == "crash_at_boot" else None
        if crashing is not None:
            for f in range(FINGERS):
                node(emu, f, crashing).apps["crash"] = crashing_app(crashing)  # type: ignore[index]
        if kind == "swap_page_cut":
            arm_swap_page_cut(emu, finger, board, 1 + after % 40)
        session = HandSession(EmulatorTransport(emu, "palm"))
        sent = [0]

        def fault(direction: str, t: float, frame: bytes) -> None:
            if direction != "tx":
                return
            sent[0] += 1
            if sent[0] != after:
                return
            if kind == "host_killed":
                raise HostKilled()
            if kind == "node_power_cut":
                cut(emu, node(emu, finger, board), board, finger)
            elif kind == "link_dropped":
                emu.break_away(finger)
                emu.scheduler.call_later(150_000, lambda: emu.reattach(finger))

        session.taps.append(fault)
        plan = make_plan(images(crashing), keep_trial=kind == "never_confirmed")
        try:
            run_plan(session, plan)
        except (HostKilled, HostError):
            pass
        session.close()
        check_every_node(emu, before)
    finally:
        emu.close()


#: How often (µs, simulated) the wait after a case looks whether the hand has settled.
SETTLED_POLL_US = 250_000
#: The wait (µs) before the first look: past anything a case schedules (its faults' ends).
SETTLED_AFTER_US = 1_000_000


def settled(emu: Emulator) -> bool:
    """Whether nothing more happens to any node's slots without a reset: every record
    confirmed, every powered node running an application (no trial, swap or revert under
    way, no boot program counting down its autoboot window)."""
    return all(read_record(mcu.hal.flash)[0].state == SlotState.CONFIRMED
               and (not mcu.powered or mcu.program_name not in (None, "bootloader"))
               for _, mcu in all_nodes(emu))


def check_every_node(emu: Emulator, before: dict[str, Any]) -> None:
    """No re-run: wait out every trial (until the hand has :func:`settled`, at most a trial's
    timeout and an autoboot window: from a settled hand later is the same), power up as a
    user would, then check each node."""
    emu.step(SETTLED_AFTER_US)  # what the case scheduled (a power back, a link back) happens
    left = TRIAL_TIMEOUT_US + AUTOBOOT_WINDOW_US + 1_000_000 - SETTLED_AFTER_US
    while left > 0 and not settled(emu):
        emu.step(min(SETTLED_POLL_US, left))
        left -= SETTLED_POLL_US
    with HandSession(EmulatorTransport(emu, "palm")) as session:
        for f in range(FINGERS):
            session.request("palm.finger_power",
                            {"finger": f, "state": FingerPower.FULL, "stagger_ms": 0})
        emu.step(AUTOBOOT_WINDOW_US + 500_000)
        for f in range(FINGERS):
            session.request("fmcb.phalange_power", {"on": 1}, to=Target(f, Hop.FMCB))
        emu.step(AUTOBOOT_WINDOW_US + 500_000)
        for name, mcu in all_nodes(emu):
            assert mcu.program_name not in (None, "bootloader"), f"{name} runs no image"
            version = getattr(mcu.program, "fw_version", None)
            assert version in (before[name], NEW_VERSION), f"{name} runs {version}"
            record = read_record(mcu.hal.flash)[0]
            assert record.state == SlotState.CONFIRMED, f"{name}: {record.state.name}"
            who = session.request("identify", to=Target(int(name.split()[1]),
                                                        Hop[name.split()[2].upper()]))
            v = who["fw_version"]
            assert (v["major"], v["minor"], v["patch"]) == version


#: Frames the host sends in an uninterrupted update of twelve nodes: about 1 to 200
#: download, 200 to 250 the fmcbs' swaps, checks and confirmations, then polls while the
#: phalanges boot behind them, 1100 to 1200 the phalanges' swaps, checks and confirmations.
FRAME = st.one_of(st.integers(1, 200), st.integers(195, 250), st.integers(250, 1100),
                  st.integers(1100, 1210))
CASES = st.tuples(st.sampled_from(KINDS), st.integers(0, FINGERS - 1), st.sampled_from(BOARDS),
                  FRAME)


@settings(max_examples=3, deadline=None, suppress_health_check=list(HealthCheck))
@given(case=CASES)
def test_an_interrupted_slot_update_leaves_every_node_on_a_confirmed_image(
        case: tuple[str, int, BoardType, int]) -> None:
    run_case(*case)


@pytest.mark.parametrize(("kind", "board", "after"), [
    ("host_killed", BoardType.F3, 1130),        # during the phalanges' swaps
    ("node_power_cut", BoardType.FMCB, 220),    # the fmcb during its check
    ("link_dropped", BoardType.F2, 150),        # during the download
    ("swap_page_cut", BoardType.FMCB, 5),       # the fmcb's 5th page write of its swap
    ("swap_page_cut", BoardType.F3, 12),
    ("crash_at_boot", BoardType.F2, 0),
    ("never_confirmed", BoardType.FMCB, 0),
])
def test_each_kind_of_fault_once(kind: str, board: BoardType, after: int) -> None:
    run_case(kind, 1, board, after)


#: The campaign's cases, run in :data:`CAMPAIGN_SHARDS` tests of equal share (so that the
#: workers of ``make test-long`` share them out).  Shard ``k`` draws its frames from those
#: ``≡ k (mod CAMPAIGN_SHARDS)``, so no two shards run the same case.
CAMPAIGN_CASES = 200
CAMPAIGN_SHARDS = 8
#: ``make test`` runs a sample of the campaign instead (``make test-long`` both): this many
#: cases in :data:`SAMPLE_SHARDS` shards, on seeds of their own.
SAMPLE_CASES = 32
SAMPLE_SHARDS = 4


def shard_cases(shard: int, shards: int) -> st.SearchStrategy[tuple[str, int, BoardType, int]]:
    """:data:`CASES` with the frame moved up to the next one ``≡ shard (mod shards)``."""
    return CASES.map(lambda c: (*c[:3], c[3] + (shard - c[3]) % shards))


def run_shard(shard: int, shards: int, cases: int, seed_value: int) -> None:
    """Shard ``shard`` of a campaign of ``cases`` cases in ``shards`` shards: its share of
    them, drawn on ``seed_value``; checks that it ran that many."""
    assert cases % shards == 0
    ran: list[tuple[str, int, BoardType, int]] = []

    @seed(seed_value)
    @settings(max_examples=cases // shards, deadline=None,
              suppress_health_check=list(HealthCheck), database=None)
    @given(case=shard_cases(shard, shards))
    def campaign(case: tuple[str, int, BoardType, int]) -> None:
        ran.append(case)
        run_case(*case)

    campaign()
    assert len(ran) == cases // shards  # the shards add up to the campaign


@pytest.mark.slow
@pytest.mark.parametrize("shard", range(SAMPLE_SHARDS))
def test_slot_update_campaign_sample_of_32_cases(shard: int) -> None:
    """Shard ``shard`` of a 32-case sample of the campaign (``make test``)."""
    run_shard(shard, SAMPLE_SHARDS, SAMPLE_CASES, seed_value=1_000 + shard)


@pytest.mark.slow
@pytest.mark.long
@pytest.mark.timeout(7200)
@pytest.mark.parametrize("shard", range(CAMPAIGN_SHARDS))
def test_slot_update_campaign_of_200_cases(shard: int) -> None:
    """Shard ``shard`` of the 200 cases (:data:`CAMPAIGN_CASES`; ``make test-long``)."""
    run_shard(shard, CAMPAIGN_SHARDS, CAMPAIGN_CASES, seed_value=shard)
