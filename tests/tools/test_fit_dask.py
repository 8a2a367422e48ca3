"""``hil-bench fit --scheduler ADDR`` (``--dask``): the replays run on a Dask cluster and give
what they give in this process; a scheduler that is not there is one line, exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hil_emulator.inprocess import forget_shared_emulators
from hil_emulator.profile import PARAMETERS, RobotProfile
from host.arm.excite import Excitation, excite
from host.arm.facade import Arm
from host.arm.recording import ArmRecorder
from tools.hil_bench.cli import main
from tools.hil_bench.fit.cases import load_case
from tools.hil_bench.fit.evaluate import Replayer

pytest.importorskip("dask.distributed")
pytestmark = pytest.mark.process_wide("dask keeps its connection pools and event loop for the process")

NAME = "arm.J4.stiffness"
TRUTH = PARAMETERS[NAME].nominal * 0.8


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    here = tmp_path_factory.mktemp("fit-dask")
    profile, path = here / "true.json", here / "elbow.mcap"
    RobotProfile({NAME: TRUTH}).write(profile)
    forget_shared_emulators()
    try:
        with Arm.open(f"emu://arm/arm?seed=5&name=test-fit-dask&profile={profile}") as arm:
            arm.torque(True)
            with ArmRecorder(arm, path):
                excite(arm, Excitation(joints=(3,), chirp_s=1.0, hold_s=0.3,
                                       holds=((0.2, 0.3),)))
    finally:
        forget_shared_emulators()
    return path


@pytest.mark.slow
@pytest.mark.timeout(1200)
def test_replays_on_a_local_dask_cluster_equal_those_in_this_process_and_the_fit_runs_there(
        recording: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from dask.distributed import Client, LocalCluster

    paths = [str(recording)]
    cases = [load_case(recording)]
    points = [{NAME: TRUTH}, {NAME: PARAMETERS[NAME].nominal}]
    with Replayer(paths, (), cases) as here:
        local = here.run(points)
    with LocalCluster(processes=True, n_workers=2, threads_per_worker=1,
                      dashboard_address=None, host="127.0.0.1") as cluster:
        with Client(cluster) as client, Replayer(paths, (), cases, scheduler=client) as there:
            remote = there.run(points)
        assert there.replays == 2
        for a, b in zip(local, remote, strict=True):
            assert {n: c.errors for n, c in a[0].items()} == \
                {n: c.errors for n, c in b[0].items()}
        # the truth replays the recording exactly, the nominal robot does not
        assert all(not any(c.errors) for c in remote[0][0].values())
        assert any(any(c.errors) for c in remote[1][0].values())
        code = main(["fit", str(recording), "--params", NAME, "--json",
                     "--dask", cluster.scheduler_address])
    data = json.loads(capsys.readouterr().out)
    assert code == 0, data
    assert abs(data["parameters"][NAME]["value"] - TRUTH) < 0.1 * TRUTH


def test_a_scheduler_that_is_not_there_is_one_line(
        recording: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    from tools.hil_bench import campaign

    monkeypatch.setattr(campaign, "SCHEDULER_TIMEOUT_S", 0.5)
    assert main(["fit", str(recording), "--params", NAME,
                 "--scheduler", "tcp://127.0.0.1:1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no Dask scheduler there" in err[0]
