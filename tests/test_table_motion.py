"""The table's motion estimated from its noisy sensor: errors in variables."""

from __future__ import annotations

import numpy as np
import pytest

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
    """A table that lags its command (first-order, 15 ms) is no minimum-jerk profile."""
    run = generate_campaign(runs=("C",), seed=3, noise=0.0)[0]
    dt = run.t[1] - run.t[0]
    lagged = np.empty_like(run.u_true)
    lagged[0] = run.u_true[0]
    a = dt / 0.015
    for i in range(1, lagged.size):
        lagged[i] = lagged[i - 1] + a * (run.u_true[i] - lagged[i - 1])
    rng = np.random.default_rng(0)
    est = estimate_table_motion(run.t, lagged + rng.normal(0, SENSOR_NOISE, lagged.size))
    assert est.method == "smoothing spline"
    assert np.abs(est.motion(run.t) - lagged).max() < 10 * SENSOR_NOISE
