"""The table channel's time offset and rate fitted with the constants: Gauss–Newton
steps of `channel_skew.skew_step`, each applied to the prepared runs (`shift_input`)
and the constants refitted."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from analysis.identify.channel_skew import shifted_table, skew_step
from analysis.identify.output_error import OutputErrorFit, refine
from analysis.identify.prepare import PreparedRun

SKEW_ITERATIONS = 4
DRIFT_LIMIT = 1e-4  # the skew's rate within a run: two device clocks' fits, 100 ppm apart
SKEW_CONVERGED = 0.25  # standard errors: a further step smaller than this is not taken


def fit_skew(fit: OutputErrorFit, prepared: tuple[PreparedRun, ...], limit: float):
    """Gauss–Newton on the runs' skews with the constants (`channel_skew.skew_step`),
    each step's shifts applied to the runs and the constants refitted, within ±limit.

    Returns the fit, the shifted runs, the offsets (s) then rates and, when the last step
    was computed at the returned fit, (its Jacobian, that step) for reuse; else None.
    """
    n = len(prepared)
    offset, last = np.zeros(2 * n), None
    bound = np.repeat([limit, DRIFT_LIMIT], n)
    for _ in range(SKEW_ITERATIONS):
        last = (fit.jacobian, skew_step(fit, [p.oe for p in prepared]))
        step, cov, _ = last[1]
        new = np.clip(offset + step, -bound, bound)
        if np.all(np.abs(new - offset) <= SKEW_CONVERGED * np.sqrt(np.diag(cov))):
            break
        d = new - offset
        prepared = tuple(shift_input(p, float(d[k]), float(d[n + k]))
                         for k, p in enumerate(prepared))
        offset = new
        fit, last = refine(fit.model, [p.oe for p in prepared], fit.names), None
    return fit, prepared, offset, last


def shift_input(p: PreparedRun, skew: float, drift: float = 0.0) -> PreparedRun:
    """The prepared run with its table motion skew + drift (t − t_c) seconds later
    (`channel_skew.skew_origin`; z, ż follow)."""
    t = p.run.t
    table = shifted_table(p.table, t, skew, drift)
    u, ud = table.motion(t), table.motion.derivative()(t)
    x = p.z + p.table.motion(t)
    xd = p.zd + p.table.motion.derivative()(t)
    return replace(p, table=table, z=x - u, zd=xd - ud, oe=replace(p.oe, motion=table.motion))
