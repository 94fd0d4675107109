"""Run file: round trip, lifecycle, corrupt inputs, refused targets. Real HDF5 on disk."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rig.errors import DataError
from rig.runfile import (
    CAN_FLAG_ERROR,
    CAN_FLAG_EXTENDED,
    SCHEMA_VERSION,
    ChannelSpec,
    LiveRun,
    RunInfo,
    RunWriter,
    list_runs,
    open_run,
    read_status,
    recover,
    standard_channels,
)
from rig.runfile.superblock import lookup3, status_flags

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

PROFILE_TOML = 'name = "A"\n[[segment]]\nhold = 1.0\n'
INFO = RunInfo(
    "A",
    PROFILE_TOML,
    "sim",
    configuration_toml="[bus]\nkind = 'socketcand'\n",
    calibration={"table_gain": 1.0002, "mass_offset_m": -0.0031},
    host="bench-1",
)
EXTRA = ChannelSpec("oil_temp", "1", "serial:/dev/pts/3 Aux.temp", "oil temperature, raw counts",
                    "int32")


def write_run(path: Path, rows: int = 450) -> None:
    """A small run touching every table; rows > block_rows so blocks and the tail both land."""
    with RunWriter(path, INFO, channels=(*standard_channels(), EXTRA)) as run:
        for i in range(rows):
            t = i * 1e-3
            run.can_frame(t, 0x120 + i % 3, bytes([i % 256, 1, 2]), extended=i % 2 == 1)
            run.serial_frame(t, bytes(range(i % 200, i % 200 + 16)))
            run.sample("table_u", t, 1e-4 * i)
            run.sample("actuator_status_4", t, i % 7)
        run.can_frame(1.0, 0x7FF, b"", error=True)
        run.samples("mass_x", np.arange(10) * 0.01, np.linspace(0, 0.1, 10))
        run.samples("oil_temp", [0.5, 0.6], [310, 311])
        run.gap("mass_x", 0.09, 0.2, 11)
        run.samples("mass_x", [0.2], [0.11])
        run.count("serial", "lost", 11)
        run.count("serial", "crc_errors")
        run.set_count("can", "duplicates", 4)


def test_round_trip_every_table_and_attribute(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    write_run(path)
    run = open_run(path)
    assert run.status.state == "success" and run.status.complete and run.status.reason == ""
    assert run.status.samples["table_u"] == 450 and run.status.samples["raw/can"] == 451
    assert run.meta["schema_version"] == SCHEMA_VERSION
    assert run.meta["profile_toml"] == PROFILE_TOML and run.meta["backend"] == "sim"
    assert run.meta["host"] == "bench-1" and run.meta["end_time"] >= run.meta["start_time"]
    assert run.calibration == {"mass_offset_m": -0.0031, "table_gain": 1.0002}
    table_u = run.channels["table_u"]
    np.testing.assert_array_equal(table_u.time, np.arange(450) * 1e-3)
    np.testing.assert_array_equal(table_u.value, 1e-4 * np.arange(450))
    assert (table_u.units, table_u.source) == ("m", "can:TableSensor.position")
    status = run.channels["actuator_status_4"]
    assert status.value.dtype == np.uint16 and status.units == "1" and status.value[-1] == 449 % 7
    oil = run.channels["oil_temp"]
    assert (oil.dtype, oil.source, list(oil.value)) == ("int32", EXTRA.source, [310, 311])
    assert set(run.channels) == {s.name for s in standard_channels()} | {"oil_temp"}
    assert run.channels["actuator_setpoint_6"].time.shape == (0,)


def test_round_trip_raw_frames_counters_and_gaps(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    write_run(path)
    run = open_run(path)
    assert run.can.data.shape == (451, 8)
    assert run.can.data[299].tolist() == [299 % 256, 1, 2, 0, 0, 0, 0, 0]
    assert run.can.dlc[0] == 3 and run.can.arbitration_id[1] == 0x121
    assert run.can.is_extended[1] and not run.can.is_extended[0]
    assert run.can.flags[-1] == CAN_FLAG_ERROR and run.can.is_error.sum() == 1
    assert CAN_FLAG_EXTENDED == 2 and run.can.dlc[-1] == 0
    assert run.serial.data.shape == (450, 16) and bytes(run.serial.data[5]) == bytes(range(5, 21))
    assert run.counters["serial"]["lost"] == 11 and run.counters["serial"]["crc_errors"] == 1
    assert run.counters["can"]["duplicates"] == 4 and run.counters["can"]["lost"] == 0
    (gap,) = run.gaps
    assert (gap.channel, gap.start_sample, gap.end_sample, gap.count) == ("mass_x", 9, 10, 11)
    mass = run.channels["mass_x"]
    assert mass.time[gap.start_sample] == pytest.approx(0.09) and mass.time[gap.end_sample] == 0.2
    assert open_run(path, raw=False).can is None


def test_retime_places_every_sample_again_and_moves_the_gaps_with_them(tmp_path: Path) -> None:
    """The recorder's end-of-run clock fit: new times for every row, flushed or not, the
    values untouched, each gap's times those of the samples it lies between."""
    path = tmp_path / "run.h5"
    with RunWriter(path, INFO, channels=standard_channels(), block_rows=4) as run:
        run.samples("mass_x", np.arange(10) * 0.01, np.linspace(0, 0.1, 10))
        run.gap("mass_x", 0.09, 0.2, 11)
        run.samples("mass_x", [0.2, 0.21], [0.11, 0.12])
        run.samples("table_u", [0.0, 0.001], [1.0, 2.0])
        late = 5e-4 + (1 + 30e-6) * np.r_[np.arange(10) * 0.01, 0.2, 0.21]
        run.retime("mass_x", late)
        with pytest.raises(ValueError, match="3 times for 12 rows"):
            run.retime("mass_x", late[:3])
        with pytest.raises(ValueError, match="unknown channel"):
            run.retime("oil_temp", late)
    got = open_run(path)
    mass = got.channels["mass_x"]
    assert np.array_equal(mass.time, late)
    assert np.allclose(mass.value, np.r_[np.linspace(0, 0.1, 10), 0.11, 0.12])
    assert np.array_equal(got.channels["table_u"].time, [0.0, 0.001])  # not asked: as written
    (gap,) = got.gaps
    assert (gap.start_sample, gap.end_sample, gap.count) == (9, 10, 11)
    assert (gap.start_time, gap.end_time) == (late[9], late[10])


def test_every_table_describes_itself(tmp_path: Path) -> None:
    """Tools other than ours see units, source, description and dtype on every table."""
    path = tmp_path / "run.h5"
    write_run(path, rows=5)
    with h5py.File(path, "r") as f:
        for name, ds in f["channels"].items():
            assert {"units", "source", "description", "dtype", "time_units"} <= set(ds.attrs), name
            assert ds.maxshape == (None,) and ds.chunks is not None
        for name in ("raw/can", "raw/serial", "gaps"):
            assert {"units", "source", "description"} <= set(f[name].attrs)
        assert json.loads(f.attrs["samples_json"])["oil_temp"] == 2


def test_close_is_idempotent_and_first_status_wins(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    run = RunWriter(path, INFO)
    run.sample("table_u", 0.0, 0.5)
    run.close("abort", "operator pressed stop")
    run.close("success")
    run.close("fail", "ignored")
    assert run.closed
    status = read_status(path)
    assert (status.state, status.reason) == ("abort", "operator pressed stop")
    assert status.complete
    with pytest.raises(DataError, match="closed"):
        run.sample("table_u", 0.1, 0.5)
    with pytest.raises(ValueError, match="exit_status"):
        RunWriter(tmp_path / "other.h5", INFO).close("finished")


def test_exception_in_context_closes_with_fail_and_reason(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    with pytest.raises(RuntimeError), RunWriter(path, INFO) as run:
        run.sample("table_u", 0.0, 0.5)
        raise RuntimeError("actuator 3 stopped answering\nsecond line")
    status = read_status(path)
    assert status.state == "fail"
    assert status.reason == "RuntimeError: actuator 3 stopped answering second line"
    assert open_run(path).channels["table_u"].value.tolist() == [0.5]


def test_exception_after_explicit_close_keeps_the_status(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    with pytest.raises(KeyError), RunWriter(path, INFO) as run:
        run.close("success")
        raise KeyError("after the run")
    assert read_status(path).state == "success"


def test_ctrl_c_in_context_is_an_abort(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    with pytest.raises(KeyboardInterrupt), RunWriter(path, INFO):
        raise KeyboardInterrupt
    assert (read_status(path).state, read_status(path).reason) == ("abort", "KeyboardInterrupt")


def test_unconvertible_value_fails_the_run_but_still_closes_the_file(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    with pytest.raises(ValueError, match="bad rows for channels/table_u"):
        with RunWriter(path, INFO) as run:
            run.sample("mass_x", 0.0, 0.25)
            run.sample("table_u", 0.0, "not a number")
    status = read_status(path)
    assert status.state == "fail" and not status.complete
    assert "table_u" in status.reason


def test_bad_appends_are_refused_on_the_spot(tmp_path: Path) -> None:
    with RunWriter(tmp_path / "run.h5", INFO) as run:
        with pytest.raises(ValueError, match="unknown channel 'table_v'"):
            run.sample("table_v", 0.0, 1.0)
        with pytest.raises(ValueError, match="9 bytes"):
            run.can_frame(0.0, 0x120, bytes(9))
        with pytest.raises(ValueError, match="15 bytes"):
            run.serial_frame(0.0, bytes(15))
        with pytest.raises(ValueError, match="counter"):
            run.count("ethernet", "lost")
        with pytest.raises(ValueError, match="gap for unknown"):
            run.gap("nothing", 0.0, 1.0, 3)


def test_missing_directory_refused_before_anything(tmp_path: Path) -> None:
    target = tmp_path / "no" / "such" / "run.h5"
    with pytest.raises(DataError, match=str(target.parent)):
        RunWriter(target, INFO)
    assert not (tmp_path / "no").exists()


def test_directory_that_is_a_file_refused(tmp_path: Path) -> None:
    plain = tmp_path / "notes.txt"
    plain.write_text("x")
    with pytest.raises(DataError, match="notes.txt"):
        RunWriter(plain / "run.h5", INFO)


def test_existing_run_file_is_never_overwritten(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    write_run(path, rows=3)
    with pytest.raises(DataError, match="already exists"):
        RunWriter(path, INFO)
    assert open_run(path).status.state == "success"


def test_read_only_directory_refused(tmp_path: Path) -> None:
    """Root ignores chmod, so mount a read-only tmpfs; skip where mounting is not allowed."""
    ro = tmp_path / "ro"
    ro.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(ro)],
                             capture_output=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a read-only tmpfs here: {mounted.stderr.decode().strip()}")
    try:
        with pytest.raises(DataError, match=f"{ro}.*Read-only file system"):
            RunWriter(ro / "run.h5", INFO)
        assert os.listdir(ro) == []
    finally:
        subprocess.run(["umount", str(ro)], check=True)


def test_not_hdf5_is_a_one_line_data_error(tmp_path: Path) -> None:
    path = tmp_path / "noise.h5"
    path.write_bytes(np.random.default_rng(1).bytes(4096))
    with pytest.raises(DataError, match="not an HDF5 file") as info:
        open_run(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_hdf5_without_our_groups(tmp_path: Path) -> None:
    path = tmp_path / "other.h5"
    with h5py.File(path, "w") as f:
        f["x"] = np.arange(3)
    with pytest.raises(DataError, match=r"not a run file: missing /raw"):
        open_run(path)


def test_wrong_schema_version(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    write_run(path, rows=3)
    with h5py.File(path, "r+") as f:
        f["meta"].attrs["schema_version"] = 99
    with pytest.raises(DataError, match="schema version 99"):
        open_run(path)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="no such run file"):
        open_run(tmp_path / "gone.h5")


@pytest.fixture(scope="module")
def good_bytes(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    path = tmp_path_factory.mktemp("good") / "run.h5"
    write_run(path, rows=300)
    return path.read_bytes()


@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(fraction=st.floats(0.0, 0.999))
def test_truncated_file_is_a_one_line_data_error(
    tmp_path: Path, good_bytes: bytes, fraction: float
) -> None:
    path = tmp_path / "cut.h5"
    path.write_bytes(good_bytes[: int(len(good_bytes) * fraction)])
    with pytest.raises(DataError) as info:
        open_run(path)
    message = str(info.value)
    assert message.startswith(str(path)) and "\n" not in message


def test_list_runs_tolerates_broken_files(tmp_path: Path) -> None:
    write_run(tmp_path / "a_good.h5", rows=250)
    (tmp_path / "b_noise.h5").write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(50))
    with pytest.raises(RuntimeError), RunWriter(tmp_path / "c_failed.h5", INFO) as run:
        run.count("can", "lost", 2)
        raise RuntimeError("bus off")
    (tmp_path / "notes.txt").write_text("not a run")
    rows = {row.name: row for row in list_runs(tmp_path)}
    assert list(rows) == ["a_good.h5", "b_noise.h5", "c_failed.h5"]
    good = rows["a_good.h5"]
    assert (good.status, good.samples, good.losses) == ("success", 250 * 2 + 10 + 1 + 2, 11)
    assert good.duration == pytest.approx(1.0)
    assert rows["b_noise.h5"].status == "unreadable" and "b_noise.h5" in rows["b_noise.h5"].reason
    assert (rows["c_failed.h5"].status, rows["c_failed.h5"].losses) == ("fail", 2)
    assert rows["c_failed.h5"].reason == "RuntimeError: bus off"
    with pytest.raises(DataError, match="no such directory"):
        list_runs(tmp_path / "missing")


def test_recover_leaves_a_clean_file_alone(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    write_run(path, rows=3)
    before = path.read_bytes()
    assert recover(path) == path and path.read_bytes() == before


def test_lookup3_matches_reference_vectors_and_hdf5() -> None:
    """recover() rewrites the superblock checksum, so the hash must be HDF5's exactly."""
    assert lookup3(b"") == 0xDEADBEEF
    assert lookup3(b"Four score and seven years ago") == 0x17770551
    assert lookup3(b"Four score and seven years ago", 1) == 0xCD628161


def test_superblock_checksum_agrees_with_hdf5(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    write_run(path, rows=3)
    head = path.read_bytes()[:48]
    assert status_flags(path) == 0 and head[8] == 3  # superblock v3, closed cleanly
    assert lookup3(head[:44]) == int.from_bytes(head[44:48], "little")


def test_live_run_on_a_finished_file_returns_each_row_once(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    write_run(path, rows=250)
    with LiveRun(path, ["table_u", "mass_x"]) as live:
        first, second = live.poll(), live.poll()
        assert live.channels["table_u"].units == "m" and not live.writer_alive()
    np.testing.assert_array_equal(first["table_u"][1], 1e-4 * np.arange(250))
    assert len(first["mass_x"][0]) == 11 and len(second["table_u"][0]) == 0
    with pytest.raises(DataError, match="no channels"):
        LiveRun(path, ["table_v"])

