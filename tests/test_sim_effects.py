"""Undeclared effects of the simulated rig: each changes what is measured, none is recorded."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from analysis.model.report_constants import report_model
from rig.errors import ConfigError
from sim.effects import EFFECTS, Effect, parse_effect, with_effects
from sim.generate import SENSOR_NOISE, generate_campaign, write_run_csv

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

LOOP_NAMES = {"coulomb_friction", "asymmetric_damping", "quadratic_damping", "cubic_stiffness",
              "asymmetric_stiffness", "preload", "force_offset", "thermal_damping_drift",
              "hysteresis", "sensor_delay", "sensor_gain"}

# a magnitude for each that moves the mass by well over the sensor noise
MAGNITUDE = {"coulomb_friction": 300.0, "asymmetric_damping": 3000.0, "quadratic_damping": 800.0,
             "cubic_stiffness": 1e6, "asymmetric_stiffness": 2e4, "preload": 300.0,
             "force_offset": 200.0, "thermal_damping_drift": -400.0, "hysteresis": 2e4,
             "sensor_delay": 0.004, "sensor_gain": 0.02}


@pytest.fixture(scope="module")
def clean():
    return generate_campaign(noise=0.0)


def test_the_catalogue_is_the_loops_list():
    assert set(EFFECTS) == LOOP_NAMES
    assert set(MAGNITUDE) == LOOP_NAMES


def test_parse_effect_reads_value_and_shape():
    e = parse_effect("thermal_damping_drift=-300,1.5,120")
    assert e == Effect("thermal_damping_drift", -300.0, (1.5, 120.0, 0.0))  # no θ_max
    assert parse_effect("thermal_damping_drift=-300,1.5,120,0.2").shape == (1.5, 120.0, 0.2)
    assert parse_effect("hysteresis=2e4").shape == (60.0, 20.0, 1.0)  # the defaults
    assert parse_effect(" coulomb_friction=150").value == 150.0


@pytest.mark.parametrize("spec,message", [
    ("stiction=3", "unknown effect"),
    ("coulomb_friction", "needs a magnitude in N"),
    ("coulomb_friction=abc", "not a number"),
    ("coulomb_friction=nan", "must be finite"),
    ("hysteresis=1,2", "takes 3 shape constants"),
])
def test_bad_effect_specs_are_named(spec, message):
    with pytest.raises(ConfigError, match=message):
        parse_effect(spec)


def test_an_effect_on_a_term_the_model_has_adds_to_it():
    m = with_effects(report_model("average"), (Effect("coulomb_friction", 120.0),
                                               Effect("coulomb_friction", 30.0)))
    assert m.parameters()["c3"] == pytest.approx(150.0)
    assert [t.name for t in m.terms].count("c3") == 1


@pytest.mark.parametrize("name", sorted(LOOP_NAMES))
def test_each_effect_changes_the_measurement_beyond_the_noise(name, clean):
    runs = generate_campaign(effects=[Effect(name, MAGNITUDE[name],
                                             EFFECTS[name].shape_defaults)], noise=0.0)
    moved = max(np.abs(r.x - c.x).max() for r, c in zip(runs, clean))
    assert moved > 20 * SENSOR_NOISE
    for r, c in zip(runs, clean):  # the table is driven the same: only the isolator differs
        np.testing.assert_array_equal(r.u, c.u)
    sensor_only = not EFFECTS[name].term_kind
    truth_moved = max(np.abs(r.x_true - c.x_true).max() for r, c in zip(runs, clean))
    assert (truth_moved == 0.0) == sensor_only


def test_heat_carries_from_run_to_run(clean):
    """The fluid warms over the campaign, so the later runs depart more (the report's run C)."""
    runs = generate_campaign(effects=[parse_effect("thermal_damping_drift=-400")], noise=0.0)
    departure = [np.abs(r.x - c.x).max() for r, c in zip(runs, clean)]
    assert departure[0] < departure[1] < departure[2]


def test_sensor_delay_is_the_lag_of_the_mass_channel(clean):
    runs = generate_campaign(effects=[parse_effect("sensor_delay=0.005")], noise=0.0)
    r, c = runs[0], clean[0]
    lags = np.arange(0, 12)
    err = [np.abs(r.x[k:] - c.x[:len(c.x) - k]).max() for k in lags]
    assert int(lags[int(np.argmin(err))]) == 5  # 5 ms at 1 kHz
    assert min(err) < 1e-6


def test_noise_and_resolution_are_the_sensors(clean):
    runs = generate_campaign(noise=SENSOR_NOISE, seed=4)
    e = runs[0].x - clean[0].x
    assert np.std(e) == pytest.approx(SENSOR_NOISE, rel=0.05)
    counts = runs[0].u / 1e-6
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)


@pytest.mark.parametrize("units,scale", [("m", 1.0), ("in", 1 / 0.0254)])
def test_csv_holds_only_what_a_rig_logs(tmp_path, units, scale):
    run = generate_campaign(runs=("C",), effects=[parse_effect("coulomb_friction=300")])[0]
    path = tmp_path / "C.csv"
    write_run_csv(run, path, units)
    text = path.read_text()
    assert "coulomb" not in text and "c3" not in text
    rows = list(csv.reader(text.splitlines()))
    assert rows[0] == ["t [s]", f"u [{units}]", f"x [{units}]"]  # the units, not a guess
    data = np.array(rows[1:], float)
    np.testing.assert_allclose(data[:, 0], run.t, atol=1e-6)
    np.testing.assert_allclose(data[:, 1], run.u * scale, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(data[:, 2], run.x * scale, rtol=1e-8, atol=1e-12)


def test_generate_cli_writes_one_csv_per_run(tmp_path, capsys):
    from sim.cli import main

    assert main(["generate", "--profile", "A", "C", "--effect", "quadratic_damping=800",
                 "--units", "si", "--noise", "2.54e-5", "--out", str(tmp_path)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["A.csv", "C.csv"]
    out = capsys.readouterr()
    assert "run C: 3001 samples, 3.00 s at 1000 Hz" in out.out
    assert "not recorded" in out.err
    assert main(["generate", "--effect", "stiction=1", "--out", str(tmp_path)]) == 2
    assert "unknown effect" in capsys.readouterr().err


def test_a_friction_built_up_over_v_s_is_injected_with_its_shape():
    """`coulomb_friction=F,v_s`: the seals' friction builds up over v_s (m/s); without it
    the report's step."""
    assert parse_effect("coulomb_friction=150").shape == (0.0,)
    e = parse_effect("coulomb_friction=150,0.004")
    assert e.shape == (0.004,)
    m = with_effects(report_model("average"), (e,))  # onto the report's c3 at zero
    assert m.parameters()["c3"] == pytest.approx(150.0)
    assert m.parameters()["c3.v_s"] == 0.004


def test_a_hysteresis_spec_without_its_exponent_has_n_1():
    """`hysteresis=VALUE,a,b` as written before the Bouc–Wen exponent existed."""
    assert parse_effect("hysteresis=2e4,60,20").shape == (60.0, 20.0, 1.0)
