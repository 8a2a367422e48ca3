"""A twelve-node update through the two image slots, then a fleet rollback, run as a user
would: ``flash-all-fingers`` in its own process against ``hil-emulator``'s palm pty."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from protocol.image import BoardType, FirmwareImage
from tests.hil_emulator.emulator_process import HANG_GUARD_S, running_emulator


def _flash(*args: str) -> dict[str, object]:
    done = subprocess.run([sys.executable, "-m", "tools.cli.flash_all_fingers", *args, "--json"],
                          capture_output=True, text=True, timeout=20 * HANG_GUARD_S)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return dict(json.loads(done.stdout))


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_twelve_node_update_and_fleet_rollback_through_the_palm_pty(tmp_path: Path) -> None:
    files = []
    for board in (BoardType.FMCB, BoardType.F2, BoardType.F3):
        image = FirmwareImage.build(bytes(range(256)) * 9 + board.name.encode(), board,
                                    "2.3.4", board.name.lower())
        path = tmp_path / f"{board.name.lower()}.img"
        path.write_bytes(image.to_bytes())
        files += [f"--{board.name.lower()}", str(path)]
    with running_emulator("--config", "hand", "--no-physics") as info:
        port = str(info["palm"])
        update = _flash("--port", port, *files)
        assert update["ok"] is True and update["mode"] == "update"
        nodes = update["nodes"]
        assert isinstance(nodes, list) and len(nodes) == 12
        assert all(n["layout"] == "two-slot" and n["result"] == "flashed"
                   and n["version"] == "2.3.4" and n["slots"]["state"] == "confirmed"
                   and n["downtime_s"] is not None for n in nodes)
        back = _flash("--port", port, "--rollback")
        assert back["ok"] is True and back["mode"] == "rollback"
        rolled = back["nodes"]
        assert isinstance(rolled, list)
        assert all(n["result"] == "rolled back" and n["version"] == n_before["version_before"]
                   for n, n_before in zip(rolled, nodes, strict=True))
