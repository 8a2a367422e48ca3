"""The optional compiled core: its module list, its clean-up, and (slow) that a compiled
build sends the host exactly the bytes the pure-Python modules send."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tools import build_compiled
from tools.build_compiled import COMPILED_MODULES, ROOT, clean, compiled_files

#: What the slow test compiles: the scheduler, the CRCs and the frame codec (every frame and tick).
SMOKE_MODULES = COMPILED_MODULES[:3]
#: What a compiled traffic record needs besides the compiled modules themselves.
PACKAGES = ("protocol", "firmware_py", "hil_emulator", "tools")


def test_every_compiled_module_is_a_source_file_of_ours() -> None:
    assert COMPILED_MODULES
    for module in COMPILED_MODULES:
        assert module.endswith(".py")
        assert (ROOT / module).is_file(), module
        assert module.split("/", 1)[0] in PACKAGES


def test_clean_removes_the_extensions_and_the_build_directory(tmp_path: Path) -> None:
    built = []
    for module in COMPILED_MODULES:
        source = tmp_path / module
        source.parent.mkdir(parents=True, exist_ok=True)
        source.write_text("")
        extension = source.with_name(f"{source.stem}.cpython-311-x86_64-linux-gnu.so")
        extension.write_bytes(b"")
        built.append(extension)
    shared = tmp_path / "0123abcd__mypyc.cpython-311-x86_64-linux-gnu.so"
    shared.write_bytes(b"")
    (tmp_path / "build" / "temp").mkdir(parents=True)
    assert set(compiled_files(tmp_path)) == {*built, shared}
    removed = clean(tmp_path)
    assert tmp_path / "build" in removed
    assert compiled_files(tmp_path) == []
    assert not (tmp_path / "build").exists()
    assert all((tmp_path / module).is_file() for module in COMPILED_MODULES)


def test_the_pure_python_modules_are_the_default() -> None:
    """Nothing in the test run builds the extensions (``make test`` stays pure Python)."""
    if compiled_files(ROOT):
        pytest.skip("a compiled build is present in this checkout (make clean-compiled)")
    assert build_compiled.loaded_compiled() == []


def test_the_whole_compile_set_type_checks_as_mypyc_sees_it() -> None:
    """mypyc type-checks exactly :data:`COMPILED_MODULES` (with what they import) before it
    compiles; that set can fail where ``make typecheck`` of whole packages passes (an
    import cycle met in another order), and the slow smoke build compiles only a few."""
    result = subprocess.run([sys.executable, "-m", "mypy", "--config-file", "pyproject.toml",
                             *build_compiled._MYPY_FLAGS,
                             *COMPILED_MODULES], cwd=ROOT, capture_output=True, text=True,
                            timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr


def _digest_of(root: Path) -> str:
    env = {**os.environ, "PYTHONPATH": str(root)}
    out = subprocess.run([sys.executable, "-m", "tools.traffic_record", "--seed", "7"],
                         cwd=root, env=env, capture_output=True, text=True, check=True).stdout
    return str(json.loads(out)["digest"])


@pytest.mark.slow
@pytest.mark.timeout(2400)
def test_compiled_build_sends_the_same_traffic(tmp_path: Path) -> None:
    """Build into a copy of the packages, then compare the traffic digest with pure Python.

    The clock, the CRCs and the frame codec only (:data:`SMOKE_MODULES`): building all of
    ``COMPILED_MODULES`` takes about five minutes, too long for ``make test``; the same
    build path compiles the rest (``make compiled``)."""
    if shutil.which("cc") is None and shutil.which("gcc") is None:
        pytest.skip("no C compiler (cc or gcc): the compiled core cannot be built here")
    pytest.importorskip("mypyc", reason="mypyc (comes with mypy) is not installed")
    copy = tmp_path / "src"
    for package in PACKAGES:
        shutil.copytree(ROOT / package, copy / package,
                        ignore=shutil.ignore_patterns("__pycache__", "*.so"))
    shutil.copy(ROOT / "pyproject.toml", copy / "pyproject.toml")  # its [tool.mypy]
    pure = _digest_of(copy)
    # In its own process, as `make compiled` runs it: mypy looks for modules on sys.path,
    # which here holds the checkout as well as the copy.
    env = {**os.environ, "PYTHONPATH": str(copy)}
    done = subprocess.run([sys.executable, "-m", "tools.build_compiled",
                           "--build-dir", str(tmp_path / "build"), "--only", *SMOKE_MODULES],
                          cwd=copy, env=env, capture_output=True, text=True)
    assert done.returncode == 0, f"the compiled core did not build: {done.stderr[-2000:]}"
    built = compiled_files(copy)
    assert len([p for p in built if "__mypyc" not in p.name]) == len(SMOKE_MODULES)
    loaded = subprocess.run(
        [sys.executable, "-c",
         "from tools.build_compiled import loaded_compiled; print(len(loaded_compiled()))"],
        cwd=copy, env=env, capture_output=True, text=True, check=True).stdout.strip()
    assert loaded == str(len(SMOKE_MODULES))
    assert _digest_of(copy) == pure
