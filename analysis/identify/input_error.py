"""Errors in variables: the table-motion estimate's uncertainty carried into the constants.

The model is driven by the table motion estimated from the table sensor (a few
minimum-jerk ramp parameters p fitted to thousands of noisy samples, see
`analysis.identify.table_motion`). Output error then treats that input as exact, and
the Jacobian's covariance counts only the mass sensor's noise. Measured on
runs A, B, C with 25.4 µm on both sensors, that understates the spread of the
constants by up to 4× (bench/identify.py): an error of a few µs in a ramp's
start time moves the simulated x as much as a constant does.

The input's share is added to first order. With r(θ, p) the scaled residual
of x, J = ∂r/∂log θ and J_p = ∂r/∂p, the fitted constants move by
G δp with G = −(JᵀJ)⁻¹ Jᵀ J_p when p is off by δp, and δp has the covariance
C_p = (J_uᵀ J_u)⁻¹ of the ramp fit (J_u: the fitted u's derivative over p in
units of σ_u: the white noise of u's low-frequency power, `TableMotion.sigma_lowfreq`,
which for a channel interpolated onto another clock exceeds each sample's σ). So
cov(log θ) = σ²(JᵀJ)⁻¹ + Σ_runs G C_p Gᵀ. p is the ramps' parameters and, when the
table motion was fitted with a servo lag (`TableMotion.lag` > 0), the lag τ: its
uncertainty reaches the constants the same way, and u is perturbed through the same
lagged model it was fitted with.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from analysis.identify.covariance import determined_gram_inverse, gram_inverse
from analysis.identify.output_error import OutputErrorFit, with_log_covariance
from analysis.identify.run_data import RunData
from analysis.identify.step_pulse import (
    params_ramps,
    step_pulse_motion,
    step_pulse_params,
    step_pulse_value,
    tied_ramps,
)
from analysis.identify.step_pulse_fit import refine_step_pulse
from analysis.identify.table_motion import TableMotion
from analysis.model.isolator import IsolatorModel
from analysis.simulate import RunSetup, simulate_runs

STEP = (1e-5, 1e-6)  # FD steps: s for ramp times and the lag, m for levels; ≪ their spread


def _params(table: TableMotion) -> np.ndarray:
    """[start level, (begin s, duration s, to m) per ramp, then the lag s if it was fitted]."""
    return step_pulse_params(table.ramps, table.lag if table.lag > 0 else None)


def _motion(t: np.ndarray, table: TableMotion, p: np.ndarray, tied: np.ndarray):
    """The table motion of parameter vector p (the estimate's own form: lagged or not)."""
    return step_pulse_motion(t, params_ramps(p, tied), p[-1] if table.lag > 0 else 0.0,
                             table.shape)


def refine_table(t: np.ndarray, u: np.ndarray, table: TableMotion) -> TableMotion:
    """The step-pulse fit refined on the whole record: every ramp, level and the lag at once.

    `analysis.identify.table_motion` fits each moving stretch on its own samples, so a
    level held for 2 s is set by the few samples next to its ramps. Fitted
    together on every sample the levels use all the rest they hold for — the
    least-squares (and, for white noise, maximum-likelihood) input whose
    covariance C_p below assumes. Measured: without this, the spread of k1 over
    noise draws was 2.5× the propagated standard error. The servo lag is refitted
    with them when the estimate has one (`TableMotion.lag` > 0), else held at 0.
    """
    if not table.ramps:
        return table
    free = table.lag > 0
    ramps, lag = refine_step_pulse(t, u, table.ramps, table.lag, free_lag=free,
                                   shape=table.shape)
    motion = step_pulse_motion(t, ramps, lag, table.shape)
    rms = float(np.sqrt(np.mean((step_pulse_value(t, ramps, lag, table.shape) - u) ** 2)))
    return replace(table, motion=motion, ramps=tuple(ramps), lag=lag,
                   residual_over_noise=rms / max(table.sigma, 1e-300))


def _steps(table: TableMotion) -> np.ndarray:
    n = len(table.ramps)
    return np.array([STEP[1]] + [STEP[0], STEP[0], STEP[1]] * n + [STEP[0]] * (table.lag > 0))


def input_sensitivities(model: IsolatorModel, runs: Sequence[RunData],
                        tables: Sequence[TableMotion]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per run (J_x, C_p): ∂(x_sim/σ_x)/∂p at `model`, and the input fit's covariance.

    J_x is a first-order quantity: a fit a few standard errors away (a run
    refitted alone from the joint fit) may use the joint model's and save the
    run's 3·ramps + 2 simulations. Every run's perturbed motions are simulated
    in one parallel batch.
    """
    setups, cols = [], []
    for run, table in zip(runs, tables):
        p0, tied = _params(table), tied_ramps(table.ramps)
        h = _steps(table)
        motions = [_motion(run.t, table, p0, tied)]
        for j in range(p0.size):
            p = p0.copy()
            p[j] += h[j]
            motions.append(_motion(run.t, table, p, tied))
        setups += [RunSetup(m, run.t[-1] - run.t[0], run.dt, run.t[0]) for m in motions]
        cols.append((motions, h, table.sigma_lowfreq or table.sigma))
    row = model.vector()
    xs = [b.z[0] + b.u for b in simulate_runs(model, setups, [row] * len(setups))]
    out, k = [], 0
    for run, (motions, h, noise) in zip(runs, cols):
        n = run.t.size
        x0, u0 = xs[k][:n], motions[0](run.t)
        Jx, Ju = np.empty((n, h.size)), np.empty((n, h.size))
        for j in range(h.size):
            Jx[:, j] = (xs[k + 1 + j][:n] - x0) / run.sigma_x / h[j]
            # noise: what the few slow parameters average (white σ of u's low frequencies)
            Ju[:, j] = (motions[1 + j](run.t) - u0) / noise / h[j]
        out.append((Jx, determined_gram_inverse(Ju)))
        k += 1 + h.size
    return out


def with_input_uncertainty(fit: OutputErrorFit, runs: Sequence[RunData],
                           tables: Sequence[TableMotion],
                           sensitivities: Sequence[tuple[np.ndarray, np.ndarray]] | None = None
                           ) -> OutputErrorFit:
    """`fit` with the input estimate's share added to its covariance and std.

    Only when every run's input is a step-pulse fit (a spline has no few
    parameters to propagate); otherwise `fit` is returned unchanged.
    `sensitivities`: each run's `input_sensitivities` when already known; those
    used are kept in the result's `input_sensitivity`.
    """
    if fit.jacobian is None or not all(t.ramps for t in tables):
        return fit
    if sensitivities is None:
        sensitivities = input_sensitivities(fit.model, runs, tables)
    J = fit.jacobian
    info_inv = gram_inverse(J)
    share = np.zeros((J.shape[1], J.shape[1]))
    start = 0
    for run, (Jx, Cp) in zip(runs, sensitivities):
        rows = slice(start, start + run.t.size)
        G = -info_inv @ (J[rows].T @ Jx)  # how the constants follow an input error
        share += G @ Cp @ G.T
        start += run.t.size
    return with_log_covariance(fit, share, input_covariance=True,
                               input_sensitivity=tuple(sensitivities))
