"""Step-pulse profiles: the report's runs, the ramp shape and TOML errors."""

from __future__ import annotations

import numpy as np
import pytest

from rig.errors import ConfigError
from rig.profile import load_profile, parse_profile

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

INCH = 0.0254


@pytest.mark.parametrize("run,sign,rise", [("A", 1, 0.20), ("B", -1, 0.20), ("C", 1, 0.12)])
def test_report_runs(run, sign, rise):
    p = load_profile(run)
    assert p.duration == pytest.approx(3.0)
    t = np.arange(0, 3.0001, 1e-4)
    u, v, a = p.sample(t)
    assert (u.max() if sign > 0 else -u.min()) == pytest.approx(5.5 * INCH)
    assert np.abs(u).max() == pytest.approx(5.5 * INCH)
    assert u[0] == 0 and abs(u[-1]) < 1e-15  # starts and ends at the origin
    # the rise: from rest at 0.10 s to the full step at 0.10 s + rise, no earlier
    assert np.abs(u[t <= 0.1]).max() == 0
    reach = t[np.argmax(np.abs(u) >= 5.5 * INCH * (1 - 1e-9))]
    assert reach == pytest.approx(0.1 + rise, abs=2e-4)
    peaks = p.peaks()
    assert np.abs(v).max() == pytest.approx(peaks["velocity"], rel=1e-4)
    assert np.abs(a).max() == pytest.approx(peaks["acceleration"], rel=1e-3)


def test_ramp_is_minimum_jerk_with_continuous_acceleration():
    p = load_profile("A")
    m = p.motion()
    for b in m.x[1:-1]:  # velocity and acceleration are continuous at every break
        for d in (1, 2):
            assert m(b - 1e-12, d) == pytest.approx(m(b + 1e-12, d), abs=1e-6)
    assert m(0.2, 0) == pytest.approx(5.5 * INCH / 2)  # symmetric about mid-rise
    # the fastest ramp is the 0.12 s return: 1.875 Δ/T and 5.774 Δ/T²
    assert p.peaks()["velocity"] == pytest.approx(1.875 * 5.5 * INCH / 0.12)
    assert p.peaks()["acceleration"] == pytest.approx(5.7735 * 5.5 * INCH / 0.12**2, rel=1e-4)


def parse(text: str):
    import tomllib
    return parse_profile(tomllib.loads(text), "p.toml")


def test_custom_profile_in_metres():
    p = parse('units = "m"\n[[segment]]\nramp_to = 0.05\nduration = 0.5\n[[segment]]\nhold = 1\n')
    assert p.duration == 1.5 and p.peaks()["displacement"] == 0.05


@pytest.mark.parametrize("text,field", [
    ('units = "furlong"\n[[segment]]\nhold = 1\n', "units"),
    ('units = "lb"\n[[segment]]\nhold = 1\n', "units"),
    ("x = 1\n", "segment"),
    ("[[segment]]\nhold = -1\n", "segment 1.hold"),
    ("[[segment]]\nhold = 1\n[[segment]]\nramp_to = 1\n", "segment 2.duration"),
    ("[[segment]]\nramp_to = 'far'\nduration = 1\n", "segment 1.ramp_to"),
    ("[[segment]]\nramp_to = nan\nduration = 1\n", "segment 1.ramp_to"),
    ("[[segment]]\nspeed = 3\n", "segment 1"),
    ("[[segment]]\nhold = 1\nramp_to = 2\n", "segment 1"),
])
def test_bad_profiles_name_the_field(text, field):
    with pytest.raises(ConfigError) as e:
        parse(text)
    assert e.value.field == field
    assert str(e.value).startswith("p.toml: ")


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(ConfigError, match="no such profile"):
        load_profile(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[[segment]\nhold=")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_profile(bad)
    binary = tmp_path / "bin.toml"
    binary.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(ConfigError, match="cannot read|not valid"):
        load_profile(binary)
