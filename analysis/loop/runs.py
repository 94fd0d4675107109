"""The measured runs the loop is given, and what a fit predicts along them.

The loop judges a fit by its prediction of each run: the states z and ż along it
(free of differentiation noise) for the diagnosis and the conditioning report, a
candidate's signature variable for the evidence figure, and the per-run errors the
report prints. Each fit's runs are asked for several times, so the predictions are
remembered (`recent.Recent`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from analysis.identify.run_data import RunData, noise_sigma
from analysis.identify.run_errors import compare
from analysis.identify.table_motion import estimate_table_motion
from analysis.loop.candidates import Candidate
from analysis.loop.recent import Recent
from analysis.loop.refit import Fit, Hypothesis, predict, runs_away

if TYPE_CHECKING:  # the pipeline imports the loop's callers; only its type is needed here
    from analysis.identify.pipeline import IsolatorFit


@dataclass(frozen=True)
class LoopRun:
    """One measured run for the loop: the fit's RunData plus measured derivatives (SI)."""

    data: RunData
    ud: np.ndarray  # table velocity (from the smoothed input), m/s
    zd: np.ndarray | None = None  # measured relative velocity, m/s
    xdd: np.ndarray | None = None  # measured mass acceleration, m/s²
    input_method: str = ""  # how the table motion was estimated

    @classmethod
    def from_measurement(cls, name: str, t: np.ndarray, u: np.ndarray, x: np.ndarray,
                         zd: np.ndarray | None = None, xdd: np.ndarray | None = None
                         ) -> LoopRun:
        """A run from sampled u and x (m): input estimated, x noise from the data."""
        table = estimate_table_motion(t, u)
        data = RunData(name, np.asarray(t, float), table.motion, np.asarray(x, float),
                       noise_sigma(x))
        return cls(data, table.motion(t, 1), zd, xdd, table.method)


_PREDICTED = Recent(8)


def _predicted(h: Hypothesis, runs: Sequence[LoopRun]) -> list[np.ndarray]:
    """predict(h, runs' data), remembered: each fit's runs are reported several times."""
    data = tuple(r.data for r in runs)
    return _PREDICTED.get((h, *data), lambda: predict(h, data))


def predicted_states(fit: Fit, runs: Sequence[LoopRun]
                     ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Measured-side z and ż of each run, from the prediction (free of differentiation noise)."""
    pred = _predicted(fit.hypothesis, runs)
    z = [p[0] - r.data.motion(r.data.t) for p, r in zip(pred, runs)]
    return z, [np.gradient(v, r.data.t) for v, r in zip(z, runs)]


def diverging_runs(fit: Fit, runs: Sequence[LoopRun]) -> list[str]:
    """The runs whose lone prediction by the fit runs away (`refit.runs_away`): a
    thermal term whose falling viscosity takes the damping below zero late in run C
    predicts z 1e177 m there."""
    z, zd = predicted_states(fit, runs)
    return [r.data.name for r, a, b in zip(runs, z, zd) if runs_away(a) or runs_away(b)]


def predicted_signature(fit: Fit, runs: Sequence[LoopRun], c: Candidate) -> np.ndarray:
    """The variable candidate `c`'s residual shows against, along the fit's prediction
    of every run, concatenated."""
    pred = _predicted(fit.hypothesis, runs)
    z, zd = predicted_states(fit, runs)
    out = {"z": z, "zd": zd, "t": [r.data.t for r in runs], "x": [p[0] for p in pred],
           "xd": [np.gradient(p[0], r.data.t) for p, r in zip(pred, runs)]}[c.signature]
    return np.concatenate(out)


def run_errors(fit: Fit, runs: Sequence[LoopRun]) -> dict[str, dict[str, float]]:
    """Per run: NRMSE of z, ż, ẍ (fractions), RMS of m(ẍ_meas − ẍ_model) in N, residual/noise."""
    pred = _predicted(fit.hypothesis, runs)
    out = {}
    for p, r in zip(pred, runs):
        t = r.data.t
        e = compare(fit.hypothesis.model.mass, t, r.data.x, r.data.motion(t), r.ud,
                    r.data.sigma_x, p[0], r.zd, r.xdd)
        out[r.data.name] = e.as_dict()
    return out


def loop_runs(fit: IsolatorFit) -> list[LoopRun]:
    """The prepared runs as the loop reads them: the same input estimate and derivatives."""
    return [LoopRun(p.oe, p.oe.motion(p.oe.t, 1), p.zd, p.xdd, p.table.method)
            for p in fit.prepared]
