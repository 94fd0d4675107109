"""The loop's final fit carried on with finer finite differences where it stopped short.

A refit's Jacobian comes from steps of FD_STEP (0.3 %) of each constant: above the
integrator's noise and wide enough not to count single stick/slip events. Where the
model has absorbed an effect's neighbourhood the valley can be narrower than that
step: an unseen campaign with a 7.8 % sensor gain (seed 1004) ended at 3.26 x the
noise, the gain and k1 within 0.2 % of the generator's, α at 70 against 84 1/m and β
at 111 against 95 s/m. There a 0.1 % change of k1 alone raised the cost by 77–93 %,
the forward difference of c2 had the wrong sign, and every trust-region step the
solver tried along that Jacobian was refused until xtol stopped it, while the cost
fell smoothly all the way along the line to the generator's constants (3.26 at the
stop, 1.14 nine tenths of the way). Restarted with the same step it stays; with
steps of 0.1 % it walked on: 2.00, then from there 1.06 x the noise.

So a final fit left well above the noise (where the loop would report structure it
cannot explain) is refitted from where it stopped with finer steps, each while it
cuts the residual, and kept only where it is lower. It names nothing and drops
nothing: which effects are in the model is settled before it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from analysis.identify.run_data import RunData
from analysis.loop.candidates import CANDIDATES, Candidate
from analysis.loop.refit import Fit, refit_free
from analysis.loop.result import Step

FINER_STEPS = (1e-3, 3e-4, 1e-4)  # of each scaled constant, after the refit's 3e-3
AGAIN = 3  # fresh trust regions per step size, from where the last one stopped
GAIN = 0.995  # a refit is kept, and another tried, if it cut the residual by 0.5 %


def polished(fit: Fit, data: Sequence[RunData], candidates: dict[str, Candidate],
             progress: Callable[[str], None] = lambda m: None) -> Fit:
    """`fit` refitted from where it stopped with finer finite-difference steps (its own
    free constants), the lowest kept; a step size that cuts nothing ends the search
    (the misfit is then the model's, not the solver's)."""
    progress(f"loop: the final fit stopped at {fit.residual_over_noise:.2f} x noise: "
             "refitting it with finer finite differences")
    best = fit
    for step in FINER_STEPS:
        cut = False
        for _ in range(AGAIN):
            again = refit_free(best.hypothesis, data, best.names, candidates, fd_step=step)
            if not again.rss < GAIN * best.rss:
                break
            best, cut = again, True
        if not cut:
            break
    return best


def step_candidates(fit: Fit, steps: Sequence[Step]) -> dict[str, Candidate]:
    """The candidate of each added effect, keyed by its parameter, at the shape the final
    model has it (a refitted shape sizes and bounds the effect as it was refitted)."""
    shapes = {t.name: t.shape for t in fit.hypothesis.model.terms}
    out = {}
    for s in steps:
        c = CANDIDATES[s.added]
        out[s.parameter] = c.shaped(shapes[s.parameter]) if c.term_kind and \
            s.parameter in shapes else c
    return out
