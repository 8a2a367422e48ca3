"""The compiled core: its module list, its clean-up, the set-up's choice (compiled where
built and current, pure Python on request or when made from other sources, by their
digests), and that a compiled build sends the host exactly the bytes the pure-Python modules
send, as a touch, a copy, an edit, a second virtual environment and a wheel see it."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from protocol import compiled_guard
from protocol.compiled_guard import NOTED_ENV, PURE_PYTHON_ENV, RECORD_NAME, extension_suffix
from tools import build_compiled
from tools.build_compiled import COMPILED_MODULES, ROOT, clean, compiled_files, is_current

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
    record = tmp_path / RECORD_NAME
    record.write_text("{}")
    (tmp_path / "build" / "temp").mkdir(parents=True)
    assert set(compiled_files(tmp_path)) == {*built, shared, record}
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


def _clean_env(**extra: str) -> dict[str, str]:
    """This environment without PYTHONPATH, and without what says that a note was printed
    already (this process may have printed it), plus ``extra``."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", NOTED_ENV)}
    return {**env, **extra}


def test_a_current_build_is_imported_and_without_one_the_sources_are() -> None:
    current = is_current(ROOT)
    assert _loaded(**{PURE_PYTHON_ENV: "0"}) == (len(COMPILED_MODULES) if current else 0)


def test_the_environment_variable_forces_pure_python() -> None:
    assert _loaded(**{PURE_PYTHON_ENV: "1"}) == 0


def _fake_build(root: Path, module: str = "firmware_py/scheduler.py") -> tuple[Path, Path]:
    """A build's files under ``root`` as the build leaves them (the extension and the
    runtime library are empty files: nothing here imports them), with its record; returns
    (the module's source, the runtime library)."""
    source = root / module
    constants = root / "protocol" / "robot.py"
    for path, text in ((source, "x = 1\n"), (constants, "N: int = 7\n")):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    source.with_name(source.stem + extension_suffix()).write_bytes(b"")
    runtime = root / f"0123abcd__mypyc{extension_suffix()}"
    runtime.write_bytes(b"")
    compiled_guard.write_record(root, compiled_guard.record(root, [module], runtime.name))
    return source, runtime


def test_a_touch_leaves_a_build_current_and_an_edit_makes_it_stale(tmp_path: Path) -> None:
    """By what the build was made from, not file times: a touch (a copy, a checkout of the
    same content) changes nothing, an edit does, and undoing the edit undoes it."""
    source, _ = _fake_build(tmp_path)
    later = source.stat().st_mtime + 3600
    for path in (source, tmp_path / "protocol" / "robot.py"):
        os.utime(path, (later, later))
    assert compiled_guard.stale(tmp_path) == []
    assert compiled_guard.problem(tmp_path) is None
    source.write_text("x = 2\n")
    assert compiled_guard.stale(tmp_path) == ["firmware_py/scheduler.py"]
    assert compiled_guard.problem(tmp_path) == ("it was built from other versions of "
                                                "firmware_py/scheduler.py")
    source.write_text("x = 1\n")  # back as it was built (git checkout)
    assert compiled_guard.problem(tmp_path) is None


def test_an_edited_or_new_source_whose_constants_are_copied_makes_it_stale(
        tmp_path: Path) -> None:
    """mypyc copies ``Final`` constants (protocol/robot.py's numbers) into the compiled
    modules: an edited constant counts although robot.py itself is not compiled, and so
    does a new module of that package."""
    _fake_build(tmp_path, "firmware_py/arm_stepper.py")
    (tmp_path / "protocol" / "robot.py").write_text("N: int = 8\n")
    assert compiled_guard.stale(tmp_path) == ["protocol/robot.py"]
    (tmp_path / "protocol" / "new.py").write_text("")
    assert compiled_guard.stale(tmp_path) == ["protocol/new.py", "protocol/robot.py"]
    assert "protocol/robot.py" in build_compiled.build_sources(tmp_path)


def test_a_build_that_cannot_be_used_whole_says_why_and_what_to_do(tmp_path: Path) -> None:
    """One line each: a runtime library that does not load, or is missing, an extension of
    another build, no record; the advice fits the install (a checkout has the Makefile)."""
    source, runtime = _fake_build(tmp_path)
    line = compiled_guard.decide(tmp_path)
    assert line is not None and "\n" not in line
    assert line.startswith("note: the compiled core is not used (its runtime library does "
                           "not load: ")
    assert line.endswith(f"running pure Python (`python -m tools.build_compiled --root "
                         f"{tmp_path}` rebuilds it, `--clean` removes it)")
    runtime.unlink()
    assert compiled_guard.problem(tmp_path) == f"its runtime library {runtime.name} is missing"
    (tmp_path / "Makefile").write_text("")
    (tmp_path / "tools").mkdir()
    (tmp_path / "tools" / "build_compiled.py").write_text("")
    assert str(compiled_guard.decide(tmp_path)).endswith("(`make compiled` rebuilds it)")
    other = tmp_path / "protocol" / f"crc{extension_suffix()}"
    (tmp_path / "protocol" / "crc.py").write_text("")
    other.write_bytes(b"")
    assert compiled_guard.problem(tmp_path) == ("extensions not of its build are there "
                                                "(protocol/crc.py)")
    (tmp_path / RECORD_NAME).unlink()
    assert compiled_guard.problem(tmp_path) == ("it has no record of what it was built "
                                                f"from, {RECORD_NAME}")


def test_no_build_or_one_for_another_python_is_pure_python_quietly(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    source = tmp_path / "firmware_py" / "scheduler.py"
    source.parent.mkdir()
    source.write_text("")
    assert compiled_guard.decide(tmp_path) == ""
    source.with_name("scheduler.cpython-39-x86_64-linux-gnu.so").write_bytes(b"")
    assert compiled_guard.extensions(tmp_path) == []  # this Python would not import it
    assert compiled_guard.decide(tmp_path) == ""
    _fake_build(tmp_path)
    monkeypatch.setenv(PURE_PYTHON_ENV, "1")
    assert compiled_guard.decide(tmp_path) == ""


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


def _traffic(root: Path | None, python: str = sys.executable,
             cwd: Path | None = None) -> tuple[int, str, str]:
    """(how many compiled modules, the traffic digest, standard error) of one process of
    ``python`` importing the sources under ``root`` (on PYTHONPATH; None: what ``python``
    has installed), run in ``cwd`` (default ``root``)."""
    code = ("from tools.build_compiled import loaded_compiled\n"
            "from tools.traffic_record import main\n"
            "print(len(loaded_compiled())); main(['--seed', '7'])")
    env = _clean_env(**({"PYTHONPATH": str(root)} if root is not None else {}))
    done = subprocess.run([python, "-c", code], cwd=cwd or root, env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    count, record = done.stdout.split("\n", 1)
    return int(count), str(json.loads(record)["digest"]), done.stderr


def test_the_default_build_and_pure_python_send_the_same_traffic() -> None:
    """The checkout as the set-up left it (the compiled core where it could be built) and
    the same checkout forced to pure Python: the same traffic digest."""
    default = _digest_of(ROOT, **{PURE_PYTHON_ENV: "0"})
    assert default == _digest_of(ROOT, **{PURE_PYTHON_ENV: "1"})


@pytest.mark.slow
@pytest.mark.timeout(2400)
def test_compiled_build_sends_the_same_traffic(tmp_path: Path) -> None:
    """Build into a copy of the packages, then compare the traffic digest with pure Python:
    as built, touched, copied elsewhere (compiled: current), edited (pure Python, said once).

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
    env = {**_clean_env(), "PYTHONPATH": str(copy)}
    done = subprocess.run([sys.executable, "-m", "tools.build_compiled",
                           "--build-dir", str(tmp_path / "build"), "--only", *SMOKE_MODULES],
                          cwd=copy, env=env, capture_output=True, text=True)
    assert done.returncode == 0, f"the compiled core did not build: {done.stderr[-2000:]}"
    built = compiled_files(copy)
    assert len([p for p in built if p.suffix == ".so" and "__mypyc" not in p.name]) == len(
        SMOKE_MODULES)
    assert _traffic(copy) == (len(SMOKE_MODULES), pure, "")
    # touched, and copied elsewhere with new times: still the same build, still current
    for module in (*SMOKE_MODULES, "protocol/robot.py"):
        os.utime(copy / module)
    moved = tmp_path / "moved"
    shutil.copytree(copy, moved, copy_function=shutil.copy)
    assert _traffic(copy) == (len(SMOKE_MODULES), pure, "")
    assert _traffic(moved) == (len(SMOKE_MODULES), pure, "")
    # edited (a comment only, so the traffic stays): stale, pure Python, one line saying so
    edited = moved / SMOKE_MODULES[0]
    edited.write_text(edited.read_text() + "\n# edited\n")
    assert _traffic(moved) == (0, pure, (
        f"note: the compiled core is not used (it was built from other versions of "
        f"{SMOKE_MODULES[0]}): running pure Python (`python -m tools.build_compiled --root "
        f"{moved}` rebuilds it, `--clean` removes it)\n"))


def test_the_links_an_earlier_set_up_made_in_site_packages_are_removed(
        tmp_path: Path) -> None:
    """Earlier versions linked the runtime library into site-packages (the guard now loads
    it from the build): the set-up removes those links into its root and dangling ones,
    never another file."""
    root, site = tmp_path / "root", tmp_path / "site"
    root.mkdir()
    site.mkdir()
    lib = root / "abc__mypyc.cpython-311-x86_64-linux-gnu.so"
    lib.write_bytes(b"\x7fELF")
    ours = site / lib.name
    ours.symlink_to(lib)
    gone = site / "g0ne__mypyc.cpython-311-x86_64-linux-gnu.so"
    gone.symlink_to(tmp_path / "deleted" / gone.name)
    foreign = site / "other__mypyc.cpython-311-x86_64-linux-gnu.so"
    foreign.write_bytes(b"not ours")
    assert build_compiled._unlink_shared_libraries(root, site) == sorted([gone, ours])
    assert foreign.exists() and lib.exists()


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


def _runs(command: list[str], cwd: Path) -> str:
    """Run an installed command as a user would (no PYTHONPATH); its standard error, which
    holds no traceback, after exit status 0."""
    done = subprocess.run(command, cwd=cwd, env=_clean_env(), capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "Traceback" not in done.stderr
    return done.stderr


def _venv_with_our_dependencies(venv: Path) -> str:
    """A new virtual environment at ``venv`` (its Python returned) that finds the project's
    dependencies among this one's installed packages (one ``.pth`` line naming this
    environment's site-packages), but not this environment's install of the project (the
    ``.pth`` files there, its editable finder among them, are not read through that line).

    So installing the project there resolves every dependency as satisfied instead of
    downloading and unpacking MuJoCo, NumPy, rerun and the rest again (most of the minutes a
    fresh environment takes; ``make install`` proves they install), and what the install
    itself does (the build back-end in its own isolated environment, the editable finder,
    the wheel, the console scripts) is as in any other environment.  No pip of its own: this
    environment's pip installs into it (``pip --python``)."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True,
                   timeout=300)
    python = str(venv / "bin" / "python")
    site = subprocess.run([python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                          env=_clean_env(), capture_output=True, text=True,
                          check=True).stdout.strip()
    ours = sysconfig.get_path("purelib")
    assert Path(site) != Path(ours)
    (Path(site) / "dependencies-from-the-first-venv.pth").write_text(ours + "\n")
    done = subprocess.run([python, "-c", "import protocol"], cwd=venv, env=_clean_env(),
                          capture_output=True, text=True)
    assert done.returncode != 0, "the new environment sees the project before installing it"
    return python


@pytest.mark.slow
@pytest.mark.timeout(2400)
def test_a_second_venv_with_an_editable_install_then_a_wheel_install(tmp_path: Path) -> None:
    """What an IDE, tox or a user's own venv does with this checkout: ``pip install -e``
    uses the checkout's build whole (its runtime library found from the build) where it is
    current, or runs pure Python saying so in one line; ``pip install .`` installs a pure
    Python wheel, with nothing to say.  Both send the traffic of pure Python, and their
    commands run."""
    venv = tmp_path / "venv"
    python = _venv_with_our_dependencies(venv)
    bin_dir = venv / "bin"
    work = tmp_path / "elsewhere"  # not the checkout: the sources come through the install
    work.mkdir()

    def pip_install(*args: str) -> None:
        done = subprocess.run([sys.executable, "-m", "pip", "--python", python, "install",
                               "-q", *args], env=_clean_env(), capture_output=True, text=True,
                              timeout=1800)
        assert done.returncode == 0, done.stderr[-3000:]

    pure = _digest_of(ROOT, **{PURE_PYTHON_ENV: "1"})
    pip_install("-e", str(ROOT))
    current = is_current(ROOT)
    count, digest, err = _traffic(None, python, work)
    assert (count, digest) == (len(COMPILED_MODULES) if current else 0, pure)
    notes = [line for line in err.splitlines() if line.startswith("note: the compiled core")]
    assert len(notes) == (0 if current else 1), err
    for command in ([str(bin_dir / "armctl"), "--help"],
                    [str(bin_dir / "hil-emulator"), "--config", "arm", "--duration", "2"]):
        said = _runs(command, work)
        assert said.count("note: the compiled core") == (0 if current else 1), said

    pip_install("--no-deps", "--force-reinstall", str(ROOT))  # the wheel, over the editable
    site = Path(subprocess.run([python, "-c", "import protocol; print(protocol.__file__)"],
                               cwd=work, env=_clean_env(), capture_output=True, text=True,
                               check=True).stdout.strip()).parent.parent
    assert site.is_relative_to(venv)
    packed = [*site.glob("*__mypyc*"), *(site / RECORD_NAME).parent.glob(Path(RECORD_NAME).name)]
    for package in compiled_guard.PACKAGES:
        packed += (site / package).rglob("*.so")
    assert packed == []  # the wheel carries no compiled core
    assert _traffic(None, python, work) == (0, pure, "")
    for command in ([str(bin_dir / "armctl"), "--help"],
                    [str(bin_dir / "hil-emulator"), "--config", "arm", "--duration", "2"]):
        # (an emulator that falls behind the wall clock on a busy machine says so, and
        # that `make compiled` helps: advice about speed, not a note about this build)
        said = "".join(line for line in _runs(command, work).splitlines(keepends=True)
                       if "cannot keep up with the wall clock" not in line)
        assert "compiled core" not in said and "make compiled" not in said, said
