"""Fixtures of the tools' tests: an arm on an in-process emulator at the module's ``URL``,
freshly powered for each test and shared with the CLI runs the test makes on that URL."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from hil_emulator.inprocess import forget_shared_emulators
from host.arm.facade import Arm


@pytest.fixture()
def arm(request: pytest.FixtureRequest) -> Iterator[Arm]:
    """A freshly powered arm (torque off, not homed) shared with the armctl runs."""
    forget_shared_emulators()
    with Arm.open(request.module.URL) as opened:
        yield opened
    forget_shared_emulators()
