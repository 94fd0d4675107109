"""Other tools' files in and out: CAN logs (`rig import`), MDF 4 and TDMS (`analysis fit`),
and run files out as MDF 4 (`rig export`). Every file here is written by the library
that owns the format (python-can's writers, asammdf, nptdms, cantools' DBC parser reads
the bench DBC), from a known table and mass motion sampled at the rig's rates."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import can
import numpy as np
import pytest

from analysis.identify.foreign import parse_channels
from analysis.identify.loading import load_runs
from rig.cli import main as rig_main
from rig.config import load_config
from rig.errors import DataError
from rig.geometry import ActuatorPlan
from rig.paths import data_file
from rig.run.schedule import run_messages
from rig.runfile import open_run
from rig.units import INCH, POUND_MASS
from rig.wire import can_messages as cm
from rig.wire.can_messages import Feedback, Heartbeat, MassSample, NodeState, TableSample

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

T0 = 1_700_000_000.0  # Unix s of the log's first frame
RESOLUTION = 1e-6  # m per count, both sensors (data/rig.toml)
N_SENSOR = 1200  # samples at 1 kHz: 1.2 s
TABLE_LAT, MASS_LAT, JITTER = 200e-6, 300e-6, 40e-6  # s, bus and sensor latency
MASS_PHASE = 0.5e-3  # s: the mass sensor samples half a period after the table's
START_T = 0.06  # s: START on the bus
PAYLOAD_KG = 6000 * POUND_MASS  # data/rig.toml
FORMATS = ("blf", "asc", "trc", "csv", "mf4")
MASS_DBC_LINES = """
BO_ 337 MassSensor: 8 MASS_SENSOR
 SG_ Counts : 0|24@1- (1,0) [-8388608|8388607] "count" RIG
 SG_ Sequence : 24|8@1+ (1,0) [0|255] "" RIG
 SG_ TimestampUs : 32|32@1+ (1,0) [0|4294967295] "us" RIG
"""


def pulse(t: np.ndarray, at: float, height: float) -> np.ndarray:
    """A step pulse: min-jerk up over 0.12 s from `at`, hold 0.3 s, min-jerk back."""
    def up(s: np.ndarray) -> np.ndarray:
        s = np.clip(s / 0.12, 0.0, 1.0)
        return s**3 * (10 - 15 * s + 6 * s**2)
    return height * (up(t - at) - up(t - at - 0.42))


def table_u(t: np.ndarray) -> np.ndarray:
    return pulse(t, 0.2, 2.0 * INCH)


def mass_x(t: np.ndarray) -> np.ndarray:
    return pulse(t, 0.23, 1.7 * INCH)


def counts(v: np.ndarray) -> np.ndarray:
    return np.rint(v / RESOLUTION).astype(int)


class Truth:
    """Sample instants, counts and the arrival-time placement the rig can make of them."""

    k = np.arange(N_SENSOR)
    t_table = k * 1e-3
    t_mass = k * 1e-3 + MASS_PHASE
    u_counts = counts(table_u(t_table))
    x_counts = counts(mass_x(t_mass))


def _plan() -> ActuatorPlan:
    t = np.arange(0, 1.0 + 1e-9, 1 / 400)
    ext = np.outer(table_u(t), [1, 1, -1, -1, 0, 0])
    ext = np.round(ext, 6)
    zero = np.zeros_like(ext)
    return ActuatorPlan("pulse", 400.0, t, ext, zero, zero, zero)


def bus_frames(db) -> list[can.Message]:
    """The bus of a step-pulse run, as a logger on it would see it, in time order."""
    rng = np.random.default_rng(7)
    out: list[tuple[float, object]] = []
    for k in Truth.k:  # sensors: their own device clocks (+3 s, +7 s), some latency
        out.append((Truth.t_table[k] + TABLE_LAT + rng.uniform(0, JITTER),
                    TableSample(int(Truth.u_counts[k]), int(k), 3_000_000 + int(k) * 1000)))
        out.append((Truth.t_mass[k] + MASS_LAT + rng.uniform(0, JITTER),
                    MassSample(int(Truth.x_counts[k]), int(k), 7_000_000 + int(k) * 1000)))
    for i in range(1, 7):
        for k in range(120):  # feedback at 100 Hz, servo tick at 400 Hz
            out.append((k * 0.01 + 1e-3 + i * 1e-5, Feedback(i, 4 * k, 0.0, NodeState.RUNNING)))
    for node in cm.NODES:
        for k in range(12):
            out.append((k * 0.1 + (node - 1) * 1e-5, Heartbeat(node, k, NodeState.RUNNING)))
    for timed in run_messages(_plan()):
        out.append((START_T + timed.due, timed.message))
    out.sort(key=lambda item: item[0])
    first = out[0][0]
    return [can.Message(timestamp=float(T0 + t - first), arbitration_id=fid, data=data,
                        is_extended_id=False, channel=0)
            for t, m in out for fid, data in [cm.encode(m, db)]]


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    """A bench DBC (the rig's plus a MassSensor), its frames, and a log of each format."""
    d = tmp_path_factory.mktemp("bench")
    dbc = d / "bench.dbc"
    text = data_file("isolator_rig.dbc").read_text()
    text = text.replace("\nBO_ 513 ", MASS_DBC_LINES + "\nBO_ 513 ", 1)
    dbc.write_text(text.replace("TABLE_SENSOR\n", "TABLE_SENSOR MASS_SENSOR\n", 1))
    db = cm.bench_database(dbc)
    frames = bus_frames(db)
    logs = {}
    for fmt in FORMATS:
        logs[fmt] = d / f"run.{fmt}"
        with can.Logger(logs[fmt]) as writer:
            for msg in frames:
                writer.on_message_received(msg)
    return dbc, db, frames, logs


def _one_error_line(capsys, *names: str) -> str:
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert err.startswith(("rig: error: ", "analysis: error: ")), err
    for name in names:
        assert name in err, err
    return err


@pytest.mark.parametrize("fmt", FORMATS)
def test_import_decodes_each_log_format_as_a_live_run(bench, fmt, tmp_path, capsys) -> None:
    dbc, _, frames, logs = bench
    out = tmp_path / f"{fmt}.h5"
    assert rig_main(["import", str(logs[fmt]), "--dbc", str(dbc), "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert f"{len(frames):,} CAN frames" in said and "table_u 1,200 samples" in said
    run = open_run(out)
    assert run.status.state == "success" and run.status.complete
    assert run.meta["backend"] == "import"
    assert str(run.meta["start_time"]).startswith("2023-11-14T22:13:20")
    assert len(run.can.time) == len(frames)
    assert np.array_equal(run.can.arbitration_id, [m.arbitration_id for m in frames])
    # the sensors: every sample, its value to the count, placed on its sampling instant
    # (plus the least latency the rig could see)
    for name, t_true, c_true, lat in (("table_u", Truth.t_table, Truth.u_counts, TABLE_LAT),
                                      ("mass_x", Truth.t_mass, Truth.x_counts, MASS_LAT)):
        ch = run.channels[name]
        assert ch.source.startswith(f"import:{logs[fmt]} can:0x1"), ch.source
        assert ch.units == "m" and ch.value.size == N_SENSOR
        assert np.max(np.abs(ch.value - c_true * RESOLUTION)) <= RESOLUTION / 2
        assert np.max(np.abs(ch.time - (t_true + lat))) < 10e-6, name
    # setpoints at START + index / rate, as `rig run` writes the ones it sends
    plan = _plan()
    sp = run.channels["actuator_setpoint_3"]
    assert sp.value.size == plan.t.size
    start = run.channels["actuator_setpoint_1"].time[0]
    assert abs(start - START_T) < 2e-6
    assert np.allclose(sp.time, START_T + plan.t, atol=2e-6)
    assert np.max(np.abs(sp.value - plan.extension[:, 2])) <= RESOLUTION / 2
    assert run.channels["actuator_feedback_6"].value.size == 120
    assert all(v == 0 for v in run.counters["can"].values())
    if fmt == "blf":  # the file loads for the fit, with the payload mass of its config
        loaded = load_runs([out])
        r = loaded.runs[0]
        assert r.mass == pytest.approx(PAYLOAD_KG)
        _, u_own = r.table_samples
        assert np.max(np.abs(u_own - Truth.u_counts * RESOLUTION)) < 1e-9
        k = np.rint((r.t - (MASS_PHASE + MASS_LAT)) / 1e-3).astype(int)
        assert np.max(np.abs(r.x - Truth.x_counts[k] * RESOLUTION)) < 1e-9


def test_import_with_the_rigs_own_dbc_has_no_mass_and_is_refused(bench, tmp_path,
                                                                   capsys) -> None:
    _, _, _, logs = bench
    out = tmp_path / "run.h5"
    code = rig_main(["import", str(logs["asc"]), "--dbc", str(data_file("isolator_rig.dbc")),
                     "--out", str(out)])
    assert code == 2
    err = _one_error_line(capsys, str(logs["asc"]), "cannot make mass_x", "no MassSensor",
                          "found table_u (1200 samples), actuator_setpoint_* (6 actuators)")
    assert "serial port" in err
    assert not out.exists()


def test_bad_logs_are_one_line_exit_2_and_leave_no_file(bench, tmp_path, capsys) -> None:
    dbc = str(bench[0])
    corrupt = tmp_path / "corrupt.blf"
    corrupt.write_bytes(bench[3]["blf"].read_bytes()[:40] + b"\xff" * 500)
    torn = tmp_path / "torn.mf4"
    torn.write_bytes(bench[3]["mf4"].read_bytes()[:300])
    foreign = tmp_path / "other_bus.csv"
    with can.Logger(foreign) as w:
        for k in range(50):
            w.on_message_received(can.Message(timestamp=T0 + k * 1e-3, arbitration_id=0x3A0,
                                              data=bytes(8), is_extended_id=False))
    unknown = tmp_path / "run.xyz"
    unknown.write_text("x")
    cases = ((corrupt, "not a readable Vector BLF file"),
             (torn, "not a readable ASAM MDF 4 bus logging file"),
             (foreign, "none of its 50 frames decodes as a message of the DBC (ids 0x3A0)"),
             (unknown, "not a CAN log rig import reads"),
             (tmp_path / "missing.blf", "no such file"))
    for log, why in cases:
        out = tmp_path / f"{log.stem}.h5"
        assert rig_main(["import", str(log), "--dbc", dbc, "--out", str(out)]) == 2
        _one_error_line(capsys, str(log), why)
        assert not out.exists()


def test_a_dbc_that_changes_a_rig_message_is_refused(bench, tmp_path, capsys) -> None:
    changed = tmp_path / "changed.dbc"
    text = bench[0].read_text()
    changed.write_text(text.replace(" SG_ Counts : 0|24@1- (1,0)",
                                    " SG_ Counts : 0|24@1- (2,0)", 1))
    assert rig_main(["import", str(bench[3]["csv"]), "--dbc", str(changed),
                     "--out", str(tmp_path / "run.h5")]) == 2
    _one_error_line(capsys, str(changed), "TableSensor differs from the rig's DBC")


def test_import_refuses_to_overwrite_and_keeps_the_file(bench, tmp_path, capsys) -> None:
    out = tmp_path / "there.h5"
    out.write_bytes(b"keep me")
    assert rig_main(["import", str(bench[3]["csv"]), "--dbc", str(bench[0]),
                     "--out", str(out)]) == 2
    _one_error_line(capsys, str(out))
    assert out.read_bytes() == b"keep me"


# --- MDF 4 and TDMS straight into the fit ---------------------------------------------------

def _known(n: int = 600, dt: float = 1e-3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = 0.05 + dt * np.arange(n)
    return t, table_u(t), mass_x(t)


def _write_mdf(path: Path, names=("u", "x"), units=("in", "in")) -> None:
    from asammdf import MDF, Signal
    t, u, x = _known()
    with MDF(version="4.10") as mdf:
        mdf.append([Signal(u / INCH, t, name=names[0], unit=units[0]),
                    Signal(x / INCH, t, name=names[1], unit=units[1])], comment="bench")
        mdf.save(path, overwrite=True)


def _write_tdms(path: Path, names=("u", "x"), units=("in", "in"), group="Run 1",
                timing=True) -> None:
    from nptdms import ChannelObject, GroupObject, TdmsWriter
    t, u, x = _known()
    wf = {"wf_increment": 1e-3, "wf_start_offset": float(t[0])} if timing else {}
    with TdmsWriter(path) as w:
        w.write_segment([GroupObject(group)] + [
            ChannelObject(group, name, v / INCH, properties={"unit_string": unit, **wf})
            for name, v, unit in zip(names, (u, x), units)])


def test_mdf_and_tdms_in_inches_load_as_the_known_motion_in_metres(tmp_path) -> None:
    mdf, tdms = tmp_path / "bench.mf4", tmp_path / "labview.tdms"
    _write_mdf(mdf)
    _write_tdms(tdms)
    t, u, x = _known()
    loaded = load_runs([mdf, tdms], mass=PAYLOAD_KG)
    assert [r.name for r in loaded.runs] == ["bench", "labview"]
    for r in loaded.runs:
        assert r.t.size == t.size and np.allclose(r.t, t, atol=1e-9, rtol=0)
        assert np.max(np.abs(r.u - u)) < 1e-12 and np.max(np.abs(r.x - x)) < 1e-12
    assert np.ptp(loaded.runs[0].u) == pytest.approx(2.0 * INCH, rel=1e-6)


def test_channel_names_and_units_from_the_caller(tmp_path) -> None:
    mdf, tdms = tmp_path / "named.mf4", tmp_path / "named.tdms"
    _write_mdf(mdf, names=("TableDisp", "MassDisp"), units=("", ""))
    _write_tdms(tdms, names=("TableDisp", "MassDisp"), units=("mm", "mm"), timing=False)
    channels = parse_channels("TableDisp, MassDisp")
    assert channels == ("TableDisp", "MassDisp")
    _, u, _ = _known()
    r = load_runs([mdf], mass=PAYLOAD_KG, units="in", channels=channels).runs[0]
    assert np.max(np.abs(r.u - u)) < 1e-12
    with pytest.raises(DataError, match=r"named.mf4: no channels u and x .*TableDisp"):
        load_runs([mdf], mass=PAYLOAD_KG)
    with pytest.raises(DataError, match=r"named.tdms: channel 'TableDisp' has no time"):
        load_runs([tdms], mass=PAYLOAD_KG, channels=channels)


def test_bad_measurement_files_are_one_line_exit_2(tmp_path, capsys) -> None:
    from analysis.cli import main as analysis_main
    furlong, missing, torn = (tmp_path / "furlong.tdms", tmp_path / "other.tdms",
                              tmp_path / "torn.mf4")
    _write_tdms(furlong, units=("furlong", "in"))
    _write_tdms(missing, names=("a", "b"))
    _write_mdf(torn)
    torn.write_bytes(torn.read_bytes()[:200])
    cases = ((furlong, "channel 'u' in 'furlong', an unknown unit"),
             (missing, "no channels u and x"),
             (torn, "not a readable MDF file"))
    for path, why in cases:
        with pytest.raises(DataError, match=why):
            load_runs([path], mass=PAYLOAD_KG)
        assert analysis_main(["fit", str(path), "--mass", "2721"]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and why in err and str(path) in err, err
    lb = tmp_path / "force.tdms"
    _write_tdms(lb, units=("lb", "lb"))
    with pytest.raises(DataError, match="in 'lb', not a length"):
        load_runs([lb], mass=PAYLOAD_KG)


# --- rig export --mdf ---------------------------------------------------------------------

def test_export_mdf_round_trip_and_back_into_the_fit(bench, tmp_path, capsys) -> None:
    from asammdf import MDF
    dbc, _, _, logs = bench
    run_h5, mf4 = tmp_path / "run.h5", tmp_path / "run.mf4"
    assert rig_main(["import", str(logs["trc"]), "--dbc", str(dbc), "--out", str(run_h5)]) == 0
    assert rig_main(["export", str(run_h5), "--mdf", str(mf4)]) == 0
    assert "MDF 4.10" in capsys.readouterr().out
    run = open_run(run_h5, raw=False)
    with MDF(mf4) as mdf:
        assert mdf.header.start_time.timestamp() == pytest.approx(T0, abs=1e-3)
        for name in ("table_u", "mass_x", "actuator_setpoint_1", "actuator_status_2"):
            sig, ch = mdf.get(name), run.channels[name]
            assert sig.unit == ch.units
            assert np.array_equal(sig.samples, ch.value)
            assert np.array_equal(sig.timestamps, ch.time)
            assert ch.source in sig.comment
    loaded = load_runs([mf4], mass=PAYLOAD_KG)  # table_u and mass_x, each its own clock
    assert any("their own times" in w for w in loaded.warnings)
    r = loaded.runs[0]
    k = np.rint((r.t - (MASS_PHASE + MASS_LAT)) / 1e-3).astype(int)
    assert np.max(np.abs(r.x - Truth.x_counts[k] * RESOLUTION)) < 1e-9
    assert rig_main(["export", str(run_h5), "--mdf", str(mf4)]) == 2  # never overwritten
    _one_error_line(capsys, str(mf4), "already exists")


def test_rig_import_refusal_as_a_real_process(bench, tmp_path) -> None:
    out = tmp_path / "run.h5"
    proc = subprocess.run(
        [sys.executable, "-m", "rig.cli", "import", str(bench[3]["blf"]), "--out", str(out)],
        capture_output=True, text=True, timeout=120, check=False,
        cwd=Path(__file__).resolve().parents[1])
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1 and "cannot make mass_x" in proc.stderr
    assert not out.exists()


def test_load_config_payload_is_the_one_the_tests_assume() -> None:
    assert load_config().table.payload_mass == pytest.approx(PAYLOAD_KG)
