"""Fixtures of the fault tests: a hand emulator brought up, without physics."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from hil_emulator.inprocess import bring_up
from tests.hil_emulator.faults.probes import FaultyEmulator


@pytest.fixture
def hand() -> Iterator[FaultyEmulator]:
    """A hand without physics, brought up (about 1 s of wall time)."""
    emu = FaultyEmulator("hand", seed=4, physics=False, can="none")
    bring_up(emu)
    yield emu
    emu.close()
