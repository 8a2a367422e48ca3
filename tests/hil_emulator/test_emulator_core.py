"""The emulator core stands alone: importing it runs no fault, no host library, no
in-process transport (``python -X importtime`` shows what an import pulls in)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from hil_emulator.emulator import Emulator
from hil_emulator.pacing import Pacer
from hil_emulator.robot import EmulatedRobot


def _imported_by(module: str) -> set[str]:
    """Every module ``import module`` imports in a fresh interpreter (from -X importtime)."""
    out = subprocess.run([sys.executable, "-X", "importtime", "-c", f"import {module}"],
                         capture_output=True, text=True, check=True)
    return {line.rsplit("|", 1)[-1].strip() for line in out.stderr.splitlines()
            if line.startswith("import time:") and "|" in line}


@pytest.mark.parametrize("module", ["hil_emulator.emulator", "hil_emulator.robot",
                                    "hil_emulator.pacing"])
def test_importing_the_core_imports_no_fault_and_no_host_library(module: str) -> None:
    imported = _imported_by(module)
    assert module in imported  # the probe sees the import at all
    above = sorted(m for m in imported
                   if m.startswith(("hil_emulator.faults", "hil_emulator.inprocess", "host",
                                    "tools")) and m not in SHARED_HOST_MODULES)
    assert above == []


#: The host modules the emulator's core may import: the real-time scheduling both sides'
#: threads ask for, a leaf of the standard library (and the package above it, whose public
#: names load on first use, with the flat names' aliases, another such leaf).
SHARED_HOST_MODULES = frozenset({"host", "host.scheduling", "host.old_module_names"})


def test_the_host_modules_the_core_shares_import_nothing_of_ours() -> None:
    imported = _imported_by("host.scheduling")
    assert "host.scheduling" in imported
    ours = sorted(m for m in imported if m.split(".")[0] in
                  {"protocol", "firmware_py", "host", "bootloader", "hil_emulator", "tools"})
    assert ours == sorted(SHARED_HOST_MODULES)


def test_the_emulator_is_a_robot_with_ports_served_by_its_pacer() -> None:
    with Emulator("arm", physics=False) as emu:
        assert isinstance(emu, EmulatedRobot)
        assert isinstance(emu.pacer, Pacer) and emu.pacer.ports is emu.links
        emu.open_ports()
        assert emu.links["arm"].fileno() >= 0  # its pty, waited on by the pacer
        t0 = emu.scheduler.now_us()
        emu.step(1_000)
        assert emu.scheduler.now_us() == t0 + 1_000
        assert emu.lateness_stats()["count"] == 0  # never paced to the wall clock
