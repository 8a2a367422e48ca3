"""The calibration file: one versioned JSON file per robot, one section per part.

A robot's calibration (its accelerometers' mounting, bias and scale, an arm's link
parameters …) is a property of the robot as built, so it lives in a file named by the
robot's serial number and every estimator that can use it loads it.  The file::

    {
      "format": "lowcost-calibration",
      "version": 1,
      "robot_serial": "00001000",
      "created_utc": "2026-12-03T16:00:00Z",
      "sections": {
        "hand": {"method": "...", "created_utc": "...", ...},
        "arm":  {"method": "...", "created_utc": "...", ...}
      }
    }

Each section carries its own ``method`` (how it was made) and ``created_utc`` (when) and
whatever its part needs; a section may also carry ``firmware`` (the version string of the
robot's firmware when it was made, ``"major.minor.patch"``), which :func:`find` compares
with the robot's.  A hand's serial is its palm's ``uid`` (the ``identify`` reply) as eight
hex digits (:func:`serial_of_uid`); an arm's, its stepper nodes' ``arm_serial`` register as
``arm-`` and four hex digits (:func:`serial_of_arm`), so an arm and a hand have files of their
own and either may be moved to another robot with its calibration.

:func:`save_section` replaces one section and keeps the others, writing atomically (a
temporary file in the same directory, fsync, rename), so a crash leaves the old file or
the new one, never half of one.  :func:`load` refuses a file that is not one, or one of a
newer version than this library reads, with a one-line
:class:`~host.errors.CalibrationFileError`.  :func:`find` is what a program calls: the file to
use for a robot and the warnings its user must see (missing, another robot's, an older
format, made on older firmware).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from host.errors import CalibrationFileError, UsageError

#: The ``format`` key's value: what says the JSON is a calibration file.
FORMAT = "lowcost-calibration"
#: The version this library writes.  A file of a newer version is refused; one of an older
#: version still read here is used with a warning (re-run the calibration).
VERSION = 1
#: The oldest version this library still reads.
OLDEST_READABLE = 1
#: The environment variable that overrides the directory of :func:`default_path`.
DIR_ENV = "LOWCOST_CALIBRATION_DIR"
#: What a serial number may contain (it names a file).
_SERIAL = re.compile(r"^[0-9A-Za-z_-]{1,64}$")
_REQUIRED_SECTION_KEYS = ("method", "created_utc")


@dataclass
class CalibrationFile:
    """A calibration file as read: ``robot_serial``, format ``version``, ``created_utc``
    (ISO 8601, UTC, when the file was first written) and ``sections`` (name → a dict of
    JSON values, each with ``method`` and ``created_utc``)."""

    robot_serial: str
    version: int = VERSION
    created_utc: str = ""
    sections: dict[str, dict[str, Any]] = field(default_factory=dict)

    def section(self, name: str) -> dict[str, Any] | None:
        """The section ``name`` (``"hand"``, ``"arm"``), or None if the file has none."""
        return self.sections.get(name)

    def to_json(self) -> dict[str, Any]:
        """The file's JSON object."""
        return {"format": FORMAT, "version": self.version, "robot_serial": self.robot_serial,
                "created_utc": self.created_utc, "sections": self.sections}


def utc_now() -> str:
    """Now, as the file writes times: ISO 8601, UTC, whole seconds (``...Z``)."""
    return datetime.now(UTC).replace(microsecond=0).isoformat().replace("+00:00", "Z")


def serial_of_uid(uid: int) -> str:
    """A robot serial number from a palm's 32-bit ``uid``: eight lower-case hex digits."""
    return f"{uid & 0xFFFFFFFF:08x}"


def serial_of_arm(value: int) -> str:
    """An arm's serial number from its stepper nodes' 16-bit ``arm_serial``: ``arm-`` and
    four lower-case hex digits."""
    return f"arm-{value & 0xFFFF:04x}"


def _check_serial(robot_serial: str) -> str:
    if not isinstance(robot_serial, str) or not _SERIAL.match(robot_serial):
        raise UsageError(f"robot serial {robot_serial!r} is not 1-64 letters, digits, '-' "
                         "or '_'")
    return robot_serial


def default_path(robot_serial: str) -> Path:
    """Where a robot's calibration file lives unless told: ``$LOWCOST_CALIBRATION_DIR`` if
    set, else ``$XDG_CONFIG_HOME/lowcost-hand/calibration`` (``~/.config/…``), then
    ``<serial>.json``."""
    _check_serial(robot_serial)
    chosen = os.environ.get(DIR_ENV)
    if chosen:
        directory = Path(chosen).expanduser()
    else:
        config = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
        directory = Path(config) / "lowcost-hand" / "calibration"
    return directory / f"{robot_serial}.json"


def _bad(path: Path, why: str) -> CalibrationFileError:
    return CalibrationFileError(f"{path}: not a usable calibration file: {why}", path=path)


def _parse(path: Path, text: str) -> CalibrationFile:
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as exc:
        raise _bad(path, f"not JSON ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(obj, dict) or obj.get("format") != FORMAT:
        raise _bad(path, f"its \"format\" is not {FORMAT!r}")
    version = obj.get("version")
    if not isinstance(version, int) or isinstance(version, bool):
        raise _bad(path, "\"version\" is not an integer")
    if version > VERSION:
        raise CalibrationFileError(
            f"{path}: calibration file version {version} is newer than this library reads "
            f"({VERSION}): update the software or calibrate again", path=path)
    if version < OLDEST_READABLE:
        raise _bad(path, f"version {version} is older than the oldest readable "
                         f"({OLDEST_READABLE})")
    serial = obj.get("robot_serial")
    if not isinstance(serial, str) or not _SERIAL.match(serial):
        raise _bad(path, "\"robot_serial\" is missing or not a serial number")
    created = obj.get("created_utc")
    if not isinstance(created, str):
        raise _bad(path, "\"created_utc\" is missing")
    sections = obj.get("sections")
    if not isinstance(sections, dict):
        raise _bad(path, "\"sections\" is not an object")
    for name, data in sections.items():
        if not isinstance(data, dict):
            raise _bad(path, f"section {name!r} is not an object")
        missing = [k for k in _REQUIRED_SECTION_KEYS if not isinstance(data.get(k), str)]
        if missing:
            raise _bad(path, f"section {name!r} lacks {', '.join(missing)}")
    return CalibrationFile(serial, version, created, sections)


def load(path: str | os.PathLike[str]) -> CalibrationFile:
    """Read a calibration file.  Raises :class:`~host.errors.CalibrationFileError` (one
    line: the path and what is wrong) for a file that cannot be read, is not JSON, is not
    a calibration file, lacks a key, or is of a newer version than this library reads."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise CalibrationFileError(f"{p}: cannot read the calibration file: {why}",
                                   path=p) from None
    return _parse(p, text)


def _jsonable(value: Any) -> Any:
    """``value`` with numpy arrays and scalars (anything with ``tolist``) as lists and
    numbers; raises UsageError for a value JSON cannot hold (NaN, an object)."""
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if hasattr(value, "tolist") and not isinstance(value, str | bytes):
        return _jsonable(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        raise UsageError(f"a calibration value is not finite ({value})")
    if value is None or isinstance(value, str | int | float | bool):
        return value
    raise UsageError(f"a calibration value of type {type(value).__name__} cannot be stored")


def _write_atomically(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as out:
            out.write(text)
            out.flush()
            os.fsync(out.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    with contextlib.suppress(OSError):
        dir_fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)


def save_section(path: str | os.PathLike[str], robot_serial: str, section: str,
                 data: Mapping[str, Any], *, replace_other_robot: bool = False
                 ) -> CalibrationFile:
    """Create or update the section ``section`` of the calibration file at ``path`` for
    the robot ``robot_serial``, keeping its other sections; return the file as written.

    ``data`` must hold ``method`` (a string); ``created_utc`` is set to now unless given.
    Numpy arrays and scalars are stored as lists and numbers.  A file at ``path`` of
    another robot is refused (:class:`~host.errors.CalibrationFileError`) unless
    ``replace_other_robot``, which starts a new file; an unreadable or newer-version file
    there is refused the same way (it is never overwritten silently)."""
    p = Path(path)
    _check_serial(robot_serial)
    if not section or not isinstance(section, str):
        raise UsageError("a calibration section needs a name (\"hand\", \"arm\")")
    body = _jsonable(data)
    if not isinstance(body.get("method"), str):
        raise UsageError(f"calibration section {section!r} needs a \"method\" (a string)")
    body.setdefault("created_utc", utc_now())
    if p.exists():
        existing = load(p)
        if existing.robot_serial != robot_serial:
            if not replace_other_robot:
                raise CalibrationFileError(
                    f"{p} is the calibration of robot {existing.robot_serial}, not "
                    f"{robot_serial}: not overwritten (choose another file)", path=p)
            existing = CalibrationFile(robot_serial, VERSION, utc_now(), {})
    else:
        existing = CalibrationFile(robot_serial, VERSION, utc_now(), {})
    sections = dict(existing.sections)
    sections[section] = body
    out = CalibrationFile(robot_serial, VERSION, existing.created_utc, sections)
    _write_atomically(p, json.dumps(out.to_json(), indent=2, allow_nan=False) + "\n")
    return out


def _version_tuple(text: str) -> tuple[int, ...] | None:
    try:
        return tuple(int(part) for part in text.split("."))
    except (AttributeError, ValueError):
        return None


def find(robot_serial: str, path: str | os.PathLike[str] | None = None, *,
         section: str | None = None, firmware: str | None = None,
         fallback: tuple[str, str] | None = None
         ) -> tuple[CalibrationFile | None, list[str]]:
    """The calibration file to use for the robot ``robot_serial`` and the warnings (one
    line each) its user must see.

    ``path`` defaults to :func:`default_path`.  No file there: (None, ["no calibration
    …"]).  Another robot's file: (None, [that]) (never used: it would be a silent wrong
    estimate).  A file of an older format version, one without ``section`` (if given), or
    one whose ``section`` records firmware older than ``firmware`` (the robot's version,
    ``"major.minor.patch"``): the file with the warning.  A file that is not one, or newer
    than this library reads, raises :class:`~host.errors.CalibrationFileError`.  ``fallback``
    says in the warnings what is used instead and how to make the file (default: the
    nominal sensor mounting, ``handctl calibrate``)."""
    used, remedy = fallback or ("the nominal sensor mounting", "run 'handctl calibrate'")
    p = Path(path) if path is not None else default_path(robot_serial)
    if not p.exists():
        return None, [f"no calibration file for robot {robot_serial} ({p}): estimates use "
                      f"{used} ({remedy})"]
    cal = load(p)
    if cal.robot_serial != robot_serial:
        return None, [f"{p} is the calibration of robot {cal.robot_serial}, not of this "
                      f"robot {robot_serial}: not used, estimates use "
                      f"{'the nominal mounting' if fallback is None else used}"]
    warnings: list[str] = []
    if cal.version < VERSION:
        warnings.append(f"{p} is calibration format version {cal.version} (this library "
                        f"writes {VERSION}): calibrate again to refresh it")
    data = cal.section(section) if section is not None else None
    if section is not None and data is None:
        warnings.append(f"{p} has no {section!r} section: the {section} uses "
                        f"{'the nominal mounting' if fallback is None else used}")
    if data is not None and firmware is not None and isinstance(data.get("firmware"), str):
        made, now = _version_tuple(data["firmware"]), _version_tuple(firmware)
        if made is not None and now is not None and made < now:
            warnings.append(f"{p}: the {section} was calibrated on firmware {data['firmware']}"
                            f", the robot now runs {firmware}: calibrate again")
    return cal, warnings
