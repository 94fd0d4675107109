"""The table's motion as step-pulse ramps through a fitted servo lag
(analysis.identify.table_motion).

Known truth: a profile's exact minimum-jerk motion passed through p' = (r − p)/τ,
plus white sensor noise. Tolerances are the fit's own standard errors (from the
model's Jacobian in units of σ_u): a 4-standard-error bound fails by chance with
probability 6e-5 per check when the estimate is unbiased and its covariance right.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from analysis.identify import input_error
from analysis.identify.run_data import noise_sigma
from analysis.identify.step_pulse import lag_response, params_ramps, step_pulse_value, tied_ramps
from analysis.identify.table_motion import estimate_table_motion, table_noise
from rig.profile import load_profile

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

SIGMA = 2.54e-5  # m, 0.001 in: the rig's sensors
INCH = 0.0254


def lagged_run(profile: str, lag: float, seed: int, rate: float = 1000.0):
    prof = load_profile(profile)
    t = np.arange(0.0, prof.duration + 0.5, 1.0 / rate)  # 0.5 s more: the lag settles
    true = lag_response(t, prof.motion(), lag)[0]
    rng = np.random.default_rng(seed)
    return t, true, true + SIGMA * rng.standard_normal(t.size)


def fit_std(t: np.ndarray, table) -> np.ndarray:
    """Standard errors of [start level, (begin, duration, to) per ramp, lag] from J_u."""
    tied = tied_ramps(table.ramps)
    p0 = input_error._params(table)
    h = input_error._steps(table)
    u0 = step_pulse_value(t, table.ramps, table.lag)
    J = np.empty((t.size, p0.size))
    for j in range(p0.size):
        p = p0.copy()
        p[j] += h[j]
        lag = p[-1] if table.lag > 0 else 0.0
        J[:, j] = (step_pulse_value(t, params_ramps(p, tied), lag) - u0) / table.sigma / h[j]
    keep = np.ones(p0.size, bool)  # a tied ramp's begin is no parameter (input_error)
    keep[1 + 3 * np.flatnonzero(tied)] = False
    std = np.zeros(p0.size)
    std[keep] = np.sqrt(np.diag(np.linalg.inv(J[:, keep].T @ J[:, keep])))
    return std


def test_lag_response_is_the_solution_of_the_lag_equation():
    prof = load_profile("C")  # up and straight back: a turn without rest
    command = prof.motion()
    t = np.linspace(0.0, prof.duration, 3001)
    tau = 0.005

    def r(s):
        return command(np.clip(s, command.x[0], command.x[-1]))

    sol = solve_ivp(lambda s, y: (r(s) - y) / tau, (0.0, prof.duration), [0.0], t_eval=t,
                    rtol=1e-11, atol=1e-14, max_step=2e-4)
    p, v, a = lag_response(t, command, tau)
    assert np.abs(p - sol.y[0]).max() < 1e-9  # m, of 0.14 m
    assert np.allclose(v, (r(t) - p) / tau, atol=1e-9)  # p' = (r − p)/τ
    assert np.allclose(a, np.gradient(v, t), atol=0.05 * np.abs(a).max())


@pytest.mark.parametrize("profile, lag, seed", [("A", 0.005, 1), ("C", 0.005, 2),
                                                ("B", 0.012, 3)])
def test_lagged_step_pulse_with_noise_recovers_the_lag_and_the_levels(profile, lag, seed):
    t, true, u = lagged_run(profile, lag, seed)
    est = estimate_table_motion(t, u)
    assert est.method == "step-pulse fit"
    assert est.residual_over_noise == pytest.approx(1.0, abs=0.1)
    assert est.sigma == pytest.approx(SIGMA, rel=0.1)
    std = fit_std(t, est)
    assert abs(est.lag - lag) < 4 * std[-1]
    assert std[-1] < 1e-4  # s: the data pin the lag to better than 2 % of 5 ms
    levels = [est.ramps[0][2]] + [r[3] for r in est.ramps]
    level_std = std[[0] + [3 + 3 * k for k in range(len(est.ramps))]]
    commanded = {"A": [0, 5.5, 0], "B": [0, -5.5, 0], "C": [0, 5.5, 0]}[profile]
    assert np.all(np.abs(np.array(levels) - INCH * np.array(commanded)) < 4 * level_std)
    durations = [r[1] for r in est.ramps]
    nominal = {"A": [0.2, 0.12], "B": [0.2, 0.12], "C": [0.12, 0.12]}[profile]
    dur_std = std[[2 + 3 * k for k in range(len(est.ramps))]]
    assert np.all(np.abs(np.array(durations) - nominal) < 4 * dur_std)
    # the input the model is driven with: far better than one sample (as without lag)
    err = est.motion(t) - true
    assert np.sqrt(np.mean(err**2)) < 0.2 * SIGMA
    assert np.abs(err).max() < 0.8 * SIGMA


def test_an_exact_profile_keeps_no_lag():
    prof = load_profile("A")
    t = np.arange(0.0, prof.duration, 1e-3)
    u = prof.motion()(t) + SIGMA * np.random.default_rng(4).standard_normal(t.size)
    est = estimate_table_motion(t, u)
    assert est.method == "step-pulse fit" and est.lag == 0.0


def test_an_interpolated_channel_has_its_noise_read_right():
    """The run-file loader interpolates u onto the mass sensor's instants: at half a
    sample each value is the mean of two, 0.71 σ of noise, with neighbours correlated.
    Plain second differences read 0.41 σ (and the fit was refused at 1.7× that);
    second differences three samples apart read the 0.71 σ every sample has."""
    t, true, _ = lagged_run("A", 0.005, seed=5)
    rng = np.random.default_rng(5)
    raw = true + SIGMA * rng.standard_normal(t.size)
    mid = t[:-1] + 0.5e-3
    u = np.interp(mid, t, raw)
    per_sample = SIGMA * np.sqrt(0.5)
    assert noise_sigma(u) == pytest.approx(SIGMA * np.sqrt(1 / 6), rel=0.1)  # the old reading
    assert table_noise(mid, u) == pytest.approx(per_sample, rel=0.1)
    est = estimate_table_motion(mid, u)
    assert est.method == "step-pulse fit"
    assert est.lag == pytest.approx(0.005, abs=2e-4)
    # what the few ramp parameters average is the sensor's own noise: its spectrum at
    # 0 is unchanged by interpolation, and input_error's C_p is scaled by it
    assert est.sigma_lowfreq == pytest.approx(SIGMA, rel=0.1)


def test_refine_and_the_input_share_use_the_model_that_was_fitted():
    t, _, u = lagged_run("C", 0.005, seed=6)
    est = estimate_table_motion(t, u)
    refined = input_error.refine_table(t, u, est)
    assert refined.lag == pytest.approx(est.lag, abs=1e-5)  # already the joint optimum
    # the propagation perturbs the lagged model: its parameters end with the lag
    p = input_error._params(refined)
    assert p.size == 1 + 3 * len(refined.ramps) + 1 and p[-1] == refined.lag
    tied = tied_ramps(refined.ramps)
    same = input_error._motion(t, refined, p, tied)
    assert np.abs(same(t) - refined.motion(t)).max() < 1e-12
    p[-1] += 1e-4
    moved = input_error._motion(t, refined, p, tied)(t) - refined.motion(t)
    assert np.abs(moved).max() > 5 * SIGMA  # 0.1 ms of lag moves u: it has a share to carry
    # without a lag nothing changes: the plain ramps, held at lag 0
    prof = load_profile("C")
    t2 = np.arange(0.0, prof.duration, 1e-3)
    u2 = prof.motion()(t2) + SIGMA * np.random.default_rng(7).standard_normal(t2.size)
    plain = input_error.refine_table(t2, u2, estimate_table_motion(t2, u2))
    assert plain.lag == 0.0 and input_error._params(plain).size == 1 + 3 * len(plain.ramps)
