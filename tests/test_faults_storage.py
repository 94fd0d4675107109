"""Storage faults around a run: refused before the table moves, or an orderly stop.

An output directory that is missing, read-only or nearly full is refused before
the bus is even opened (the simulated actuators never see a frame). A disk that
fills during the run stops it: SAFE_STATE, the file closed with every row
flushed so far and the reason. Small tmpfs mounts stand in for the disks (the
tests run as root, where permission bits would not stop a write); they skip
where mounting is not allowed.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from rig.cli import main
from rig.errors import DataError
from rig.profile import load_profile
from rig.run.recorder import HOLD_S
from rig.run.runner import run_profile
from rig.run.status import RunControl
from rig.runfile import open_run
from rig.wire.can_messages import NodeState
from sim.rig_sim import SimRig
from tests.test_faults_can import LOAD_MARGIN_S, At, measured
from tests.test_run_limits import hardware, profile_file

pytestmark = pytest.mark.usefixtures("no_leaks")


@contextlib.contextmanager
def mounted(where: Path, options: str) -> Iterator[Path]:
    where.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs ({done.stderr.strip()})")
    try:
        yield where
    finally:
        subprocess.run(["umount", str(where)], check=True)


def refused(sim: SimRig, out: Path, tmp_path: Path, match: str) -> None:
    spec = profile_file(tmp_path, "small", 1.0, 0.3)
    with pytest.raises(DataError, match=match):
        run_profile(hardware(sim), load_profile(spec), spec.read_text(), out)
    assert all(a.setpoints_received == 0 for a in sim.actuators)
    assert all(a.state == NodeState.DISABLED for a in sim.actuators)  # not even SAFE_STATE:
    assert sim.server.client_count == 0  # the bus was never opened


def test_a_missing_output_directory_is_refused_before_anything(sim: SimRig,
                                                               tmp_path: Path) -> None:
    refused(sim, tmp_path / "nowhere", tmp_path, "output directory does not exist")
    (tmp_path / "a_file").write_text("")
    refused(sim, tmp_path / "a_file", tmp_path, "not a directory")


def test_a_read_only_output_directory_is_refused_before_anything(sim: SimRig,
                                                                 tmp_path: Path) -> None:
    with mounted(tmp_path / "ro", "size=1m,ro") as disk:
        refused(sim, disk, tmp_path, "not writable: Read-only file system")


def test_a_nearly_full_disk_is_refused_before_anything(sim: SimRig, tmp_path: Path) -> None:
    with mounted(tmp_path / "small", "size=8m") as disk:
        refused(sim, disk, tmp_path, r"only 8\.0 MiB free, a run needs at least 16 MiB")


def test_cli_refuses_an_output_directory_it_cannot_create(tmp_path: Path,
                                                         capsys: pytest.CaptureFixture) -> None:
    with mounted(tmp_path / "ro", "size=1m,ro") as disk:
        code = main(["run", "--profile", "A", "--yes", "--out", str(disk / "runs")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith(f"rig: error: {disk / 'runs'}: cannot create the output directory")


def test_a_disk_filling_mid_run_stops_it_in_order_with_the_data_so_far(
        sim: SimRig, tmp_path: Path) -> None:
    with mounted(tmp_path / "disk", "size=20m") as disk:
        filler = disk / "filler"

        def fill() -> None:  # another process takes all but 4 MiB: under the 16 MiB floor
            st = os.statvfs(disk)
            with open(filler, "wb") as f:
                f.truncate(0)
                os.posix_fallocate(f.fileno(), 0, st.f_bavail * st.f_frsize - (4 << 20))

        spec = profile_file(tmp_path, "fill", 1.0, 1.0)
        inject = At(0.3, fill)
        result = run_profile(hardware(sim), load_profile(spec), spec.read_text(), disk,
                             control=RunControl(listeners=[inject]))
        returned = time.monotonic()
        safe = max(a.safe_state_at for a in sim.actuators) - inject.t
        measured("disk_full", safe_state_s=safe, file_closed_s=returned - inject.t)
        assert result.status == "fail" and "disk nearly full" in result.reason, result.reason
        assert all(a.state == NodeState.SAFE_STATE for a in sim.actuators)
        assert safe < 0.1 + 0.05 + LOAD_MARGIN_S  # the next flush (every 0.1 s) sees it
        run_file = open_run(result.path)
        status = run_file.status
        assert status.exit_status == "fail" and status.complete  # every row it was handed
        assert "disk nearly full" in status.reason
        # raw frames up to the stop (0.3 s baseline, then 0.3 s of the run); decoded sensor
        # samples still held for the clock fit (HOLD_S) when the writer stopped are only raw
        raw_end = run_file.can.time[-1]
        t = run_file.channels["table_u"].time
        assert raw_end > 0.3 + 0.25 and np.all(np.diff(t) > 0)
        assert t[-1] > raw_end - HOLD_S - 0.15
        filler.unlink()
