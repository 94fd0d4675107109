"""Bad input: malformed or hostile TOML, DBC mismatches on the bus, damaged HDF5 and CSV.

Every command answers with one line on stderr naming the file and the problem
and exit code 2, never a traceback. The readers are fuzzed with hypothesis (each
test bounded by max_examples to a few seconds). A damaged HDF5 file on which the
HDF5 library itself loops or crashes is caught by reading it in a forked child
first (rig.runfile.probe).
"""

from __future__ import annotations

import os
import random
import signal
import time
from pathlib import Path

import can
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from analysis.cli import main as analysis_main
from analysis.identify.loading import load_runs
from rig.cli import main as rig_main
from rig.config import load_config
from rig.errors import ConfigError, DataError
from rig.paths import data_file
from rig.profile import load_profile
from rig.runfile import RunInfo, RunWriter, check_readable, open_run
from rig.runfile import reader as runfile_reader
from rig.wire import can_messages as cm
from sim.rig_sim import SimRig
from tests.test_faults_can import At, run

FUZZ = settings(max_examples=40, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])
RIG_TOML = data_file("rig.toml").read_text(encoding="utf-8")


def one_line_error(capsys: pytest.CaptureFixture, prog: str, path: Path, *words: str) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"{prog}: error: {path}"), err
    for w in words:
        assert w in lines[0], err
    return lines[0]


# -- configuration and profile TOML -------------------------------------------------------

def _rig_toml(old: str, new: str) -> bytes:
    assert old in RIG_TOML
    return RIG_TOML.replace(old, new, 1).encode()


CONFIGS = {
    "not_toml": (b"backend = \n[[[", "not valid TOML"),
    "nested_deep": (b"a = " + b"[" * 5000 + b"]" * 5000, "nested too deeply"),
    "binary": (bytes(range(256)) * 4, "cannot read"),
    "empty": (b"", "backend: missing"),
    "infinite": (_rig_toml("value = 12, unit = \"ft\"", "value = 1e999, unit = \"ft\""),
                 "must be a finite number"),
    "huge_int": (_rig_toml("bitrate = 1_000_000", "bitrate = 1" + "0" * 40), "must be in"),
    "wrong_type": (_rig_toml('backend = "sim"', "backend = 3"), "must be one of"),
    "unknown_key": (_rig_toml('path = "/dev/ttyUSB0"', 'path = "/dev/ttyUSB0"\nparity = "none"'),
                    "serial.parity: unknown key"),
    "rate_too_high": (_rig_toml("setpoint_hz = 400", "setpoint_hz = 1e9"), "must be <="),
    "bad_unit": (_rig_toml('piston_area = { value = 12.0, unit = "in^2" }',
                           'piston_area = { value = 12.0, unit = "acre" }'),
                 "must be a area unit"),
}


@pytest.mark.parametrize("case", sorted(CONFIGS))
def test_a_bad_configuration_is_one_line_exit_2(tmp_path: Path, capsys, case: str) -> None:
    content, words = CONFIGS[case]
    path = tmp_path / f"{case}.toml"
    path.write_bytes(content)
    assert rig_main(["check", "--profile", "A", "--config", str(path)]) == 2
    one_line_error(capsys, "rig", path, words)


def test_rig_run_refuses_a_bad_configuration_before_starting_anything(tmp_path: Path,
                                                                      capsys) -> None:
    path = tmp_path / "rig.toml"
    path.write_bytes(CONFIGS["nested_deep"][0])
    out = tmp_path / "runs"
    assert rig_main(["run", "--profile", "A", "--config", str(path), "--yes",
                     "--out", str(out)]) == 2
    one_line_error(capsys, "rig", path, "nested too deeply")
    assert not out.exists()


PROFILES = {
    "not_toml": (b"[[segment]\nhold = ", "not valid TOML"),
    "nested_deep": (b"x = " + b"{a = " * 3000 + b"1" + b"}" * 3000, "nested too deeply"),
    "infinite_hold": (b"[[segment]]\nhold = inf\n", "must be a finite number"),
    "hour_long_segment": (b"[[segment]]\nhold = 4000\n", "longer than an hour"),
    "days_in_all": (b"[[segment]]\nhold = 3000\n" * 50, "longer than 3600 s"),
    "no_segments": (b"segment = 5\n", "needs at least one"),
    "string_target": (b"[[segment]]\nramp_to = \"far\"\nduration = 1\n", "finite number"),
    "absurd_target": (b"[[segment]]\nramp_to = 1e300\nduration = 1\n", "beyond ±1000 m"),
    "bad_units": (b"units = \"furlong\"\n[[segment]]\nhold = 1\n", "must be one of"),
    "binary": (b"\xff\xfe\x00garbage", "cannot read"),
}


@pytest.mark.parametrize("case", sorted(PROFILES))
def test_a_bad_profile_is_one_line_exit_2(tmp_path: Path, capsys, case: str) -> None:
    content, words = PROFILES[case]
    path = tmp_path / f"{case}.toml"
    path.write_bytes(content)
    assert rig_main(["check", "--profile", str(path)]) == 2
    one_line_error(capsys, "rig", path, words)


toml_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=5), inner,
                                                                max_size=3),
    max_leaves=8,
)


@FUZZ
@given(lines=st.lists(st.integers(0, 400), min_size=1, max_size=5),
       junk=st.lists(st.sampled_from(["= 1", "[x]", "1e999", "-0", "\"\"", "[[", "{}", "nan",
                                      "0x7fffffffffffffffff", "true", "'''", "\\"]),
                     min_size=1, max_size=5))
def test_fuzz_config_loader_only_ever_raises_config_error(tmp_path: Path, lines: list[int],
                                                           junk: list[str]) -> None:
    text = RIG_TOML.splitlines()
    for n, j in zip(lines, junk):
        k = n % len(text)
        text[k] = text[k][: len(text[k]) // 2] + j
    path = tmp_path / "fuzz.toml"
    path.write_text("\n".join(text), encoding="utf-8")
    try:
        load_config(path)
    except ConfigError as e:
        assert str(e).startswith(str(path)) and "\n" not in str(e)


@FUZZ
@given(doc=st.dictionaries(st.sampled_from(["name", "units", "start", "segment", "x"]),
                           toml_values | st.lists(st.dictionaries(
                               st.sampled_from(["hold", "ramp_to", "duration", "y"]),
                               st.floats() | st.integers() | st.text(max_size=3),
                               max_size=3), max_size=4), max_size=5))
def test_fuzz_profile_loader_only_ever_raises_config_error(tmp_path: Path, doc: dict) -> None:
    path = tmp_path / "fuzz.toml"
    path.write_text(_to_toml(doc), encoding="utf-8")
    try:
        load_profile(path)
    except ConfigError as e:
        assert str(e).startswith(str(path)) and "\n" not in str(e)


def _to_toml(doc: dict) -> str:
    """A rough TOML writer for the fuzzer (values TOML cannot hold become strings)."""
    def value(v: object) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, float):
            return "nan" if v != v else ("inf" if v == float("inf") else
                                         "-inf" if v == -float("inf") else repr(v))
        if isinstance(v, int):
            return str(v)
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{" + ", ".join(f"{k!r} = {value(x)}".replace("'", '"')
                                   for k, x in v.items()) + "}"
        return '"' + str(v).replace("\\", "\\\\").replace('"', '\\"') + '"'
    lines = []
    for k, v in doc.items():
        if k == "segment" and isinstance(v, list) and all(isinstance(s, dict) for s in v):
            for seg in v:
                lines.append("[[segment]]")
                lines += [f"{sk} = {value(sv)}" for sk, sv in seg.items()]
        else:
            lines.insert(0, f"{k} = {value(v)}")
    return "\n".join(lines) + "\n"


# -- CAN frames that do not match the DBC ---------------------------------------------------

def test_frames_that_fail_the_dbc_are_kept_raw_counted_and_ignored(sim: SimRig,
                                                                  tmp_path: Path) -> None:
    """Short frames, an index that contradicts the id, a state outside the enum, on the
    rig's own ids: kept in raw/can, counted as CAN crc_errors, never decoded; an unknown id
    (another node's) is kept raw and not counted. The run goes on."""
    bad = [can.Message(arbitration_id=cm.FEEDBACK_BASE + 3, data=b"\x03\x00", is_extended_id=False),
           can.Message(arbitration_id=cm.FEEDBACK_BASE + 4, data=bytes([2]) + bytes(7),
                       is_extended_id=False),
           can.Message(arbitration_id=cm.FEEDBACK_BASE + 5, data=bytes([5, 0, 0, 0, 0, 0, 0, 9]),
                       is_extended_id=False),
           can.Message(arbitration_id=cm.TABLE_SENSOR_ID, data=b"\x01", is_extended_id=False)]
    other = can.Message(arbitration_id=0x555, data=b"\x01\x02", is_extended_id=False)
    out = run(sim, tmp_path, At(0.2, lambda: sim.server.broadcast_many(bad * 5 + [other])),
              ramp_s=0.4)
    assert out.result.status == "success", out.result.reason
    assert out.run.counters["can"]["crc_errors"] == 20
    assert int(np.sum(out.run.can.arbitration_id == 0x555)) == 1


# -- damaged run files (HDF5) ---------------------------------------------------------------

@pytest.fixture(scope="module")
def good_run(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    """A small but complete run file: 1.5 s of table_u and mass_x at 1 kHz."""
    path = tmp_path_factory.mktemp("good") / "run.h5"
    with RunWriter(path, RunInfo("A", 'name = "A"\n', "sim")) as w:
        for i in range(1500):
            t = i * 1e-3
            w.can_frame(t, cm.TABLE_SENSOR_ID, bytes(8))
            w.serial_frame(t, bytes(16))
            w.sample("table_u", t, 0.01 * np.sin(7 * t))
            w.sample("mass_x", t + 2e-4, 0.01 * np.sin(7 * t - 0.3))
    return path.read_bytes()


def damaged(good: bytes, how: str, rng: random.Random) -> bytes:
    b = bytearray(good)
    if how == "truncated":
        return bytes(b[: rng.randrange(len(b))])
    if how == "flipped":
        for _ in range(rng.randint(1, 40)):
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
        return bytes(b)
    start = rng.randrange(len(b))  # "zeroed": a block overwritten, as by a bad sector
    size = min(rng.randint(1, 4096), len(b) - start)
    b[start:start + size] = bytes(size)
    return bytes(b)


CUTS = {"empty": b"", "not_hdf5": b"time,u,x\n0,0,0\n", "signature_only": b"\x89HDF\r\n\x1a\n"}


@pytest.mark.parametrize("case", ["empty", "not_hdf5", "signature_only", "cut_10", "cut_50",
                                  "cut_99", "zeroed_superblock"])
def test_damaged_run_files_are_one_line_errors(tmp_path: Path, good_run: bytes, capsys,
                                               case: str) -> None:
    if case in CUTS:
        content = CUTS[case]
    elif case.startswith("cut_"):
        content = good_run[: len(good_run) * int(case[4:]) // 100]
    else:
        content = bytes(64) + good_run[64:]
    path = tmp_path / "runs" / f"{case}.h5"
    path.parent.mkdir()
    path.write_bytes(content)
    assert analysis_main(["fit", str(path), "--mass", "2721.6", "--no-refine"]) == 2
    one_line_error(capsys, "analysis", path)
    assert rig_main(["runs", str(path.parent)]) == 2
    captured = capsys.readouterr()
    assert "unreadable" in captured.out and "Traceback" not in captured.err
    assert captured.err.splitlines() == [captured.err.strip()]
    assert captured.err.startswith(f"rig: error: {path}")
    assert rig_main(["recover", str(path)]) == 2
    one_line_error(capsys, "rig", path)


@FUZZ
@given(seed=st.integers(0, 2**32 - 1), how=st.sampled_from(["truncated", "flipped", "zeroed"]))
@example(seed=107840209, how="flipped")  # a flipped bit made a time inf: np.diff warned
def test_fuzz_run_file_reader_only_ever_raises_data_error(tmp_path: Path, good_run: bytes,
                                                          seed: int, how: str) -> None:
    path = tmp_path / "fuzz.h5"
    path.write_bytes(damaged(good_run, how, random.Random(seed)))
    try:
        # a file HDF5 hangs or crashes on is a DataError too (rare: 1 of ~800 tried here)
        check_readable(path, open_run, timeout=2.0)
        open_run(path)
        load_runs([path], mass=2721.6)
    except DataError as e:
        assert str(e).startswith(str(path)) and "\n" not in str(e)


def test_a_file_the_hdf5_library_hangs_or_crashes_on_is_reported_not_hung_on(
        tmp_path: Path, good_run: bytes, capsys, monkeypatch: pytest.MonkeyPatch) -> None:
    """The HDF5 C library can loop forever on a damaged file (found by fuzzing: a zeroed
    4 KiB block under an attribute's heap). Stand-ins: a read that spins with the GIL
    held and one that dies of SIGSEGV, in the forked child that reads first."""
    path = tmp_path / "runs" / "a.h5"
    path.parent.mkdir()
    path.write_bytes(good_run)
    parent = os.getpid()
    real = runfile_reader._summary

    def spins_in_the_child(p: Path) -> object:
        while os.getpid() != parent:
            pass
        return real(p)

    monkeypatch.setattr("rig.runfile.probe.BASE_TIMEOUT_S", 0.5)
    monkeypatch.setattr(runfile_reader, "_summary", spins_in_the_child)
    t = time.monotonic()
    assert rig_main(["runs", str(path.parent)]) == 2
    assert time.monotonic() - t < 3
    err = capsys.readouterr().err
    assert err.startswith(f"rig: error: {path}: damaged HDF5 file: reading it did not finish")

    def crashes_in_the_child(p: Path) -> object:
        if os.getpid() != parent:
            os.kill(os.getpid(), signal.SIGSEGV)
        return real(p)

    monkeypatch.setattr(runfile_reader, "_summary", crashes_in_the_child)
    assert rig_main(["runs", str(path.parent)]) == 2
    assert "the library crashed reading it (signal 11)" in capsys.readouterr().err


# -- damaged CSV --------------------------------------------------------------------------

GOOD_CSV = "t,u,x\n" + "".join(f"{k * 1e-3},{np.sin(k * 7e-3):.6f},{np.sin(k * 7e-3 - 0.3):.6f}\n"
                               for k in range(400))
CSVS = {
    "binary": (bytes(range(256)) * 8, "not a UTF-8 text CSV"),
    "nul_bytes": (GOOD_CSV.replace("0.0", "0\x000", 1).encode(), "is not a number"),
    "not_a_number": (GOOD_CSV.replace("0.001,", "zero,", 1).encode(), "is not a number"),
    "infinite": (GOOD_CSV.replace("0.001,", "inf,", 1).encode(), "non-finite"),
    "no_u_column": (GOOD_CSV.replace("t,u,x", "t,v,x").encode(), "no column 'u'"),
    "empty": (b"", "empty file"),
    "header_only": (b"t,u,x\n", "has 0 samples"),
    "huge_field": (("t,u,x\n0," + "9" * 200_000 + ",0\n").encode(), "not a readable CSV"),
    "truncated_row": (GOOD_CSV[: len(GOOD_CSV) // 2 + 3].encode(), ""),
    "time_backwards": (GOOD_CSV.replace("0.002,", "0.0005,", 1).encode(), "decreasing time"),
}


@pytest.mark.parametrize("case", sorted(CSVS))
def test_a_damaged_csv_is_one_line_exit_2(tmp_path: Path, capsys, case: str) -> None:
    content, words = CSVS[case]
    path = tmp_path / f"{case}.csv"
    path.write_bytes(content)
    assert analysis_main(["fit", str(path), "--mass", "2721.6", "--no-refine"]) == 2
    one_line_error(capsys, "analysis", path, words)


@FUZZ
@given(data=st.binary(max_size=2000) | st.text(alphabet="tux,.0123456789e-+\n\r \"nai",
                                               max_size=2000).map(str.encode))
def test_fuzz_csv_loader_only_ever_raises_data_error(tmp_path: Path, data: bytes) -> None:
    path = tmp_path / "fuzz.csv"
    path.write_bytes(b"t,u,x\n" + data)
    try:
        load_runs([path], mass=2721.6)
    except DataError as e:
        assert str(e).startswith(str(path)) and "\n" not in str(e)
