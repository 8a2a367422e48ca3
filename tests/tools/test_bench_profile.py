"""``hil-bench run --profile FILE``: every run's emulator has the profile's robot, the
result and the reproduce line name it, and a file that is no profile is one line, exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hil_emulator.profile import RobotProfile
from tools.hil_bench import cli as hil_bench
from tools.hil_bench.campaign import expand
from tools.hil_bench.report import reproduce_command
from tools.hil_bench.runner import Bench
from tools.hil_bench.scenario import find_scenario, parse_scenario

VALUES = {"arm.J2.stiffness": 260.0, "arm.J4.bearing_friction": 0.12}


@pytest.fixture
def profile(tmp_path: Path) -> Path:
    path = tmp_path / "robot.json"
    RobotProfile(VALUES).write(path)
    return path


def test_a_campaign_job_carries_the_profile_to_the_plant(profile: Path) -> None:
    from hil_emulator.profile import load_profile

    (job,) = expand(["spring_drift"], seeds=[31], profile=load_profile(profile))
    assert job["profile"] == {"parameters": VALUES, "source": str(profile)}
    json.dumps(job)  # plain data: what a Dask worker is sent
    carried = RobotProfile(job["profile"]["parameters"], source=job["profile"]["source"])
    bench = Bench(parse_scenario(job["raw"], job["source"]), carried)
    try:
        params = bench.emu.require_arm_plant().params
        assert params.stiffness[1] == 260.0
        assert params.bearing_friction_as_built_nm[3] == 0.12
    finally:
        bench.emu.close()
    nominal = Bench(parse_scenario(job["raw"], job["source"]))
    try:
        assert nominal.emu.require_arm_plant().params.stiffness[1] == 200.0
    finally:
        nominal.emu.close()


@pytest.mark.slow
def test_hil_bench_run_with_a_profile_names_it_in_the_result_and_the_reproduce_line(
        profile: Path, tmp_path: Path) -> None:
    out = tmp_path / "results.json"
    hil_bench.main(["run", str(find_scenario("spring_drift")), "--seed", "31",
                    "--profile", str(profile), "--json", str(out)])
    (result,) = json.loads(out.read_text())
    assert result["profile"] == str(profile)
    assert f"--profile {profile}" in reproduce_command(result)


def test_a_profile_that_is_no_profile_is_refused_before_anything_runs(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text("[1, 2]")
    assert hil_bench.main(["run", "spring_drift", "--profile", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bad) in err[0] and "not a JSON object" in err[0]
