"""analysis.identify.loading: the staircase warning, and the grid laid on the mass sensor."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from analysis.identify import loading
from analysis.identify.synthetic import synthetic_run
from analysis.model.report_constants import report_model

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

MASS = report_model("average").mass
WARNING = "faster than any isolator test"


def write_csv(path: Path, t, u, x) -> Path:
    np.savetxt(path, np.c_[t, u, x], delimiter=",", header="t,u,x", comments="")
    return path


@pytest.fixture(scope="module")
def run_c():
    return synthetic_run(report_model("average"), "C", seed=1)  # the fastest: 2.2 m/s


def test_clean_data_gives_no_warning(tmp_path, run_c):
    loaded = loading.load_runs([write_csv(tmp_path / "C.csv", run_c.t, run_c.u, run_c.x)],
                               MASS)
    assert not [w for w in loaded.warnings if WARNING in w]


def test_a_sensor_holding_its_last_value_is_flagged_and_the_data_still_used(tmp_path, run_c):
    """A sensor that repeats its value between updates every 25 ms (a starved sender):
    the table moves 2.2 m/s, so each riser is a jump of ~50 mm within 1 ms."""
    held = run_c.u[(np.arange(run_c.u.size) // 25) * 25]
    path = write_csv(tmp_path / "stairs.csv", run_c.t, held, run_c.x)
    loaded = loading.load_runs([path], MASS)
    found = [w for w in loaded.warnings if WARNING in w]
    assert len(found) == 1 and "\n" not in found[0]
    assert f"{path}: u jumps" in found[0] and "m/s" in found[0]
    assert np.array_equal(loaded.runs[0].u, held)  # a warning, not a refusal


def test_a_slow_staircase_within_the_speeds_of_a_test_is_not_flagged(tmp_path, run_c):
    """Holding for 2 samples at 2.2 m/s makes 4.4 mm risers in 1 ms: 4.4 m/s, under the
    5 m/s no test reaches; the rule is about speeds, not about the look of the data."""
    held = run_c.u[(np.arange(run_c.u.size) // 2) * 2]
    loaded = loading.load_runs([write_csv(tmp_path / "s2.csv", run_c.t, held, run_c.x)], MASS)
    assert not [w for w in loaded.warnings if WARNING in w]


def _channel(name, time, value):
    return SimpleNamespace(name=name, time=np.asarray(time, float),
                           value=np.asarray(value, float), units="m")


def fake_runfile(monkeypatch, tmp_path, table, mass) -> Path:
    run = SimpleNamespace(status=SimpleNamespace(complete=True, state="success", reason=""),
                          channels={"table_u": table, "mass_x": mass}, gaps=[])
    monkeypatch.setattr(loading, "check_readable", lambda path, reader: None)
    monkeypatch.setattr(loading, "_read_channels", lambda path: run)
    path = tmp_path / "run.h5"
    path.write_bytes(b"")
    return path


def test_run_file_grid_lies_on_the_mass_samples(monkeypatch, tmp_path):
    """Table sensor from t = 0, mass sensor from 0.4 ms, both 1 kHz: the grid is the
    mass sensor's instants, x exactly as sampled, u interpolated between its samples."""
    rng = np.random.default_rng(0)
    tu = 1e-3 * np.arange(1000)
    tx = 4e-4 + 1e-3 * np.arange(999)
    u = 1e-3 * np.sin(tu) + 2.54e-5 * rng.standard_normal(tu.size)
    x = 2.54e-5 * rng.standard_normal(tx.size)
    path = fake_runfile(monkeypatch, tmp_path, _channel("table_u", tu, u),
                        _channel("mass_x", tx, x))
    run = loading.load_runs([path], MASS).runs[0]
    assert run.t[0] == pytest.approx(tx[0], abs=1e-12)
    assert np.allclose(run.x, x[:run.t.size], rtol=0, atol=1e-15)
    assert np.allclose(run.u, np.interp(run.t, tu, u))


def test_a_run_file_channel_with_a_staircase_is_flagged(monkeypatch, tmp_path):
    t = 1e-3 * np.arange(1000)
    ramp = np.clip((t - 0.3) * 1.5, 0, 0.14)  # 1.5 m/s, held for 20 samples at a time
    stairs = ramp[(np.arange(t.size) // 20) * 20]
    path = fake_runfile(monkeypatch, tmp_path, _channel("table_u", t, ramp),
                        _channel("mass_x", t, stairs))
    found = [w for w in loading.load_runs([path], MASS).warnings if WARNING in w]
    assert len(found) == 1 and "mass_x jumps" in found[0]


def test_channel_times_go_on_the_final_clock_fit():
    """The rig writes a sample on its clock fit as that stood half a second after the
    sample arrived, the last half second on the final fit: the times step where the fit
    moved (here 60 µs, then 20 µs; µs rounding as the device stamps have). Re-placed,
    every sample lies on the final fit's line, missing samples keeping their slot."""
    rng = np.random.default_rng(1)
    k = np.delete(np.arange(3000), [1200, 1201])  # two samples lost
    final = 0.25 + 1.00002e-3 * k
    logged = final + np.where(k < 1000, 60e-6, np.where(k < 2400, -20e-6, 0.0))
    logged += rng.uniform(-0.5e-6, 0.5e-6, k.size)
    placed = loading._final_fit_times(logged)
    assert np.abs(placed - final).max() < 0.2e-6
    # a clock that does not keep one rate (wandering by half a sample) is left as written
    wander = 1e-3 * k + 0.5e-3 * np.sin(k / 300.0)
    assert np.array_equal(loading._final_fit_times(wander), wander)
