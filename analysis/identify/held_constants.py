"""Constants the runs may not determine: the non-smooth ones (the breakaway force)
judged on slices of the cost and freed only when the runs prefer another value, and
any the fit leaves loose held at their start value."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from analysis.identify.covariance import correlated_noise_factor
from analysis.identify.output_error import HOLD_LOG_STD, OutputErrorFit, refine
from analysis.identify.residuals import slice_residuals
from analysis.identify.run_data import RunData
from analysis.model.isolator import IsolatorModel

# Thresholds: the breakaway force switches the mass between stuck and sliding, so a
# finite-difference column of it counts whether one stick/slip event moved by a sample
# (log std 0.001 on one draw, 1.4 on the next: measured on rig campaigns). It is judged
# instead on decade-wide steps of the cost, fitted last and freed only when the runs
# prefer another value by more than SIGNIFICANT_CHI2.
NONSMOOTH = ("F_break",)
SLICE_FACTORS = (0.1, 0.3, 1.0, 3.0, 10.0)  # of the held value: the search's own range
SIGNIFICANT_CHI2 = 10.83  # χ²₁ at 0.1 %: a difference no noise draw makes by chance
CONSISTENT_CHI2 = 3.84  # χ²₁ at 5 %: values the runs cannot tell from the best

Progress = Callable[[str], None]  # a stage's progress message


def settle_nonsmooth(fit: OutputErrorFit, runs: Sequence[RunData], held: tuple[str, ...],
                     progress: Progress) -> tuple[OutputErrorFit, tuple[str, ...]]:
    for name in NONSMOOTH:
        fit, freed = _nonsmooth(fit, runs, name, progress)
        held = held if freed else held + (name,)
    return fit, held


def hold_loose(fit: OutputErrorFit, start: IsolatorModel, runs: Sequence[RunData],
               held: tuple[str, ...], progress: Progress
               ) -> tuple[OutputErrorFit, tuple[str, ...]]:
    """A constant the fit leaves undetermined (std beyond HOLD_LOG_STD) back at its start
    value and held; the rest refitted."""
    loose = [n for n, v, s in zip(fit.names, fit.values, fit.std) if s > HOLD_LOG_STD * v]
    if loose:
        held = held + tuple(loose)
        back = {n: start.parameters()[n] for n in loose}
        fit = replace(refine(fit.model.with_parameters(**back), runs,
                             [n for n in fit.names if n not in loose]),
                      consistent=fit.consistent)
    if held:
        progress(f"  held (not determined by these runs): {', '.join(held)}")
    return fit, held


def _nonsmooth(fit: OutputErrorFit, runs: Sequence[RunData], name: str, progress: Progress
               ) -> tuple[OutputErrorFit, bool]:
    """`fit` with constant `name` freed if the runs determine it, else held; and which.

    The cost is sliced at SLICE_FACTORS of the held value with every other constant
    at the fit. Freed only when a value there beats the held one by SIGNIFICANT_CHI2,
    scaled by how much the residual's own correlation moves a cost difference along
    that change (`correlated_noise_factor`: a model µm off the truth moves it many times
    more than white noise), and the fit from it, with `name` free, keeps that gain and
    leaves every constant within HOLD_LOG_STD: a freed breakaway force that ends in a
    valley above the held fit's cost (one where a 10× force trades off against α) is
    refused. Held, the range of values within CONSISTENT_CHI2 of the best is kept as
    `fit.consistent[name]`.
    """
    held = fit.model.parameters()[name]
    values = held * np.asarray(SLICE_FACTORS)
    res = slice_residuals(fit.model, runs, name, values)
    chi2 = np.sum(res**2, axis=1)
    i0 = SLICE_FACTORS.index(1.0)
    base = float(chi2[i0])
    best = int(np.argmin(chi2))
    kappa = correlated_noise_factor(res[i0], res[best] - res[i0], [r.t.size for r in runs])
    if base - chi2[best] > SIGNIFICANT_CHI2 * kappa:
        progress(f"  {name}: the runs prefer {values[best]:.4g} (chi2 {base - chi2[best]:.0f} "
                 f"lower, correlated noise x{kappa:.2g}): freed")
        names = fit.names + (name,)
        free = refine(fit.model.with_parameters(**{name: float(values[best])}), runs, names)
        cut = base - float(free.residual @ free.residual)
        loose = free.std > HOLD_LOG_STD * free.values
        if cut > SIGNIFICANT_CHI2 * kappa and not loose.any():
            return free, True
        progress(f"  {name}: freed, the fit gains chi2 {cut:.0f} but leaves "
                 f"{', '.join(np.array(names)[loose]) or 'nothing'} undetermined: held")
    near = values[chi2 <= chi2.min() + CONSISTENT_CHI2 * kappa]
    return replace(fit, consistent={**fit.consistent,
                                    name: (float(near.min()), float(near.max()))}), False
