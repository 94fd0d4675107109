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

The skew also drifts within a run: each channel's clock fit has its own rate
error (a line under a few seconds of fastest deliveries; on a loaded machine the
table's and the mass's disagreed by up to 39 ppm, 0.2 ms over a 5 s run, 0.4 mm
of x at run C's speed). So each run's skew is s + ρ (t − t_c): an offset at the
table motion's centroid t_c and a rate, both fitted, both carried into the
constants' covariance. A run whose motion is brief (run C's ramps) pins its rate
only to ~25 ppm, and that uncertainty belongs in the constants': held at 0 there,
the 95 % intervals of 20 rig campaigns covered the rig's α 3 times in 4 (α's
error bar shrank to a third, its spread did not). About the centroid the two are
nearly uncorrelated; about the record's middle, a run whose ramps all come early
(run C) traded one for the other along a valley where the BLAS kernel's last bits
chose the point (offset −161 or −103 µs, rate +1 or +45 ppm, the constants alike).
The centroid is taken from the motion as it stands at each step; a step moves it by
the step's offset, which changes the shift by rate × offset, ~1e-9 s.
Measured on 20 rig campaigns before the rate was fitted: the 95 % intervals
covered the rig's constants in 78 % of cases, and with the samples placed at
their true instants (the simulator's truth file) in 7 of 8 where the rig's own
placement gave 4.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.interpolate import PPoly

from analysis.identify.covariance import gram_inverse
from analysis.identify.output_error import OutputErrorFit, with_log_covariance
from analysis.identify.residuals import scaled_residual
from analysis.identify.run_data import RunData
from analysis.identify.step_pulse import step_pulse_motion
from analysis.identify.table_motion import TableMotion

SKEW_STEP = 2e-5  # s: finite-difference step, far above rounding, linear at 0.1 ms scale
SKEW_SCALE = 1e-4  # s: the column's unit, so that it is scaled like the constants' columns
DRIFT_STEP = 1e-5  # the rate's finite-difference step: 20 µs at 2 s from the middle
DRIFT_SCALE = 1e-5  # the rate column's unit (10 ppm)


def skew_origin(motion: PPoly, t: np.ndarray) -> float:
    """s: the instant a run's skew offset is stated at and its rate turns about — the
    centroid of the table's speed over the run's samples, where the data see the skew."""
    speed = np.abs(motion.derivative()(t))
    total = float(np.sum(speed))
    return float(np.sum(speed * t) / total) if total > 0 else 0.5 * float(t[0] + t[-1])


def shifted_motion(motion: PPoly, skew: float, drift: float = 0.0, origin: float = 0.0
                   ) -> PPoly:
    """The table motion later by skew + drift (t − origin): the PPoly's breaks moved and
    each piece stretched by 1 + drift."""
    if drift == 0.0:
        return PPoly(motion.c, motion.x + skew)
    order = motion.c.shape[0] - 1
    stretch = (1.0 + drift) ** -np.arange(order, -1, -1, dtype=float)
    return PPoly(motion.c * stretch[:, None],
                 motion.x + skew + drift * (motion.x - origin))


def shifted_table(table: TableMotion, t: np.ndarray, skew: float, drift: float = 0.0
                  ) -> TableMotion:
    """The table estimate later by skew + drift (t − t_c) (`skew_origin`): ramps moved
    and stretched, so the input's own uncertainty (`input_error`) is propagated around
    the shifted motion."""
    origin = skew_origin(table.motion, t)
    if not table.ramps:
        return replace(table, motion=shifted_motion(table.motion, skew, drift, origin))
    ramps = tuple((r[0] + skew + drift * (r[0] - origin), r[1] * (1.0 + drift), *r[2:])
                  for r in table.ramps)
    return replace(table, ramps=ramps, motion=step_pulse_motion(t, ramps, table.lag,
                                                                    table.shape))


def skew_columns(fit: OutputErrorFit, runs: list[RunData]) -> np.ndarray:
    """(rows, 2 n) ∂r/∂s_k and ∂r/∂ρ_k of the fit's scaled residual for each run's own
    skew offset s_k (units of SKEW_SCALE) and rate ρ_k (DRIFT_SCALE): run k's rows in
    columns k and n + k, zero elsewhere. One parallel batch each."""
    later = [replace(r, motion=shifted_motion(r.motion, SKEW_STEP)) for r in runs]
    d = (scaled_residual(fit.model, later) - fit.residual) / SKEW_STEP * SKEW_SCALE
    faster = [replace(r, motion=shifted_motion(r.motion, 0.0, DRIFT_STEP,
                                               skew_origin(r.motion, r.t))) for r in runs]
    e = (scaled_residual(fit.model, faster) - fit.residual) / DRIFT_STEP * DRIFT_SCALE
    n = len(runs)
    cols, start = np.zeros((d.size, 2 * n)), 0
    for k, run in enumerate(runs):
        rows = slice(start, start + run.t.size)
        cols[rows, k], cols[rows, n + k] = d[rows], e[rows]
        start += run.t.size
    return cols


def skew_step(fit: OutputErrorFit, runs: list[RunData]
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Gauss–Newton step of each run's skew offset (s) then rate (1), their covariance,
    G) from `fit`: arrays of 2 n, (2 n, 2 n), (constants, 2 n).

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
    m = Js.shape[1]
    unit = np.repeat([SKEW_SCALE, DRIFT_SCALE], m // 2)
    cov = s2 * gram_inverse(A)[-m:, -m:] * np.outer(unit, unit)
    G = -np.linalg.lstsq(J, Js, rcond=None)[0] / unit
    return delta[-m:] * unit, cov, G


def with_skew_share(fit: OutputErrorFit, cov_skew: np.ndarray, G: np.ndarray
                    ) -> OutputErrorFit:
    """`fit` with the skews' uncertainty added to the constants' covariance."""
    return with_log_covariance(fit, G @ cov_skew @ G.T)
