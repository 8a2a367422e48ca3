"""hil-bench: scenario files checked key by key, a subset of the standard suite with its
reports, exit codes, the fault catalogue, and campaigns equal on local processes and on a
local Dask cluster."""

from __future__ import annotations

import json
import time
import tomllib
from pathlib import Path
from typing import Any

import pytest

from tools.hil_bench import cli as hil_bench
from tools.hil_bench.campaign import comparable, expand, run_jobs
from tools.hil_bench.scenario import ScenarioError, parse_scenario, scenario_dir, standard_suite

pytestmark = pytest.mark.process_wide("dask keeps its connection pools and event loop for the process")

SUITE = scenario_dir()
#: The subset of the standard suite run by default (about 15 s).
SUBSET = ("break_away", "link_corruption", "tendon_glitch_long", "port_vanish",
          "servo_overheat", "arm_push", "supply_sag")


def _raw(name: str) -> dict[str, Any]:
    with open(SUITE / f"{name}.toml", "rb") as f:
        return tomllib.load(f)


@pytest.mark.parametrize(("change", "message"), [
    ({"config": "octopus"}, r"config: 'octopus' is not one of"),
    ({"seed": -1}, r"seed: -1 is not an integer"),
    ({"colour": 1}, r"colour: unknown key"),
    ({"actions": [{"do": "dance"}]}, r"actions\[0\]\.do: 'dance' is not one of"),
    ({"actions": [{"do": "wait"}]}, r"actions\[0\]\.seconds: missing"),
    ({"actions": [{"do": "wait", "seconds": "soon"}]}, r"actions\[0\]\.seconds: 'soon'"),
    ({"actions": [{"do": "wait", "seconds": 1, "speed": 2}]}, r"actions\[0\]\.speed: 'wait'"),
    ({"assertions": [{"check": "action_ok", "action": "nope"}]},
     r"assertions\[0\]\.action: no action with id 'nope'"),
    ({"assertions": [{"check": "finger_event", "finger": 2, "event": "lost",
                      "after": "boom"}]}, r"assertions\[0\]\.after: no fault labelled 'boom'"),
    ({"faults": [{"fault": "break_away", "params": {"finger": "x"}}]},
     r"faults\[0\]\.params\.finger"),
    ({"faults": [{"fault": "break_away", "at_s": -1}]}, r"faults\[0\]\.at_s"),
    ({"actions": [{"do": "ping", "node": "finger9.fmcb"}]},
     r"actions\[0\]\.node: 'finger9\.fmcb' is not palm, finger<0\.\.3>"),
    ({"actions": [{"do": "ping", "node": "bogus"}]}, r"actions\[0\]\.node: 'bogus'"),
    ({"actions": [{"do": "ping", "node": "arm.5"}]},
     r"actions\[0\]: 'ping' needs a configuration with the arm \(full or arm\)"),
    ({"actions": [{"do": "power", "finger": 2, "state": "on"}]},
     r"actions\[0\]\.state: 'on' is not one of off, low, full"),
    ({"actions": [{"do": "power", "finger": 7, "state": "off"}]},
     r"actions\[0\]\.finger: 7 is not 0\.\.3 or 'all'"),
    ({"config": "arm"}, r"actions\[0\]: 'poll' needs a configuration with the hand"),
])
def test_scenario_errors_name_the_file_and_the_key(change: dict[str, Any], message: str
                                                   ) -> None:
    raw = {**_raw("break_away"), **change}
    with pytest.raises(ScenarioError, match=r"^x\.toml: " + message):
        parse_scenario(raw, "x.toml")


def test_every_implemented_fault_has_a_standard_scenario() -> None:
    from hil_emulator.faults import FAULTS

    used = {f["fault"] for p in standard_suite()
            for f in tomllib.loads(p.read_text()).get("faults", [])}
    assert set(FAULTS) <= used, sorted(set(FAULTS) - used)
    for path in standard_suite():
        parse_scenario(tomllib.loads(path.read_text()), str(path))


@pytest.mark.slow
def test_a_subset_of_the_standard_suite_passes_with_reports(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]
                                                            ) -> None:
    out = tmp_path / "results.json"
    files = [str(SUITE / f"{n}.toml") for n in SUBSET]
    code = hil_bench.main(["run", *files, "--json", str(out), "--report",
                           str(tmp_path / "report")])
    text = capsys.readouterr().out
    assert code == 0, text
    results = json.loads(out.read_text())
    assert [r["scenario"] for r in results] == list(SUBSET)
    by_name = {r["scenario"]: r for r in results}
    lost = by_name["break_away"]["assertions"][0]
    assert lost["check"] == "finger_event" and 0 < lost["measured"]["latency_ms"] <= 50
    slip = by_name["arm_push"]["assertions"][0]["measured"]
    assert slip["latency_ms"] <= 10  # within one 100 Hz control cycle
    assert by_name["link_corruption"]["assertions"][0]["measured"]["foreign_frames"] == 0
    report = tmp_path / "report"
    assert "7 of 7 runs passed" in (report / "summary.md").read_text()
    assert (report / "break_away-seed1.json").exists()
    assert (report / "break_away-seed1-fault0.png").read_bytes()[:4] == b"\x89PNG"


def test_a_failed_assertion_exits_1_and_a_bad_file_2(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]
                                                     ) -> None:
    scenario = tmp_path / "strict.toml"
    scenario.write_text((SUITE / "tendon_glitch_long.toml").read_text().replace(
        'state = "bootloader"', 'state = "running"'))
    assert hil_bench.main(["run", str(scenario)]) == 1
    assert "FAIL (node_state0)" in capsys.readouterr().out
    bad = tmp_path / "bad.toml"
    bad.write_text('config = "arm"\n[[actions]]\ndo = "wait"\n')
    assert hil_bench.main(["run", str(bad)]) == 2
    assert "actions[0].seconds: missing" in capsys.readouterr().err


def test_list_faults_prints_every_fault_with_parameters_and_the_missing_ones(
        capsys: pytest.CaptureFixture[str]) -> None:
    from hil_emulator.faults import FAULTS, NOT_YET_IMPLEMENTED

    assert hil_bench.main(["list-faults"]) == 0
    text = capsys.readouterr().out
    for name in FAULTS:
        assert f"\n{name}  (" in f"\n{text}"
    for name in NOT_YET_IMPLEMENTED:
        assert f"{name}  (-)  [not yet implemented]" in text
    assert "- duration_us: int = 1000" in text
    assert hil_bench.main(["list-faults", "--json"]) == 0
    assert len(json.loads(capsys.readouterr().out)) == len(FAULTS) + len(NOT_YET_IMPLEMENTED)


def test_experiments_dispatches_or_says_the_module_is_missing(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    import sys
    import types

    fake = types.ModuleType("tools.experiments.dissertation")
    seen: list[list[str]] = []

    def fake_main(argv: list[str]) -> int:
        seen.append(argv)
        return 0

    fake.main = fake_main  # type: ignore[attr-defined]  # a module built at run time
    monkeypatch.setitem(sys.modules, "tools.experiments.dissertation", fake)
    assert hil_bench.main(["experiments", "sweep", "--x", "1"]) == 0
    # its own options first, as a user types them (argparse's REMAINDER refused these)
    assert hil_bench.main(["experiments", "--json", "--report", "out"]) == 0
    assert seen == [["sweep", "--x", "1"], ["--json", "--report", "out"]]
    monkeypatch.setitem(sys.modules, "tools.experiments.dissertation", None)  # import fails
    monkeypatch.setattr(hil_bench.importlib, "import_module", _missing)
    assert hil_bench.main(["experiments"]) == 2
    assert "dissertation.py is not installed" in capsys.readouterr().err


def _missing(name: str) -> Any:
    raise ModuleNotFoundError(f"No module named {name!r}", name=name)


def _campaign(n_seeds: int) -> list[dict[str, Any]]:
    return expand([SUITE / "servo_overheat.toml", SUITE / "supply_sag.toml"],
                  seeds=list(range(n_seeds)))


@pytest.mark.slow
def test_a_campaign_on_a_local_dask_cluster_equals_the_in_process_run() -> None:
    from dask.distributed import Client, LocalCluster

    jobs = _campaign(2)
    here = [comparable(r) for r in run_jobs(jobs)]
    with LocalCluster(processes=True, n_workers=2, threads_per_worker=1,
                      dashboard_address=None, host="127.0.0.1") as cluster, \
            Client(cluster) as client:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        there = [comparable(r) for r in run_jobs(jobs, scheduler=client)]
        by_address = [comparable(r) for r in run_jobs(jobs[:1],
                                                      scheduler=cluster.scheduler_address)]
    assert there == here and by_address == here[:1]
    assert [r["seed"] for r in here] == [0, 1, 0, 1] and all(r["passed"] for r in here)


@pytest.mark.slow
def test_campaign_vary_runs_every_combination_and_local_workers_agree(tmp_path: Path
                                                                      ) -> None:
    path = tmp_path / "vary.toml"
    text = (SUITE / "tendon_glitch_short.toml").read_text()
    head, sep, rest = text.partition("[[faults]]")
    path.write_text(head + '[campaign]\nseeds = [1, 2]\n'
                    'vary = { "faults.0.params.duration_us" = [500, 1900] }\n' + sep + rest)
    jobs = expand([path])
    assert [(j["raw"]["seed"], j["overrides"]["faults.0.params.duration_us"]) for j in jobs] \
        == [(1, 500), (1, 1900), (2, 500), (2, 1900)]
    here = [comparable(r) for r in run_jobs(jobs)]
    assert [comparable(r) for r in run_jobs(jobs, workers=2)] == here
    assert all(r["passed"] for r in here)


@pytest.mark.slow
def test_the_whole_standard_suite_passes_on_two_local_processes(tmp_path: Path) -> None:
    assert hil_bench.main(["run", "--suite", "standard", "--workers", "2",
                           "--json", str(tmp_path / "r.json")]) == 0


@pytest.mark.slow
def test_a_200_run_campaign_on_a_local_dask_cluster() -> None:
    from dask.distributed import Client, LocalCluster

    jobs = _campaign(100)
    assert len(jobs) == 200
    with LocalCluster(processes=True, n_workers=2, threads_per_worker=1,
                      dashboard_address=None, host="127.0.0.1") as cluster, \
            Client(cluster) as client:
        results = run_jobs(jobs, scheduler=client)
    assert len(results) == 200 and all(r["passed"] for r in results)
    assert comparable(results[7]) == comparable(run_jobs([jobs[7]])[0])


def _strict_glitch(tmp_path: Path) -> Path:
    """tendon_glitch_long expecting f3 still running: fails once the glitch outlasts the
    phalanges' 2 ms hold-up (2500 µs), passes below it (1500 µs)."""
    path = tmp_path / "strict.toml"
    text = (SUITE / "tendon_glitch_long.toml").read_text().replace(
        'state = "bootloader"', 'state = "running"')
    head, sep, rest = text.partition("[[faults]]")
    path.write_text(head + '[campaign]\nseeds = [1]\n'
                    'vary = { "faults.0.params.duration_us" = [1500, 2500] }\n' + sep + rest)
    return path


@pytest.mark.slow
def test_a_failed_run_prints_the_command_that_runs_it_alone(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import shlex

    path = _strict_glitch(tmp_path)
    assert hil_bench.main(["run", str(path), "--report", str(tmp_path / "rep")]) == 1
    out = capsys.readouterr().out
    assert "tendon_glitch_long seed 1 duration_us=1500: pass" in out
    assert "tendon_glitch_long seed 1 duration_us=2500: FAIL (node_state0)" in out
    command = [line.split("reproduce: ", 1)[1] for line in out.splitlines()
               if "reproduce: " in line]
    assert command == [f"hil-bench run {shlex.quote(str(path))} --seed 1 "
                       f"--set faults.0.params.duration_us=2500"]
    assert f"`{command[0]}`" in (tmp_path / "rep" / "summary.md").read_text()
    assert hil_bench.main(shlex.split(command[0])[1:]) == 1
    again = capsys.readouterr().out
    assert "seed 1 duration_us=2500: FAIL (node_state0)" in again
    assert "0 of 1 runs passed" in again


def test_ctrl_c_keeps_the_finished_runs_and_exits_130(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    from tools.hil_bench import campaign

    run_job = campaign.run_job
    calls = [0]

    def interrupted(job: dict[str, Any]) -> dict[str, Any]:
        calls[0] += 1
        if calls[0] == 2:
            raise KeyboardInterrupt
        return run_job(job)

    monkeypatch.setattr(campaign, "run_job", interrupted)
    out_json, report = tmp_path / "r.json", tmp_path / "rep"
    code = hil_bench.main(["run", "tendon_glitch_short", "--seeds", "3",
                           "--json", str(out_json), "--report", str(report)])
    captured = capsys.readouterr()
    assert code == hil_bench.EXIT_INTERRUPTED
    assert "interrupted: 1 of 3 runs finished" in captured.err
    assert "1 of 1 runs passed (interrupted: 2 of 3 not run)" in captured.out
    assert [r["seed"] for r in json.loads(out_json.read_text())] == [0]
    summary = (report / "summary.md").read_text()
    assert "Interrupted: 1 of the campaign's 3 runs finished" in summary
    assert (report / "tendon_glitch_short-seed0.json").exists()


@pytest.mark.parametrize(("option", "message"), [
    (["--json", "{tmp}/missing/r.json"], "--json {tmp}/missing/r.json: the directory"),
    (["--json", "{tmp}"], "is a directory"),
    (["--report", "{tmp}/file"], "--report {tmp}/file: cannot make that directory"),
])
def test_outputs_that_cannot_be_written_are_refused_before_anything_runs(
        option: list[str], message: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    from tools.hil_bench import campaign

    (tmp_path / "file").write_text("")
    monkeypatch.setattr(campaign, "run_job", _never)
    argv = ["run", "link_loss", *(o.format(tmp=tmp_path) for o in option)]
    assert hil_bench.main(argv) == 2
    assert message.format(tmp=tmp_path) in capsys.readouterr().err


def _never(job: dict[str, Any]) -> dict[str, Any]:
    raise AssertionError("ran a job")


@pytest.mark.parametrize("option", [["--workers", "0"], ["--seed", "-1"], ["--seed", "x"],
                                    ["--set", "nokey"], ["--seed", "1", "--seeds", "2"]])
def test_bad_run_options_are_usage_errors(option: list[str],
                                          capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        hil_bench.main(["run", "link_loss", *option])
    assert exc.value.code == 2
    assert "error: argument" in capsys.readouterr().err


def test_built_in_scenarios_are_listed_and_run_by_name(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert hil_bench.main(["list-scenarios"]) == 0
    text = capsys.readouterr().out
    for path in standard_suite():
        assert f"\n{path.stem}  (" in f"\n{text}"
    assert hil_bench.main(["list-scenarios", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert [e["name"] for e in listed] == [p.stem for p in standard_suite()]
    assert [j["source"] for j in expand(["link_loss", "break_away.toml"])] \
        == [str(SUITE / "link_loss.toml"), str(SUITE / "break_away.toml")]
    assert hil_bench.main(["run", "no_such_scenario"]) == 2
    assert "hil-bench list-scenarios" in capsys.readouterr().err


def test_set_fixes_one_value_of_a_varied_key(tmp_path: Path) -> None:
    jobs = expand([_strict_glitch(tmp_path)], seeds=[4],
                  fixed={"faults.0.params.duration_us": 2500, "physics": False})
    assert [j["overrides"] for j in jobs] == [{"faults.0.params.duration_us": 2500,
                                              "physics": False}]
    assert jobs[0]["raw"]["faults"][0]["params"]["duration_us"] == 2500
    assert jobs[0]["raw"]["seed"] == 4


@pytest.mark.parametrize("address", ["nonsense", "tcp://127.0.0.1:1"])
def test_a_scheduler_that_is_not_there_is_said_before_anything_runs(
        address: str, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    from tools.hil_bench import campaign

    monkeypatch.setattr(campaign, "run_job", _never)
    monkeypatch.setattr(campaign, "SCHEDULER_TIMEOUT_S", 0.5)
    assert hil_bench.main(["run", "link_loss", "--scheduler", address]) == 2
    err = capsys.readouterr().err
    assert f"--scheduler {address}: no Dask scheduler there" in err
    assert "Traceback" not in err


def test_a_port_that_is_no_dask_scheduler_is_said_within_the_timeout(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """A port that takes the connection and says nothing: Dask's client gives up after the
    timeout, and what it leaves is collected there (its ``__del__`` once deadlocked a
    later garbage collection for the test's whole timeout)."""
    import socket

    from tools.hil_bench import campaign

    monkeypatch.setattr(campaign, "run_job", _never)
    monkeypatch.setattr(campaign, "SCHEDULER_TIMEOUT_S", 0.5)
    with socket.create_server(("127.0.0.1", 0)) as silent:
        address = f"tcp://127.0.0.1:{silent.getsockname()[1]}"
        started = time.monotonic()
        assert hil_bench.main(["run", "link_loss", "--scheduler", address]) == 2
        waited = time.monotonic() - started
    err = capsys.readouterr().err
    assert f"--scheduler {address}: no Dask scheduler there" in err
    assert "Traceback" not in err
    assert waited < 60  # not the test's timeout: the client gave up and was collected


def test_a_failed_action_no_assertion_checks_is_noted(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "quiet.toml"
    path.write_text('config = "hand"\nphysics = false\n'
                    '[[actions]]\ndo = "power"\nfinger = 2\nstate = "off"\n'
                    '[[actions]]\ndo = "ping"\nid = "gone"\nnode = "finger2.fmcb"\n'
                    '[[actions]]\ndo = "ping"\nid = "palm"\n')
    assert hil_bench.main(["run", str(path)]) == 0  # no assertion: the run passes
    out = capsys.readouterr().out
    assert "quiet seed 0: pass" in out
    assert "note: action gone failed (no assertion checks it): " in out
    assert "action palm" not in out and "action power0" not in out



def test_host_vanish_measures_when_the_elastic_joints_come_to_rest() -> None:
    """``arm_held`` reports ``joints_rest_ms`` (from the plant's joint velocities, not the
    motors' step rates: an elastic joint rings on after its motor stopped) and, given
    ``rest_within_ms``, fails a run whose joints are not at rest by then."""
    from tools.hil_bench.runner import run_scenario

    raw = tomllib.loads((scenario_dir() / "host_vanish.toml").read_text())
    (held,) = run_scenario(raw)["assertions"]
    assert held["passed"]
    motors, joints = held["measured"]["rest_ms"], held["measured"]["joints_rest_ms"]
    assert joints == -1 or joints >= motors > 0  # the joints move while the motors step
    raw["assertions"][0]["rest_within_ms"] = 0  # they were moving when the host vanished
    (held,) = run_scenario(raw)["assertions"]
    assert not held["passed"] and "not at rest" in held["message"]


def test_several_built_in_names_run_in_the_order_given(
        capsys: pytest.CaptureFixture[str]) -> None:
    """``hil-bench run NAME1 NAME2``: both built-in scenarios run, in that order."""
    assert hil_bench.main(["run", "link_latency", "link_loss", "--seed", "0"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines[:2]] == ["link_latency", "link_loss"]
    assert lines[-1] == "2 of 2 runs passed"


def test_host_vanish_with_a_reader_on_the_bus_holds_the_arm() -> None:
    """``host_vanish_reader``: another program's READs every 20 ms, before and after the host
    went, do not keep its goals driving (the host set the nodes' feed to goals only)."""
    from tools.hil_bench.runner import run_scenario

    raw = tomllib.loads((scenario_dir() / "host_vanish_reader.toml").read_text())
    (held,) = run_scenario(raw)["assertions"]
    assert held["passed"], held
    assert max(held["measured"]["drive_on_deg"]) < 8.0


@pytest.mark.slow
def test_host_vanish_with_a_reader_on_its_own_adapter_holds_the_arm() -> None:
    """``host_vanish_reader_adapter``: the reader's READs from its own adapter collide with
    the host's cycles; the host repeats them and moves, and once it is gone the reads do
    not keep its goals driving."""
    from tools.hil_bench.runner import run_scenario

    raw = tomllib.loads((scenario_dir() / "host_vanish_reader_adapter.toml").read_text())
    out = run_scenario(raw)
    (held,) = out["assertions"]
    assert held["passed"], held
    moved = out["actions"]["killed"]["result"]
    assert moved["reader_reads"] > 0 and moved["retries"] > 0 and moved["timeouts"] == 0
