"""The compiled core: its module list, its clean-up, the set-up's choice (compiled where
built and fresh, pure Python on request or when stale), and that a compiled build sends the
host exactly the bytes the pure-Python modules send."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from protocol import compiled_guard
from protocol.compiled_guard import PURE_PYTHON_ENV
from tools import build_compiled
from tools.build_compiled import COMPILED_MODULES, ROOT, clean, compiled_files, is_built

#: What the slow test compiles: the scheduler, the HAL's interfaces and the virtual board
#: (every tick and every peripheral call goes through them).
SMOKE_MODULES = COMPILED_MODULES[:3]
#: What a compiled traffic record needs besides the compiled modules themselves.
PACKAGES = ("protocol", "firmware_py", "hil_emulator", "tools")


def test_every_compiled_module_is_a_source_file_of_ours() -> None:
    assert COMPILED_MODULES
    for module in COMPILED_MODULES:
        assert module.endswith(".py")
        assert (ROOT / module).is_file(), module
        assert module.split("/", 1)[0] in PACKAGES


def test_every_part_of_the_virtual_hal_is_compiled() -> None:
    """The virtual HAL is split by peripheral; a part left out of the list would run from
    source beside compiled callers (slower, and its classes interpreted)."""
    parts = sorted(p.relative_to(ROOT).as_posix()
                   for p in (ROOT / "firmware_py" / "sim").glob("virtual_*.py"))
    assert len(parts) > 1
    assert set(parts) <= set(COMPILED_MODULES)


def test_clean_removes_the_extensions_and_the_build_directory(tmp_path: Path) -> None:
    built = []
    for module in COMPILED_MODULES:
        source = tmp_path / module
        source.parent.mkdir(parents=True, exist_ok=True)
        source.write_text("")
        extension = source.with_name(f"{source.stem}.cpython-311-x86_64-linux-gnu.so")
        extension.write_bytes(b"")
        built.append(extension)
    # a module an earlier build compiled and the list no longer names: its extension would
    # still shadow its source, so it goes too
    dropped = tmp_path / "protocol" / "dropped.py"
    dropped.write_text("")
    built.append(dropped.with_name("dropped.cpython-311-x86_64-linux-gnu.so"))
    built[-1].write_bytes(b"")
    shared = tmp_path / "0123abcd__mypyc.cpython-311-x86_64-linux-gnu.so"
    shared.write_bytes(b"")
    (tmp_path / "build" / "temp").mkdir(parents=True)
    assert set(compiled_files(tmp_path)) == {*built, shared}
    removed = clean(tmp_path)
    assert tmp_path / "build" in removed
    assert compiled_files(tmp_path) == []
    assert not (tmp_path / "build").exists()
    assert all((tmp_path / module).is_file() for module in COMPILED_MODULES)


def _loaded(**env: str) -> int:
    """How many compiled modules a fresh process imports as extensions."""
    out = subprocess.run(
        [sys.executable, "-c",
         "from tools.build_compiled import loaded_compiled; print(len(loaded_compiled()))"],
        cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT), **env}, capture_output=True,
        text=True, check=True).stdout.strip()
    return int(out)


def test_a_fresh_build_is_imported_and_without_one_the_sources_are() -> None:
    fresh = is_built(ROOT) and not compiled_guard.stale(ROOT)
    assert _loaded(**{PURE_PYTHON_ENV: "0"}) == (len(COMPILED_MODULES) if fresh else 0)


def test_the_environment_variable_forces_pure_python() -> None:
    assert _loaded(**{PURE_PYTHON_ENV: "1"}) == 0


def test_a_build_older_than_its_source_is_ignored(tmp_path: Path) -> None:
    source = tmp_path / "firmware_py" / "scheduler.py"
    source.parent.mkdir()
    source.write_text("")
    extension = source.with_name("scheduler.cpython-311-x86_64-linux-gnu.so")
    extension.write_bytes(b"")
    os.utime(source, (1_000_000, 1_000_000))
    os.utime(extension, (2_000_000, 2_000_000))
    assert compiled_guard.extensions(tmp_path) == [(extension, source)]
    assert compiled_guard.stale(tmp_path) == []
    os.utime(source, (3_000_000, 3_000_000))  # edited after the build
    assert compiled_guard.stale(tmp_path) == [source]


def test_a_build_older_than_a_constant_it_copies_is_ignored(tmp_path: Path) -> None:
    """mypyc copies ``Final`` constants (protocol/robot.py's numbers) into the compiled
    modules: an edited constant must count although robot.py itself is not compiled."""
    source = tmp_path / "firmware_py" / "arm_stepper.py"
    constants = tmp_path / "protocol" / "robot.py"
    for path in (source, constants):
        path.parent.mkdir()
        path.write_text("")
    extension = source.with_name("arm_stepper.cpython-311-x86_64-linux-gnu.so")
    extension.write_bytes(b"")
    for path, t in ((source, 1_000_000), (constants, 1_000_000), (extension, 2_000_000)):
        os.utime(path, (t, t))
    assert compiled_guard.stale(tmp_path) == []
    os.utime(constants, (3_000_000, 3_000_000))  # a robot number edited after the build
    assert compiled_guard.stale(tmp_path) == [constants]
    assert "protocol/robot.py" in build_compiled.build_sources(tmp_path)


def test_setup_with_pure_python_requested_removes_the_build_and_says_so(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    module = tmp_path / COMPILED_MODULES[0]
    module.parent.mkdir(parents=True)
    module.write_text("")
    extension = module.with_name(f"{module.stem}.cpython-311-x86_64-linux-gnu.so")
    extension.write_bytes(b"")
    monkeypatch.setenv(PURE_PYTHON_ENV, "1")
    line = build_compiled.setup(tmp_path)
    assert line == (f"compiled core: not built ({PURE_PYTHON_ENV} is set): the emulator "
                    "runs pure Python")
    assert not extension.exists()


def test_setup_without_a_compiler_falls_back_in_one_line(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.delenv(PURE_PYTHON_ENV, raising=False)
    monkeypatch.setenv("CC", "no-such-compiler")
    monkeypatch.setenv("PATH", str(tmp_path))  # no cc, no gcc
    line = build_compiled.setup(tmp_path, tmp_path / "build")
    assert line.startswith("compiled core: cannot be built here (no C compiler")
    assert line.endswith("the emulator runs pure Python")
    printed = capsys.readouterr().out.strip().splitlines()
    assert printed[-1] == line and len(printed) == 2  # "building ..." then the outcome


def test_setup_falls_back_in_one_line_whatever_the_build_raises(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    def broken(*args: object) -> list[Path]:
        raise RuntimeError("mypyc crashed")

    monkeypatch.delenv(PURE_PYTHON_ENV, raising=False)
    monkeypatch.setattr(build_compiled, "build", broken)
    line = build_compiled.setup(tmp_path, tmp_path / "build")
    assert line.startswith("compiled core: cannot be built here (mypyc crashed; see ")
    assert line.endswith("the emulator runs pure Python")
    assert capsys.readouterr().out.strip().splitlines()[-1] == line


@pytest.mark.slow
def test_setup_falls_back_when_the_c_compiler_fails(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A compiler that is there but fails (``CC=/bin/false``): mypyc's C is not compiled,
    nothing is left behind, and the set-up says so in one line."""
    pytest.importorskip("mypyc", reason="mypyc (comes with mypy) is not installed")
    module = tmp_path / "protocol" / "tiny.py"
    module.parent.mkdir()
    module.write_text("def double(x: int) -> int:\n    return 2 * x\n")
    monkeypatch.delenv(PURE_PYTHON_ENV, raising=False)
    monkeypatch.setenv("CC", "/bin/false")
    monkeypatch.setenv("LDSHARED", "/bin/false -shared")
    line = build_compiled.setup(tmp_path, tmp_path / "build", modules=("protocol/tiny.py",))
    assert line.startswith("compiled core: cannot be built here (the C build failed")
    assert line.endswith("the emulator runs pure Python")
    assert list(tmp_path.rglob("*.so")) == []
    assert module.is_file()


def test_the_whole_compile_set_type_checks_as_mypyc_sees_it() -> None:
    """mypyc type-checks exactly :data:`COMPILED_MODULES` (with what they import) before it
    compiles; that set can fail where ``make typecheck`` of whole packages passes (an
    import cycle met in another order), and the slow smoke build compiles only a few."""
    result = subprocess.run([sys.executable, "-m", "mypy", "--config-file", "pyproject.toml",
                             *build_compiled._MYPY_FLAGS,
                             *COMPILED_MODULES], cwd=ROOT, capture_output=True, text=True,
                            timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr


def _digest_of(root: Path, **extra: str) -> str:
    env = {**os.environ, "PYTHONPATH": str(root), **extra}
    out = subprocess.run([sys.executable, "-m", "tools.traffic_record", "--seed", "7"],
                         cwd=root, env=env, capture_output=True, text=True, check=True).stdout
    return str(json.loads(out)["digest"])


def test_the_default_build_and_pure_python_send_the_same_traffic() -> None:
    """The checkout as the set-up left it (the compiled core where it could be built) and
    the same checkout forced to pure Python: the same traffic digest."""
    default = _digest_of(ROOT, **{PURE_PYTHON_ENV: "0"})
    assert default == _digest_of(ROOT, **{PURE_PYTHON_ENV: "1"})


@pytest.mark.slow
@pytest.mark.timeout(2400)
def test_compiled_build_sends_the_same_traffic(tmp_path: Path,
                                              request: pytest.FixtureRequest) -> None:
    """Build into a copy of the packages, then compare the traffic digest with pure Python.

    The scheduler, the HAL and the virtual board only (:data:`SMOKE_MODULES`): building all of
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
    # the build linked its shared library into this interpreter's site-packages: not left
    # there, pointing into a directory pytest deletes
    request.addfinalizer(lambda: build_compiled._unlink_shared_libraries(
        copy, build_compiled._site_packages()))
    assert done.returncode == 0, f"the compiled core did not build: {done.stderr[-2000:]}"
    built = compiled_files(copy)
    assert len([p for p in built if "__mypyc" not in p.name]) == len(SMOKE_MODULES)
    loaded = subprocess.run(
        [sys.executable, "-c",
         "from tools.build_compiled import loaded_compiled; print(len(loaded_compiled()))"],
        cwd=copy, env=env, capture_output=True, text=True, check=True).stdout.strip()
    assert loaded == str(len(SMOKE_MODULES))
    assert _digest_of(copy) == pure


def test_the_shared_library_is_linked_into_site_packages_and_unlinked_by_clean(
        tmp_path: Path) -> None:
    """mypyc's shared library is a top-level module the editable install does not map: the
    set-up links it into site-packages, replacing an old link into the same root, a link of
    the same name into another, and links whose library is gone."""
    root, site = tmp_path / "root", tmp_path / "site"
    root.mkdir()
    site.mkdir()
    old = site / "0ld__mypyc.cpython-311-x86_64-linux-gnu.so"
    old.symlink_to(root / "0ld__mypyc.cpython-311-x86_64-linux-gnu.so")  # dangling
    foreign = site / "other__mypyc.cpython-311-x86_64-linux-gnu.so"
    foreign.write_bytes(b"not ours")
    lib = root / "abc__mypyc.cpython-311-x86_64-linux-gnu.so"
    lib.write_bytes(b"\x7fELF")
    # a run interrupted before it cleaned up left a link to a build directory since deleted,
    # and another checkout's build of the same group links the same name
    gone = site / "g0ne__mypyc.cpython-311-x86_64-linux-gnu.so"
    gone.symlink_to(tmp_path / "deleted" / gone.name)
    elsewhere = tmp_path / "other-checkout" / lib.name
    elsewhere.parent.mkdir()
    elsewhere.write_bytes(b"\x7fELF")
    (site / lib.name).symlink_to(elsewhere)
    links = build_compiled.link_shared_libraries(root, site)
    assert links == [site / lib.name]
    assert links[0].resolve() == lib.resolve()
    assert not old.is_symlink() and not gone.is_symlink() and foreign.exists()
    build_compiled._unlink_shared_libraries(root, site)
    assert not (site / lib.name).exists() and foreign.exists()


def test_an_installed_command_runs_outside_the_repository(tmp_path: Path) -> None:
    """``armctl --help`` from another directory with no PYTHONPATH: whichever build is in
    use (the compiled core's shared library included), the console script finds it all."""
    script = Path(sys.executable).parent / "armctl"
    if not script.exists():
        pytest.skip("armctl is not installed beside this interpreter")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    done = subprocess.run([str(script), "--help"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "usage: armctl" in done.stdout
