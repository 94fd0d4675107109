"""Effects the loop added that the final model does not need, dropped.

The loop names one effect at a time, forward, and each is judged against the model
as it was when it came in. `drop_redundant` looks back: each effect judged again, by
the checks it passed on the way in, against the model with the ones named after it
(backward elimination) and against the final fit, whose restarts move every constant.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from analysis.identify.run_data import RunData
from analysis.loop.candidates import CANDIDATES
from analysis.loop.judge import held_look_alikes, own_parameters, stands_alone
from analysis.loop.refit import Fit, refit_free
from analysis.loop.result import Step


def drop_redundant(fit: Fit, free: list[str], steps: list[Step], data: Sequence[RunData],
                   progress: Callable[[str], None],
                   against: str = "with the effects named after it", alike: bool = True,
                   base: Fit | None = None):
    """Each added effect judged again against `fit`: one the model no longer needs is
    dropped and the model refitted without it (backward elimination).

    Equation error names one effect at a time, and a first name can stand in for the
    one named after it: a sensor gain was named before a thermal drift, and with the
    drift in the model the gain cut nothing. The final fit's restarts can make a lone
    effect redundant too: on an unseen lagged servo (1201) a sensor gain named at
    4.45 x noise was kept at -0.020 % once the restarts had taken the model without it
    to 1.10 x, and on a one-sided damping (513) a force offset of 0.24 N and a cubic
    spring named at 50 x noise stayed beside it at 1.06 x. `against`: when it is
    judged again, for the progress line and the reason.

    `alike`: whether a look-alike of a determined constant is refused, as on the way
    in. Judged after the restarts, only whether the model still needs the effect counts:
    |t|, the cut, the motion explained. Held at a constant it looks like, an effect refits
    in a valley of its own there: on an unseen Bouc–Wen loop with a sensor gain (5401)
    the loop's k_h, at |t| 4.1 in the restarted fit (30.5 x noise), went to |t| 0.2 with
    α held and was dropped, and the model without it ended at 58 x.

    `base`: the fit without any effect. Where every effect is dropped and `base` is
    lower, it is the model: the refits without them can walk from their valley to a worse
    one than the base fit's (an unseen Bouc–Wen loop: 43.7 x noise after against 24.0
    before).
    Returns (fit, free, steps, refused).
    """
    steps, dropped = list(steps), []
    for step in list(steps):
        others = [n for n in free if n not in own_parameters(fit, step.parameter)]
        progress(f"loop: is {step.added} still needed {against}?")
        cands = {s.parameter: CANDIDATES[s.added] for s in steps}
        without = refit_free(fit.hypothesis.with_values({step.parameter: 0.0}), data, others,
                             {p: c for p, c in cands.items() if p != step.parameter})
        # as on the way in (`judge`): each shape constant it stands in for held, judged
        # again (a Coulomb friction beside a cubic spring, against ε at 0.997), and a
        # look-alike kept where no constant of the model can take its place
        reason = ("the model without it fits as well" if without.rss <= fit.rss else
                  held_look_alikes(without, fit, step.parameter, data, cands,
                                   alike=alike and not stands_alone(fit, without))[1])
        if reason:
            dropped.append({"candidate": step.added,
                            "reason": f"dropped, judged again {against}: {reason}"})
            steps.remove(step)
            fit, free = without, others
    if dropped and not steps and base is not None and base.rss < fit.rss:
        fit, free = base, list(base.names)
    return fit, free, steps, dropped
