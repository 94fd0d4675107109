"""Run file under stress: a live reader in another process, kill -9 of the writer, a full disk.

Writers and readers run as real processes (subprocess), on real files; the
disk-full tests mount a small tmpfs (we run as root) and skip where that is
not allowed.
"""

from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import h5py
import numpy as np
import pytest

from rig.errors import DataError
from rig.runfile import RunInfo, RunWriter, open_run, read_status, recover

REPO = Path(__file__).resolve().parents[1]
INFO = RunInfo("A", 'name = "A"\n', "sim")

# Appends 20 rows to table_u and raw/can every 2 ms; prints table_u's flushed
# row count each time it grows. Runs for argv[2] seconds (forever if 0), then closes.
WRITER = """
import sys, time
from rig.runfile import RunInfo, RunWriter
path, seconds = sys.argv[1], float(sys.argv[2])
run = RunWriter(path, RunInfo("A", "", "sim"), block_rows=100, flush_interval=0.05)
i = shown = 0
while seconds == 0 or run.elapsed() < seconds:
    t = run.elapsed()
    for _ in range(20):
        run.can_frame(t, 0x120, i.to_bytes(4, "little"))
        run.sample("table_u", t, float(i))
        i += 1
    if run.rows_written["channels/table_u"] != shown:
        shown = run.rows_written["channels/table_u"]
        print(shown, flush=True)
    time.sleep(0.002)
run.close()
print("closed", flush=True)
"""

# Reads the file with open_run until the writer has closed it; prints what it saw.
READER = """
import sys, time
from rig.runfile import open_run
from rig.errors import DataError
while True:
    try:
        run = open_run(sys.argv[1], raw=False)
    except DataError as exc:
        print("error", exc, flush=True)
        time.sleep(0.05)
        continue
    values = run.channels["table_u"].value
    ok = bool((values == range(len(values))).all())
    print(run.status.state, len(values), ok, flush=True)
    if run.status.state != "running":
        break
    time.sleep(0.05)
"""


# Follows table_u with LiveRun until the writer is gone; prints rows seen and their check.
FOLLOWER = """
import sys, time
import numpy as np
from rig.runfile import LiveRun
with LiveRun(sys.argv[1], ["table_u"]) as live:
    values = []
    while True:
        alive = live.writer_alive()
        values.extend(live.poll()["table_u"][1])
        if not alive:
            break
        time.sleep(0.05)
print(len(values), bool(np.array_equal(values, np.arange(len(values)))), flush=True)
"""


@contextlib.contextmanager
def python(script: str, *args: object) -> Iterator[subprocess.Popen[str]]:
    """Run `script` in a child Python; it is killed and its pipes closed on the way out."""
    child = subprocess.Popen(
        [sys.executable, "-c", script, *map(str, args)],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    with child:  # Popen's own exit closes the pipes and waits
        try:
            yield child
        finally:
            if child.poll() is None:
                child.kill()


def test_second_process_reads_the_file_while_it_grows(tmp_path: Path) -> None:
    path = tmp_path / "live.h5"
    with python(WRITER, path, 2.0) as writer:
        assert writer.stdout.readline().strip().isdigit()  # the file exists and has data
        with python(READER, path) as reader, python(FOLLOWER, path) as follower:
            out, err = reader.communicate(timeout=30)
            followed, follower_err = follower.communicate(timeout=30)
        _, writer_err = writer.communicate(timeout=30)
    assert writer.returncode == reader.returncode == follower.returncode == 0, (
        err + follower_err + writer_err
    )
    assert followed.split() == [str(open_run(path).status.samples["table_u"]), "True"]
    seen = [line.split() for line in out.splitlines() if not line.startswith("error")]
    live = [int(n) for state, n, ok in seen if state == "running"]
    assert len(set(live)) >= 3 and live == sorted(live), out
    assert all(ok == "True" for *_, ok in seen), "reader saw rows out of order or garbage"
    assert seen[-1][0] == "success" and int(seen[-1][1]) >= live[-1]
    assert "error" not in out, out


@pytest.fixture
def killed_run(tmp_path: Path) -> tuple[Path, int]:
    """A run whose writer got SIGKILL mid-run; returns the path and the rows it had flushed."""
    path = tmp_path / "killed.h5"
    flushed = 0
    with python(WRITER, path, 0) as writer:
        for line in writer.stdout:
            flushed = int(line)
            if flushed >= 1500:
                break
        writer.send_signal(signal.SIGKILL)
        rest, _ = writer.communicate(timeout=10)
    flushed = max([flushed, *map(int, rest.split())])  # lines printed before the kill landed
    assert writer.returncode == -signal.SIGKILL
    return path, flushed


def test_kill_9_keeps_every_flushed_row_and_reads_as_crashed(killed_run: tuple[Path, int]) -> None:
    path, flushed = killed_run
    run = open_run(path)
    values = run.channels["table_u"].value
    assert len(values) >= flushed
    np.testing.assert_array_equal(values, np.arange(len(values)))
    assert len(run.can.time) >= flushed - 100  # flushed by the same ticks, up to a block behind
    assert (run.status.state, run.status.exit_status, run.status.complete) == (
        "crashed", "running", False)


def test_recover_makes_a_killed_run_plainly_readable(killed_run: tuple[Path, int]) -> None:
    path, flushed = killed_run
    with pytest.raises(OSError, match="already open for write"):
        h5py.File(path, "r").close()  # why recover exists: plain readers refuse the flags
    before = open_run(path).channels["table_u"].value
    assert recover(path) == path
    with h5py.File(path, "r") as f:
        assert f["channels/table_u"].shape[0] == len(before) >= flushed
    status = read_status(path)
    # the file itself says crashed, as every reader does: not "running" with a dead writer
    assert (status.state, status.exit_status, status.complete) == ("crashed", "crashed", False)
    with h5py.File(path, "r") as f:
        assert f.attrs["exit_status"] == "crashed"
    assert "recovered" in status.reason
    np.testing.assert_array_equal(open_run(path).channels["table_u"].value, before)
    assert not (path.parent / f".{path.name}.reserve").exists()


def test_recover_names_a_missing_file_on_one_line(tmp_path: Path, capsys) -> None:
    from rig.cli import main

    assert main(["recover", str(tmp_path / "gone.h5")]) == 2
    err = capsys.readouterr().err
    assert err == f"rig: error: {tmp_path / 'gone.h5'}: no such file\n"
    with pytest.raises(DataError, match="not a file"):
        recover(tmp_path)


# Stalls inside close() right after reopening the file plainly for the final status, so
# the test can kill the writer in the few-millisecond window where it is not in SWMR mode.
CLOSER = """
import sys, time
import rig.runfile.writer as writer_module
from rig.runfile import RunInfo, RunWriter
reopen = writer_module.reopen_for_status
def reopen_and_stall(path):
    f = reopen(path)
    print("reopened", flush=True)
    time.sleep(60)
    return f
writer_module.reopen_for_status = reopen_and_stall
run = RunWriter(sys.argv[1], RunInfo("A", "", "sim"))
run.samples("table_u", range(500), range(500))
run.close()
"""


def test_kill_while_closing_is_recovered_without_h5clear(tmp_path: Path) -> None:
    path = tmp_path / "closing.h5"
    with python(CLOSER, path) as writer:
        assert writer.stdout.readline().strip() == "reopened"
        writer.kill()
        writer.communicate(timeout=10)
    with pytest.raises(DataError, match="recover"):
        open_run(path)  # flagged open for write, and not by a SWMR writer: nothing opens it
    assert recover(path) == path
    run = open_run(path)
    assert (run.status.state, run.status.complete) == ("crashed", False)
    np.testing.assert_array_equal(run.channels["table_u"].value, np.arange(500))


def test_recover_refuses_a_live_writer(tmp_path: Path) -> None:
    path = tmp_path / "live.h5"
    with RunWriter(path, INFO) as run:
        run.sample("table_u", 0.0, 1.0)
        run.flush()
        assert read_status(path).state == "running"
        with pytest.raises(DataError, match="still running"):
            recover(path)
    assert read_status(path).state == "success"


@contextlib.contextmanager
def tmpfs(where: Path, size: str) -> Iterator[Path]:
    where.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs to fill ({done.stderr.strip()})")
    try:
        yield where
    finally:
        subprocess.run(["umount", str(where)], check=True)


def fill(run: RunWriter) -> int:
    """Append until the writer refuses; return the number of table_u rows appended."""
    for i in range(10**6):
        run.can_frame(i * 1e-4, 0x120, bytes(8))
        run.sample("table_u", i * 1e-4, float(i))
        run.sample("actuator_feedback_2", i * 1e-4, float(i))
        if i % 500 == 0:
            run.flush()
    raise AssertionError("the disk never filled")


def test_disk_full_closes_cleanly_with_the_data_so_far(tmp_path: Path) -> None:
    with tmpfs(tmp_path / "small", "2m") as disk:
        path = disk / "run.h5"
        with (
            pytest.raises(DataError, match="disk full"),
            RunWriter(path, INFO, min_free_bytes=0) as run,
        ):
            fill(run)
        run_file = open_run(path)
        assert run_file.status.state == "fail" and not run_file.status.complete
        assert "No space left on device" in run_file.status.reason
        for name in ("table_u", "actuator_feedback_2"):
            values = run_file.channels[name].value
            assert len(values) > 1000
            np.testing.assert_array_equal(values, np.arange(len(values)))  # no garbage rows
        with h5py.File(path, "r") as f:  # plainly readable: closed properly
            assert f.attrs["exit_status"] == "fail"


def test_low_disk_space_stops_before_enospc(tmp_path: Path) -> None:
    with tmpfs(tmp_path / "small", "3m") as disk:
        path = disk / "run.h5"
        with (
            pytest.raises(DataError, match="disk nearly full"),
            RunWriter(path, INFO, min_free_bytes=1 << 20) as run,
        ):
            fill(run)
        run_file = open_run(path)
        assert (run_file.status.state, run_file.status.complete) == ("fail", True)
        values = run_file.channels["table_u"].value
        np.testing.assert_array_equal(values, np.arange(len(values)))
        assert len(run_file.can.time) == len(values) > 1000


def test_no_space_at_start_is_refused_before_anything(tmp_path: Path) -> None:
    with tmpfs(tmp_path / "tiny", "64k") as disk:
        with pytest.raises(DataError, match=f"{disk}.*No space left on device"):
            RunWriter(disk / "run.h5", INFO)
        assert list(disk.iterdir()) == []
