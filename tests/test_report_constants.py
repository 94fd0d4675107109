"""Table 1 as data: SI on load, back to the report's units exactly."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from analysis.model.report_constants import (
    NAMES,
    RUNS,
    format_table1,
    load_table1,
    report_model,
    si_unit,
)
from rig.paths import data_file
from rig.units import from_si, to_si

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)


def test_table1_round_trip_us_si_us():
    raw = tomllib.loads(data_file("table1.toml").read_text())
    table = load_table1()
    for run in RUNS:
        for name in NAMES:
            us = raw["runs"][run][name]
            si = table.runs[run][name]
            assert from_si(si, raw["units"][name]) == pytest.approx(us, rel=1e-12, abs=1e-12)
            assert to_si(from_si(si, raw["units"][name]), raw["units"][name]) == pytest.approx(si)


def test_known_conversions():
    t = load_table1().runs["average"]
    assert t["k1"] == pytest.approx(405 * 4.4482216152605 / 0.0254)  # 70 926 N/m
    assert t["delta"] == pytest.approx(0.019558)  # the report's 0.0196 m
    assert t["epsilon"] == pytest.approx(0.01524)  # the report's 0.0152 m/s
    assert t["F_break"] == pytest.approx(91.63, abs=0.01)  # the report's 91.6 N
    assert t["alpha"] == pytest.approx(2 / 0.0254)
    assert load_table1().mass == pytest.approx(2721.554, abs=1e-3)  # 6000 lb


def test_printed_table_in_both_unit_systems():
    us, si = format_table1("us"), format_table1("si")
    assert "lb/in" in us and "405" in us and "0.77" in us
    assert "N/m" in si and "7.093e+04" in si
    assert "6000 lbm" in us and "2721.55 kg" in si
    with pytest.raises(ValueError):
        format_table1("imperial")


@pytest.mark.parametrize("run", RUNS)
def test_report_model_carries_every_constant(run):
    m = report_model(run)
    p = m.parameters()
    for name in ("k1", "k2", "c1", "c2", "c3", "alpha", "beta", "gamma"):
        assert p[name] == pytest.approx(load_table1().runs[run][name])
    assert m.dead_band == pytest.approx(load_table1().runs[run]["delta"])
    units = m.units()
    assert units["k1"] == si_unit("k1") and units["beta"] == si_unit("beta")


def test_parameter_vector_layout_round_trips(average_model):
    m = average_model
    v, idx = m.vector(), m.vector_index()
    for name, value in m.parameters().items():
        assert v[idx[name]] == value
    changed = m.with_parameters(k1=1.0, beta=3.0, delta=0.0)
    assert changed.parameters()["k1"] == 1.0 and changed.term("c2").shape == (3.0,)
    assert changed.dead_band == 0.0 and m.dead_band > 0  # the original is untouched
    with pytest.raises(KeyError, match="unknown parameters"):
        m.with_parameters(k9=1.0)
    assert np.all(np.isfinite(v))
