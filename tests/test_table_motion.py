"""The table's motion estimated from its noisy sensor: errors in variables."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from analysis.table_motion import estimate_table_motion
from sim.generate import SENSOR_NOISE, generate_campaign


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
