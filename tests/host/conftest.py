"""Fixtures of the host tests: the module's hand and arm, each on an in-process emulator
(the module's ``URL``, ``emu://…?name=…``) opened once for the module."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from hil_emulator.inprocess import forget_shared_emulators
from host.arm.facade import Arm
from host.hand.facade import Hand


@pytest.fixture(scope="module")
def hand(request: pytest.FixtureRequest) -> Iterator[Hand]:
    """The hand at the module's ``URL``, brought up once; its tests share it (and what each
    leaves of its state: they say which finger each one uses)."""
    with Hand.open(request.module.URL) as opened:
        yield opened


@pytest.fixture(scope="module")
def arm(request: pytest.FixtureRequest) -> Iterator[Arm]:
    """The arm at the module's ``URL``, shared by its tests; the emulator is forgotten
    afterwards (the next module gets a freshly powered one)."""
    with Arm.open(request.module.URL) as opened:
        yield opened
    forget_shared_emulators()
