"""A bench scenario: what to build, which faults, what the host does, what must hold.

Read from TOML (schema in docs/HIL_BENCH.md).  Every key is checked when the file is read,
and a mistake raises :class:`ScenarioError` naming the file and the key
(``scenario.toml: actions[2].seconds: ...``), before anything runs.
"""

from __future__ import annotations

import copy
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from hil_emulator.errors import FaultPlanError
from hil_emulator.faults import PlanEntry, parse_plan
from hil_emulator.robot import CONFIGS
from protocol import topology
from protocol.messages.palm import FingerPower
from protocol.topology import FINGERS, SERVO_IDS, STEPPER_IDS
from tools.errors import ScenarioError

#: Each action's keys: required ones, then optional ones with defaults.
ACTIONS: Final[dict[str, tuple[tuple[str, ...], dict[str, Any]]]] = {
    "wait": (("seconds",), {}),
    "power": (("finger", "state"), {}),
    "ping": ((), {"node": "palm"}),
    "poll": (("rate_hz",), {}),
    "stream": (("seconds",), {"rate_hz": 100.0}),
    "move": (("targets",), {"effort": None, "timeout": 2.0, "unhomed": True}),
    "grasp": ((), {"fingers": [0, 1, 2, 3], "closure": 0.6, "effort": 120, "timeout": 2.0}),
    "home": ((), {"finger": None}),
    "flash": ((), {"version": "9.9.9", "fingers": [], "all_or_nothing": False}),
    "arm_open": ((), {}),
    "arm_torque": (("on",), {}),
    "arm_move": (("angles",), {"duration": 1.0, "timeout": 3.0, "interrupt_s": None}),
    "arm_home": ((), {}),
    "arm_play": (("waypoints",), {"time_scale": 1.0}),
    "arm_stream": (("seconds",), {"rate_hz": 100.0}),
    "arm_clear_errors": ((), {}),
    "arm_move_vanish": (("angles",), {"duration": 6.0, "after_s": 1.5, "reader_ms": None,
                                      "read_for_s": 3.0, "reader_adapter": False}),
}
#: Each assertion's keys: required ones, then optional ones with defaults.
ASSERTIONS: Final[dict[str, tuple[tuple[str, ...], dict[str, Any]]]] = {
    "action_ok": (("action",), {}),
    "action_fails": (("action",), {"match": ""}),
    "finger_event": (("finger", "event", "after"), {"within_ms": 50.0}),
    "fingers_present": (("fingers", "after"), {"settle_ms": 100.0}),
    "no_unsent_frames": ((), {"link": "palm", "min_corrupted": 1}),
    "flash_verified": (("action",), {}),
    "arm_flag": (("joint", "flag", "after"), {"within_ms": 10.0}),
    "servo_error": (("joint", "bit", "after"), {"within_ms": 50.0, "cleared_by": None}),
    "fault_applied": (("label",), {"count": 1}),
    "node_state": (("node", "state"), {}),
    "arm_torque_drift": (("joint", "after"), {"min_ratio": 1.5, "window_ms": 500.0,
                                              "tolerance": 0.25}),
    "arm_held": (("action",), {"within_ms": 500.0, "max_fall_deg": 2.0,
                               "max_drive_on_deg": 8.0, "rest_within_ms": None}),
    "arm_holds": (("action",), {"since": "end", "within_deg": 2.0}),
}
#: The actions that go through the palm (need a configuration with the hand) and those
#: that go to the arm's line; the configurations that have each.
HAND_ACTIONS: Final = ("power", "poll", "stream", "move", "grasp", "home", "flash")
ARM_ACTIONS: Final = ("arm_open", "arm_torque", "arm_move", "arm_stream", "arm_clear_errors",
                      "arm_move_vanish", "arm_home", "arm_play")
HAND_CONFIGS: Final = ("full", "hand")
ARM_CONFIGS: Final = ("full", "arm")
#: The boards of a finger, as ``ping`` names them (``finger<k>.<board>``).
FINGER_BOARDS: Final = tuple(b.app for b in topology.FINGER_BOARDS)
TOP_KEYS: Final = ("name", "description", "config", "seed", "physics", "ready", "faults",
                   "actions", "assertions", "campaign")


@dataclass
class Step:
    """One host action or assertion: its kind, its id, its parameters."""

    kind: str
    id: str
    params: dict[str, Any]


@dataclass
class Scenario:
    """A parsed scenario (``raw`` keeps the table it came from, for campaigns)."""

    name: str
    description: str
    config: str
    seed: int
    physics: bool
    ready: bool
    faults: list[PlanEntry]
    actions: list[Step]
    assertions: list[Step]
    campaign: dict[str, Any]
    raw: dict[str, Any] = field(repr=False)
    source: str = ""


def _steps(raw: Any, where: str, table: dict[str, tuple[tuple[str, ...], dict[str, Any]]],
           kind_key: str) -> list[Step]:
    if not isinstance(raw, list):
        raise ScenarioError(f"{where}: a list of tables ([[{where}]]), got {raw!r}")
    steps: list[Step] = []
    ids: set[str] = set()
    for i, item in enumerate(raw):
        at = f"{where}[{i}]"
        if not isinstance(item, dict):
            raise ScenarioError(f"{at}: a table, got {item!r}")
        kind = item.get(kind_key)
        if kind not in table:
            raise ScenarioError(f"{at}.{kind_key}: {kind!r} is not one of "
                                f"{', '.join(table)}")
        required, optional = table[kind]
        allowed = {kind_key, "id", *required, *optional}
        unknown = sorted(set(item) - allowed)
        if unknown:
            raise ScenarioError(f"{at}.{unknown[0]}: {kind!r} takes "
                                f"{', '.join(sorted(allowed - {kind_key}))}")
        for key in required:
            if key not in item:
                raise ScenarioError(f"{at}.{key}: missing ({kind!r} needs it)")
        step_id = str(item.get("id", f"{kind}{i}"))
        if step_id in ids:
            raise ScenarioError(f"{at}.id: {step_id!r} is used twice")
        ids.add(step_id)
        params = {**copy.deepcopy(optional), **{k: v for k, v in item.items()
                                                 if k not in (kind_key, "id")}}
        for key in ("seconds", "within_ms", "settle_ms", "window_ms", "duration", "timeout",
                    "rate_hz", "interrupt_s", "within_deg", "time_scale"):
            value = params.get(key)
            if value is not None and (isinstance(value, bool)
                                      or not isinstance(value, int | float) or value < 0):
                raise ScenarioError(f"{at}.{key}: {value!r} is not a number >= 0")
        steps.append(Step(kind, step_id, params))
    return steps


def _needs(config: str, kind: str, configs: tuple[str, ...], at: str) -> None:
    if config not in configs:
        raise ScenarioError(f"{at}: {kind!r} needs a configuration with the "
                            f"{'arm' if configs == ARM_CONFIGS else 'hand'} "
                            f"({' or '.join(configs)}); config is {config!r}")


def _check_action(step: Step, config: str, at: str) -> None:
    """What the host would refuse or the configuration lacks, found before the run: the
    action's target exists in ``config``, ``ping.node`` and ``power`` values are valid."""
    if step.kind in HAND_ACTIONS:
        _needs(config, step.kind, HAND_CONFIGS, at)
    if step.kind in ARM_ACTIONS:
        _needs(config, step.kind, ARM_CONFIGS, at)
    if step.kind == "ping":
        node = step.params["node"]
        finger = re.fullmatch(r"finger(\d+)\.(\w+)", str(node))
        arm = re.fullmatch(r"arm\.(\d+)", str(node))
        if node == "palm" or (finger and int(finger[1]) < FINGERS
                              and finger[2] in FINGER_BOARDS):
            _needs(config, "ping", HAND_CONFIGS, at)
        elif arm and int(arm[1]) in (*STEPPER_IDS, *SERVO_IDS):
            _needs(config, "ping", ARM_CONFIGS, at)
        else:
            raise ScenarioError(
                f"{at}.node: {node!r} is not palm, finger<0..{FINGERS - 1}>."
                f"<{'|'.join(FINGER_BOARDS)}> or arm.<{STEPPER_IDS[0]}..{SERVO_IDS[-1]}>")
    if step.kind == "power":
        finger, state = step.params["finger"], step.params["state"]
        if finger != "all" and (isinstance(finger, bool) or not isinstance(finger, int)
                                or not 0 <= finger < FINGERS):
            raise ScenarioError(f"{at}.finger: {finger!r} is not 0..{FINGERS - 1} or 'all'")
        states = [p.name.lower() for p in FingerPower]
        if state not in states:
            raise ScenarioError(f"{at}.state: {state!r} is not one of {', '.join(states)}")


def parse_scenario(raw: dict[str, Any], source: str = "<scenario>") -> Scenario:
    """A scenario from its TOML table (errors name ``source`` and the key)."""
    try:
        return _parse(raw, source)
    except (ScenarioError, FaultPlanError) as exc:
        raise ScenarioError(f"{source}: {exc}") from exc


def _parse(raw: dict[str, Any], source: str) -> Scenario:
    unknown = sorted(set(raw) - set(TOP_KEYS))
    if unknown:
        raise ScenarioError(f"{unknown[0]}: unknown key; a scenario has {', '.join(TOP_KEYS)}")
    config = raw.get("config", "hand")
    if config not in CONFIGS:
        raise ScenarioError(f"config: {config!r} is not one of {', '.join(CONFIGS)}")
    seed = raw.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ScenarioError(f"seed: {seed!r} is not an integer >= 0")
    for key in ("physics", "ready"):
        if not isinstance(raw.get(key, True), bool):
            raise ScenarioError(f"{key}: {raw[key]!r} is not true or false")
    if "name" in raw and not isinstance(raw["name"], str):
        raise ScenarioError(f"name: {raw['name']!r} is not text")
    campaign = raw.get("campaign", {})
    if not isinstance(campaign, dict) or set(campaign) - {"seeds", "vary"}:
        raise ScenarioError("campaign: a table with seeds (a list) and vary (path → values)")
    actions = _steps(raw.get("actions", []), "actions", ACTIONS, "do")
    for i, step in enumerate(actions):
        _check_action(step, config, f"actions[{i}]")
    assertions = _steps(raw.get("assertions", []), "assertions", ASSERTIONS, "check")
    action_ids = {a.id for a in actions}
    plan = parse_plan(raw.get("faults", []))
    labels = {e.label for e in plan}
    for i, a in enumerate(assertions):
        for key in ("action", "cleared_by"):
            ref = a.params.get(key)
            if ref is not None and ref not in action_ids:
                raise ScenarioError(f"assertions[{i}].{key}: no action with id {ref!r} "
                                    f"(ids: {', '.join(sorted(action_ids)) or 'none'})")
        for key in ("after", "label"):
            ref = a.params.get(key)
            if ref is not None and ref not in labels:
                raise ScenarioError(f"assertions[{i}].{key}: no fault labelled {ref!r} "
                                    f"(labels: {', '.join(sorted(labels)) or 'none'})")
    return Scenario(name=raw.get("name", Path(source).stem), description=raw.get("description",
                    ""), config=config, seed=seed, physics=raw.get("physics", True),
                    ready=raw.get("ready", True), faults=plan, actions=actions,
                    assertions=assertions, campaign=campaign, raw=raw, source=source)


def find_scenario(name: str | Path) -> Path:
    """The file of scenario ``name``: a path to a TOML file, or the name of a built-in
    scenario (``break_away``, or ``break_away.toml``: :func:`standard_suite`) when no such
    file exists here.  :class:`ScenarioError` if it is neither."""
    path = Path(name)
    if path.exists():
        return path
    builtin = scenario_dir() / f"{path.name.removesuffix('.toml')}.toml"
    if path.parent == Path(".") and builtin.is_file():
        return builtin
    raise ScenarioError(f"{name}: no such file, nor a built-in scenario of that name "
                        f"(hil-bench list-scenarios lists them)")


def load_scenario(path: str | Path) -> Scenario:
    """The scenario in TOML file ``path`` (or the built-in scenario of that name)."""
    path = find_scenario(path)
    try:
        with open(path, "rb") as f:
            raw = tomllib.load(f)
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read: {exc.strerror}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML: {exc}") from exc
    return parse_scenario(raw, str(path))


def with_overrides(raw: dict[str, Any], seed: int | None = None,
                   overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """A copy of scenario table ``raw`` with ``seed`` and dotted-path ``overrides``
    (``faults.0.params.duration_us``) set: one point of a campaign."""
    out = copy.deepcopy(raw)
    out.pop("campaign", None)
    if seed is not None:
        out["seed"] = seed
    for path, value in (overrides or {}).items():
        node: Any = out
        parts = path.split(".")
        for part in parts[:-1]:
            try:
                node = node[int(part)] if isinstance(node, list) else node[part]
            except (KeyError, IndexError, ValueError) as exc:
                raise ScenarioError(f"{path!r} (campaign.vary or --set): no {part!r} "
                                    f"there") from exc
        last = parts[-1]
        if isinstance(node, list):
            node[int(last)] = value
        else:
            node[last] = value
    return out


def scenario_dir() -> Path:
    """The built-in scenarios (the standard suite)."""
    return Path(__file__).parent / "scenarios"


def standard_suite() -> list[Path]:
    """Every built-in scenario file, by name."""
    return sorted(scenario_dir().glob("*.toml"))
