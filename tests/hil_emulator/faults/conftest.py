"""Fixtures of the fault tests: a hand emulator brought up, without physics."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from hil_emulator.emulator import Emulator


@pytest.fixture
def hand() -> Iterator[Emulator]:
    """A hand without physics, brought up (about 1 s of wall time)."""
    emu = Emulator("hand", seed=4, physics=False, can="none")
    emu.bring_up()
    yield emu
    emu.close()
