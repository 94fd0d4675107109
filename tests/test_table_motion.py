"""The table's motion estimated from its noisy sensor: errors in variables."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from analysis.identify.table_motion import estimate_table_motion
from sim.generate import SENSOR_NOISE, generate_campaign

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)


@pytest.fixture(scope="module")
def campaign():
    return generate_campaign(seed=11)


@pytest.mark.parametrize("k", [0, 1, 2])
def test_step_pulse_fit_recovers_the_input_below_the_noise(campaign, k):
    run = campaign[k]
    est = estimate_table_motion(run.t, run.u)
    assert est.method == "step-pulse fit"
    # what is left is the sensor's noise (accept rule: RMS within 10 % of σ)
    assert est.residual_over_noise == pytest.approx(1.0, abs=0.1)
    assert est.sigma == pytest.approx(SENSOR_NOISE, rel=0.1)
    # many samples per ramp parameter: the estimate is far better than one sample
    err = est.motion(run.t) - run.u_true
    assert np.sqrt(np.mean(err**2)) < 0.2 * SENSOR_NOISE
    assert np.abs(err).max() < 0.8 * SENSOR_NOISE


def test_motion_that_is_not_a_step_pulse_falls_back_to_the_spline():
    """A table that rings on a resonant servo (15 Hz, ζ = 0.3, 4 % overshoot) follows
    no minimum-jerk profile, with or without a lag. (A first-order lag alone is a
    step-pulse fit now: tests/test_servo_lag.py.)"""
    run = generate_campaign(runs=("C",), seed=3, noise=0.0)[0]
    wn = 2 * np.pi * 15.0
    _, ringing, _ = signal.lsim(signal.lti([wn**2], [1, 0.6 * wn, wn**2]), run.u_true, run.t)
    rng = np.random.default_rng(0)
    est = estimate_table_motion(run.t, ringing + rng.normal(0, SENSOR_NOISE, ringing.size))
    assert est.method == "smoothing spline"
    assert np.abs(est.motion(run.t) - ringing).max() < 10 * SENSOR_NOISE


def _other_rig_ramps(law, t, noise, seed):
    """Rest, 0.14 m up in 0.2 s, rest, back in 0.12 s, rest: the motion laws written out
    here, not taken from the module under test."""
    def ramp(tau):
        tau = np.clip(tau, 0.0, 1.0)
        return {"cycloidal": tau - np.sin(2 * np.pi * tau) / (2 * np.pi),
                "harmonic": 0.5 - 0.5 * np.cos(np.pi * tau),
                "parabolic": np.where(tau < 0.5, 2 * tau**2, 1 - 2 * (1 - tau) ** 2),
                "minimum-jerk": 10 * tau**3 - 15 * tau**4 + 6 * tau**5}[law]
    true = 0.01 + 0.14 * ramp((t - 0.3) / 0.2) - 0.14 * ramp((t - 1.6) / 0.12)
    return true, true + np.random.default_rng(seed).normal(0.0, noise, t.size)


@pytest.mark.parametrize("law", ["cycloidal", "harmonic", "parabolic", "minimum-jerk"])
@pytest.mark.parametrize("seed", [1, 2])
def test_other_rigs_motion_laws_are_fitted_not_smoothed(law, seed):
    """Another rig's controller ramps by another standard motion law: the fit names it
    and estimates the input well below the noise, where the spline would leave the
    isolator model several times the noise from the data (module docstring)."""
    t = np.arange(0, 2.5, 1e-3)
    noise = 25e-6
    true, u = _other_rig_ramps(law, t, noise, seed)
    est = estimate_table_motion(t, u)
    assert (est.method, est.shape, est.lag) == ("step-pulse fit", law, 0.0)
    assert est.residual_over_noise == pytest.approx(1.0, abs=0.1)
    err = est.motion(t) - true
    assert np.sqrt(np.mean(err**2)) < 0.3 * noise
    # the velocity the isolator sees, against the law's own at each ramp's middle
    for mid, peak in ((0.4, 0.14 / 0.2), (1.66, -0.14 / 0.12)):
        exact = np.gradient(true, t)[round(mid * 1e3)]
        assert est.motion(mid, 1) == pytest.approx(exact, rel=0.01), peak
