"""The table channel's time offset against the mass channel: a nuisance of output error.

A rig's two sensors reach it by different paths (the table over CAN, the mass
over a serial port): each channel is placed on the rig's clock late by its
path's smallest delivery latency, 0.1–0.2 ms, the two alike within ~0.1 ms
(`docs/time_alignment.md`). No clock fit sees that skew, but the constants do:
on a rig campaign 0.05 ms of it moves k1, c1 and α by ~10 of their standard
errors, while the runs themselves pin the skew to a few µs (measured: χ² rises
by ~140 between 0 and −0.05 ms). So where the acquisition declares such a skew
possible (`MeasuredRun.skew_limit`), each run's skew is fitted with the
constants, within that limit, and their uncertainty is carried into the
constants'. A CSV from another rig
declares none: a delay there is the loop's `sensor_delay`, an effect to name.

Convention: a skew s > 0 means the table moved s later than its samples say,
so the model is driven by u(t − s).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.interpolate import PPoly

from analysis.identify.output_error import (
    OutputErrorFit,
    RunData,
    gram_inverse,
    scaled_residual,
    with_log_covariance,
)
from analysis.table_motion import TableMotion, step_pulse_motion

SKEW_STEP = 2e-5  # s: finite-difference step, far above rounding, linear at 0.1 ms scale
SKEW_SCALE = 1e-4  # s: the column's unit, so that it is scaled like the constants' columns


def shifted_motion(motion: PPoly, skew: float) -> PPoly:
    """The table motion `skew` seconds later."""
    return PPoly(motion.c, motion.x + skew)


def shifted_table(table: TableMotion, t: np.ndarray, skew: float) -> TableMotion:
    """The table estimate `skew` seconds later: ramps moved, so the input's own
    uncertainty (`input_error`) is propagated around the shifted motion."""
    if not table.ramps:
        return replace(table, motion=shifted_motion(table.motion, skew))
    ramps = tuple((r[0] + skew, *r[1:]) for r in table.ramps)
    return replace(table, ramps=ramps, motion=step_pulse_motion(t, ramps, table.lag,
                                                                    table.shape))


def skew_columns(fit: OutputErrorFit, runs: list[RunData]) -> np.ndarray:
    """∂r/∂s_k of the fit's scaled residual for each run's own skew s_k (units of
    SKEW_SCALE): run k's rows in column k, zero elsewhere. One parallel batch."""
    later = [replace(r, motion=shifted_motion(r.motion, SKEW_STEP)) for r in runs]
    d = (scaled_residual(fit.model, later) - fit.residual) / SKEW_STEP * SKEW_SCALE
    cols, start = np.zeros((d.size, len(runs))), 0
    for k, run in enumerate(runs):
        cols[start:start + run.t.size, k] = d[start:start + run.t.size]
        start += run.t.size
    return cols


def skew_step(fit: OutputErrorFit, runs: list[RunData]
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Gauss–Newton step of each run's skew, their covariance, G) from `fit`; s.

    Each run has its own skew: every run reaches the rig by its own deliveries, and
    the smallest latency they saw differs by run (0.11–0.19 ms measured). The step
    solves [J, J_s] δ = −r by least squares (QR, not normal equations); the skews'
    covariance is their block of σ²([J, J_s]ᵀ[J, J_s])⁻¹, from the SVD, and
    G = −J⁺ J_s is how the log constants follow the skews: their covariance gains
    G C_s Gᵀ (the partitioned inverse), the skews' share.
    """
    J, r = fit.jacobian, fit.residual
    Js = skew_columns(fit, runs)
    A = np.column_stack([J, Js])
    delta = np.linalg.lstsq(A, -r, rcond=None)[0]
    s2 = float(r @ r) / max(r.size - A.shape[1], 1)
    n = Js.shape[1]
    cov = s2 * gram_inverse(A)[-n:, -n:] * SKEW_SCALE**2
    G = -np.linalg.lstsq(J, Js, rcond=None)[0] / SKEW_SCALE
    return delta[-n:] * SKEW_SCALE, cov, G


def with_skew_share(fit: OutputErrorFit, cov_skew: np.ndarray, G: np.ndarray
                    ) -> OutputErrorFit:
    """`fit` with the skews' uncertainty added to the constants' covariance."""
    return with_log_covariance(fit, G @ cov_skew @ G.T)
