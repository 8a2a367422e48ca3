"""The import paths users have: the public names at ``host``, the rooms' facades, and the
flat module names of before the rooms as deprecated aliases of the modules they became."""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

import hil_emulator
import host

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("name", sorted(host.EXPORTS))
def test_each_public_name_comes_from_its_module(name: str) -> None:
    assert getattr(host, name) is getattr(importlib.import_module(host.EXPORTS[name]), name)


def test_an_unknown_public_name_is_an_attribute_error() -> None:
    with pytest.raises(AttributeError, match="no attribute 'Handd'"):
        _ = host.Handd  # type: ignore[attr-defined]


@pytest.mark.process_wide("the view's modules load pyarrow, whose threads last the process")
@pytest.mark.parametrize(("package", "old", "new"), sorted(
    [("host", o, n) for o, n in host.MOVED.items()]
    + [("hil_emulator", o, n) for o, n in hil_emulator.MOVED.items()]))
def test_a_flat_name_of_before_imports_the_module_it_became(package: str, old: str,
                                                             new: str) -> None:
    """Same module object (monkeypatching one patches the other), and a warning naming
    where it went; the old file itself is gone."""
    assert not (ROOT / package / f"{old}.py").exists()
    sys.modules.pop(f"{package}.{old}", None)
    with pytest.warns(DeprecationWarning, match=rf"{package}\.{old} is now {package}\.{new}"):
        moved = importlib.import_module(f"{package}.{old}")
    assert moved is importlib.import_module(f"{package}.{new}")


def test_the_documented_imports_run_in_a_fresh_interpreter() -> None:
    """What the README and the guide show, and what programs of before the rooms wrote."""
    code = ("import warnings; warnings.simplefilter('error', DeprecationWarning)\n"
            "from host import Arm, Hand, open_transport, RobotView, HandSession\n"
            "from host.hand import Hand as H2; from host.arm import Arm as A2\n"
            "from host.view import RobotView as V2\n"
            "from hil_emulator.emulator import Emulator\n"
            "from hil_emulator.inprocess import EmulatorTransport, bring_up\n"
            "assert (H2, A2, V2) == (Hand, Arm, RobotView)\n"
            "warnings.simplefilter('ignore', DeprecationWarning)\n"
            "from host.transport import open_transport as o2\n"
            "from host.hand_session import HandSession as S2\n"
            "from host.hand_recording import HandRecorder\n"
            "from host.finger_params import Value\n"
            "from host.recording import Recording\n"
            "assert (o2, S2) == (open_transport, HandSession)\n"
            "print('ok')\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, check=True).stdout
    assert out.strip() == "ok"
