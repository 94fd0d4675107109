"""Effects the loop added that the final model does not need, dropped.

The loop names one effect at a time, forward, and each is judged against the model
as it was when it came in. Two checks look back once the steps are done:
`drop_redundant`, each effect judged again against the model with the ones named
after it (backward elimination), and `drop_at_zero`, each effect the final fit's
restarts left within three standard errors of zero.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from analysis.identify.run_data import RunData
from analysis.loop.candidates import CANDIDATES
from analysis.loop.judge import MIN_T, held_look_alikes, own_parameters
from analysis.loop.refit import Fit, refit_free
from analysis.loop.result import Step


def drop_redundant(fit: Fit, free: list[str], steps: list[Step], data: Sequence[RunData],
                   progress: Callable[[str], None]):
    """Each added effect judged again against the final model: one that a later effect
    has made redundant is dropped (backward elimination after the forward steps).

    Equation error names one effect at a time, and a first name can stand in for the
    one named after it: a sensor gain was named before a thermal drift, and with the
    drift in the model the gain cut nothing. Returns (fit, free, steps, refused).
    """
    steps, dropped = list(steps), []
    for step in list(steps):
        others = [n for n in free if n not in own_parameters(fit, step.parameter)]
        progress(f"loop: is {step.added} still needed with the effects named after it?")
        cands = {s.parameter: CANDIDATES[s.added] for s in steps}
        without = refit_free(fit.hypothesis.with_values({step.parameter: 0.0}), data, others,
                             {p: c for p, c in cands.items() if p != step.parameter})
        # as on the way in (`judge`): each shape constant it stands in for held, judged
        # again (a Coulomb friction beside a cubic spring, against ε at 0.997)
        reason = ("the model without it fits as well" if without.rss <= fit.rss else
                  held_look_alikes(without, fit, step.parameter, data, cands)[1])
        if reason:
            dropped.append({"candidate": step.added, "reason": "dropped once the effects "
                            f"after it were in the model: {reason}"})
            steps.remove(step)
            fit, free = without, others
    return fit, free, steps, dropped


def drop_at_zero(fit: Fit, steps: list[Step], data: Sequence[RunData],
                 progress: Callable[[str], None]):
    """Each added effect the final fit puts at zero (|t| < MIN_T, the test it passed on
    the way in) dropped, the model refitted without it: the final fit's restarts move
    every constant, and an effect judged needed before them can end at nothing. On a
    hardening spring whose sensor gain was named before the cubic (unseen 307), the gain
    ended at -1.8e-6 ± 1.5e-5 under one BLAS kernel and was reported beside the cubic;
    under two others `drop_redundant` had dropped it. Returns (fit, steps, refused)."""
    steps, dropped = list(steps), []
    for step in list(steps):
        value, std = fit.param(step.parameter)
        if std > 0 and abs(value) >= MIN_T * std:
            continue
        progress(f"loop: {step.added} is at zero in the final fit: refitting without it")
        steps.remove(step)
        others = [n for n in fit.names if n not in own_parameters(fit, step.parameter)]
        fit = refit_free(fit.hypothesis.with_values({step.parameter: 0.0}), data, others,
                         {s.parameter: CANDIDATES[s.added] for s in steps})
        dropped.append({"candidate": step.added, "reason": f"dropped: the final fit puts it "
                        f"at {value:.3g} ± {std:.2g} (|t| < {MIN_T:g})"})
    return fit, steps, dropped
