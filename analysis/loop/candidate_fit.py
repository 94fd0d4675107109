"""The named candidate refitted by output error from several starts; the best is kept.

Output error's cost is many-valleyed (where the mass sticks, and where it rests in
the dead band, move in steps with a constant), and the base fit has soaked up what
the missing effect does into Eq 10's constants, so a refit from the base fit alone
can stay in the base fit's valley. Appendix A's least-squares solution with the
candidate's column comes first (it has no valleys). Where the refit from it does not
reach the noise, the other starts race (`race`: each a few evaluations, the best
carried on): that start with the dead band and stop velocity held, the model
identified again by equation error with the candidate in it, α, β and δ searched
(`reidentify`), and the best of a scan of sizes and the score's estimate; where
still none reaches the noise, the constants the loop was given race too
(`refit_from_start`), and the best, where it held the dead band or the stop velocity,
is refitted on with them free (`with_stop_freed`).

Whether the best refit is kept is `judge`'s to decide.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from analysis.identify.regressors import campaign_regressors
from analysis.loop.candidates import SENSOR_GAIN, Candidate
from analysis.loop.refit import (
    MAX_NFEV,
    Fit,
    Hypothesis,
    Score,
    predict,
    refit_free,
)
from analysis.loop.reidentify import (
    Reidentified,
    base_projection,
    moving,
    moving_data,
    with_candidate,
    with_sensor_gain,
)
from analysis.loop.runs import LoopRun, diverging_runs
from analysis.model.isolator import IsolatorModel
from analysis.model.terms import kind

BASE_FREE = ("k1", "k2", "c1", "c2", "alpha", "beta")
LINEAR = ("k1", "k2", "c1", "c2")
SOFTENING = ("k2", "c2")  # Eq 10's tanh terms' coefficients
NOISE_LEVEL = 1.05  # residual/noise at or below which the model is "at the noise"
UNEXPLAINED_LEVEL = 1.3  # residual/noise above which structure is left unexplained
ABSENT = 1e-6  # a nonlinear coefficient this fraction of its linear one: the term is absent
STOP = ("delta", "epsilon")  # dead band and stop velocity: freed, or held, together
SHAPE_CONSTANTS = ("alpha", "beta", *STOP)
ALPHA_MOVES = (0.25, 4.0)  # α times these: another spring's valley, for a start or a restart
# a dead band below this fraction of the prior's has been closed by the fit, which then
# lets c2 tanh(βż) carry a dry friction (`_reopened`)
DEAD_BAND_CLOSED = 0.1


def constants_present(model: IsolatorModel) -> list[str]:
    """The constants of Eq 10 the model has: a term fitted to nothing (k2 tanh(αz) at
    1e-8 N/m beside k1 at 1e5 N/m, where the base fit closed it) is absent, and its
    shape constant is not free either (its Jacobian column is nil, and the look-alike
    check read a cubic spring as α at correlation 1.000)."""
    p = model.parameters()
    free = [n for n in BASE_FREE if n in p and p[n] != 0.0]
    for coef, shape, base in (("k2", "alpha", "k1"), ("c2", "beta", "c1")):
        if coef in free and abs(p[coef]) <= ABSENT * abs(p.get(base, 0.0)):
            free = [n for n in free if n not in (coef, shape)]
    return free


def reidentify_candidates(h: Hypothesis, runs: Sequence[LoopRun],
                          scores: Sequence[tuple[Score, Candidate, Hypothesis]]
                          ) -> dict[str, Reidentified]:
    """Each force candidate identified by equation error with α, β, δ searched
    (`reidentify`), and under "" the model as it is, identified the same way."""
    if any(r.zd is None or r.xdd is None for r in runs) or any(
            kind(t.kind).has_state for t in h.model.terms):
        return {}  # a term with a state (added on an earlier step) is no regressor
    moving = moving_data([r.data.x - r.data.motion(r.data.t) for r in runs],
                         [r.zd for r in runs], [r.xdd for r in runs], h.model.stop_velocity,
                         runs[0].data.dt, [r.data.motion(r.data.t) for r in runs],
                         [r.data.motion.derivative()(r.data.t) for r in runs])
    if moving is None:
        return {}
    out = {"": base_projection(h.model, moving.data)}
    if not np.isfinite(out[""].sigma2) or out[""].sigma2 <= 0:
        return {}
    for s, c, cand_h in scores:
        again = (with_sensor_gain(cand_h.model, c, moving) if c.name == SENSOR_GAIN else
                 with_candidate(cand_h.model, c, s.name, moving))
        if again is not None:
            out[c.name] = again
    return out


def candidate_refit(fit: Fit, free: list[str], runs: Sequence[LoopRun], s: Score,
                    c: Candidate, cand_h: Hypothesis, again: Reidentified | None = None,
                    prior: Hypothesis | None = None,
                    progress: Callable[[str], None] = lambda message: None
                    ) -> tuple[Score, Candidate, Hypothesis, list[float], Fit]:
    """The candidate refitted with every free constant from its starts; the best of them.

    Appendix A's solution comes first, refitted to the end: it has no valleys, and where
    the refit from it reaches the noise, no other start is needed (on the confusion
    suite the scan's start then never ended more than 0.001 σ lower, and took up to 40
    iterations to get there). Otherwise a stateless effect is also started at the other
    shapes the library tries for it (`_other_shapes`), and the other starts are raced
    (`race`): the same start with the dead band and stop velocity held, the model
    identified again with the candidate in it, and the best size of a scan. That model
    with k2 tanh(αz) saturated at the dead band's edge, where equation error cannot
    tell it from the soft α it chose, is refitted to the end beside appendix A's start.
    Where the fit has closed the dead band, a stateless effect is also started at every
    shape from `prior`'s α, β, δ and ε (`_reopened`).
    """
    data = [r.data for r in runs]
    names = free + [s.name] + c.shape_parameters(cand_h.model)
    first = equation_error_start(cand_h, runs, {s.name: c})
    stateful = c.stateful
    if stateful:
        # the runs may each have been recorded from a fresh state (seals unloaded, fluid
        # cool): on unseen campaigns so made, a Bouc–Wen loop of the right shape fitted
        # at 5.7 x noise carried over from run to run, at 1.00 x started afresh. Appendix
        # A's start is refitted to the end both ways: raced, ten evaluations did not tell
        # them apart (an unseen thermal drift ended at 13.6 x, 1.00 x refitted afresh)
        first = [h for h0 in first for h in (h0, replace(h0, fresh_states=not h0.fresh_states))]
    fits = [refit_free(h0, data, names, {s.name: c}) for h0 in first]
    at_noise = [f for f in fits if f.residual_over_noise <= NOISE_LEVEL]
    if at_noise:
        return s, c, cand_h, [], min(at_noise, key=lambda f: f.rss)
    shaped = None if stateful else _other_shapes(fits, runs, s, c, cand_h, free)
    if shaped is not None and shaped[-1].residual_over_noise <= NOISE_LEVEL:
        return shaped
    if not stateful and (opened := _reopened(fits + ([shaped[-1]] if shaped else []), runs,
                                             s, c, cand_h, free, prior, progress)) is not None:
        if opened[-1].residual_over_noise <= NOISE_LEVEL:
            return opened
        shaped = opened  # lower than every refit before it
    entries = [(h0, _held(names)) for h0 in first if _held(names) != names]
    from_first = len(entries)  # both ways already, for a term with a state
    if again is not None:
        # the model identified again with the candidate in it, α, β and δ searched
        # (`reidentify`): the base fit's compromise never seen. The dead band is refitted
        # from there too: a base fit that closed it to mimic a dry friction cannot
        # open it again otherwise
        entries += _identified_entries(again, cand_h, names, s, c)
        if again.saturated is not None:
            # and at k2 tanh(αz) saturated at the dead band's edge, where equation error
            # cannot tell the two apart (`reidentify._saturated`): refitted to the end,
            # for ten evaluations leave it short of a valley it then reaches
            fits += [refit_free(h0, data, n, {s.name: c}) for h0, n in
                     _identified_entries(again.saturated, cand_h, names, s, c)]
    if stateful:
        entries += [(replace(h0, fresh_states=not h0.fresh_states), n)
                    for h0, n in entries[from_first:]]
    sizes = _starts(cand_h, data, s, c)
    entries += [(cand_h.with_values({s.name: v}), names) for v in sizes]
    if again is None and not c.term_kind:  # a sensor's lag: nothing identified it again
        # α elsewhere, the candidate at each size (`alpha_moved` says why)
        entries += [(h0.with_values({s.name: v}), names) for v in sizes
                    for h0 in alpha_moved(cand_h, names)]
    entries += [(h0, names) for h0 in _split_starts(cand_h, s.name, c)]
    best = min(fits + [race(entries, runs, {s.name: c})], key=lambda f: f.rss)
    if shaped is not None and shaped[-1].rss < best.rss:
        return shaped
    if c.free_shape:  # the shape it was refitted at, which a start may have chosen
        c = c.shaped(best.hypothesis.model.term(s.name).shape)
    return s, c, cand_h, sizes, best


def _identified_entries(again: Reidentified, cand_h: Hypothesis, names: list[str], s: Score,
                        c: Candidate) -> list[tuple[Hypothesis, list[str]]]:
    """Race entries from a model identified again with the candidate in it, both ways."""
    h0 = replace(cand_h, model=again.model).with_values(again.sensor)
    if again.fresh_states is not None:
        h0 = replace(h0, fresh_states=again.fresh_states)
    # the terms of Eq 10 are those the identification with the candidate finds: a
    # k2 tanh(αz) the base fit closed may come back beside a cubic spring
    # and the shape constants are those of the shape it chose (a drift's limit)
    chosen = c.shaped(again.model.term(s.name).shape) if c.term_kind else c
    own = list(dict.fromkeys([*constants_present(again.model),
                              *(n for n in names if n not in BASE_FREE
                                and n not in c.shape_parameters(cand_h.model)),
                              *chosen.shape_parameters(again.model), "delta"]))
    return [(h0, n) for n in _unique([own, _held(own)])]


def _other_shapes(fits: list[Fit], runs: Sequence[LoopRun], s: Score, c: Candidate,
                  cand_h: Hypothesis, free: list[str], own: bool = False
                  ) -> tuple[Score, Candidate, Hypothesis, list[float], Fit] | None:
    """The candidate at each other shape the library tries, from appendix A's start, the
    best of them where it beats `fits`; None where none does (a stateless effect's
    refit is cheap, and its shape searched as α, β, δ are).

    Equation error chooses a shape beside the base fit's terms, and a base fit's
    c2 tanh(βż) with β near 1/v_s is a friction built up over v_s outside the dead band:
    the step's column is the one that differs from it (an unseen friction of 4.1 kN
    built up over 6.2 mm/s named as a step and refitted to 5.4 x noise; started at
    2 mm/s, 1.39 x with v_s at 6.7 mm/s). `own`: the candidate's own shape too.
    """
    data = [r.data for r in runs]
    best_rss, found = min((f.rss for f in fits), default=np.inf), None
    for shape in c.shapes:
        if tuple(shape) == c.shape and not own:
            continue
        other = c.shaped(shape)
        model, name = other.add_to(cand_h.model)
        if name != s.name:
            continue  # the effect's parameter is another term's at this shape
        h = replace(cand_h, model=model)
        names = free + [s.name] + other.shape_parameters(model)
        for h0 in equation_error_start(h, runs, {s.name: other}):
            f = refit_free(h0, data, names, {s.name: other})
            if f.rss < best_rss:
                best_rss, found = f.rss, (s, other, h, [], f)
        if found is not None and found[-1].residual_over_noise <= NOISE_LEVEL:
            break
    return found


def _reopened(fits: list[Fit], runs: Sequence[LoopRun], s: Score, c: Candidate,
              cand_h: Hypothesis, free: list[str], prior: Hypothesis | None,
              progress: Callable[[str], None]
              ) -> tuple[Score, Candidate, Hypothesis, list[float], Fit] | None:
    """The candidate at each shape the library tries, from `prior`'s α, β, δ and ε with
    appendix A's coefficients at them, where the fit has closed the dead band
    (`DEAD_BAND_CLOSED`); the best where it beats `fits`, else None.

    A base fit can close the dead band and let c2 tanh(βż), steep in β, carry a dry
    friction of the seals. From there the friction's refit goes to nothing: the refits
    from the fit's α, β and ε stay in its valley, and the dead band, freed alone, opens
    to a compromise. The prior never saw the runs. An unseen one-sided damping with a
    4.6 kN friction, the damping named and the dead band at 0.03 mm (the generator's
    22.3): from the fit's constants, the friction refitted to nothing (11.5 x noise).
    From the prior's δ alone, 5.6 x at best (of a step and a 2 and a 6 mm/s build-up);
    with its ε too, 3.5 x; with its α, β, δ and ε, 1.000 x at either build-up (103 x as
    a step), every constant within 0.5 % of the generator's, the friction 4623 N
    against 4620.
    """
    if (prior is None or not c.term_kind
            or cand_h.model.dead_band >= DEAD_BAND_CLOSED * prior.model.dead_band):
        return None
    progress(f"loop: refitting with {c.name} from the prior's dead band, which the fit "
             f"closed ({1e3 * cand_h.model.dead_band:.2f} mm)")
    p = cand_h.model.parameters()
    start = cand_h.with_values({n: prior.value(n) for n in SHAPE_CONSTANTS if n in p})
    return _other_shapes(fits, runs, s, c, start, free, own=True)


def refit_from_start(start: Hypothesis, prior: Hypothesis | None, cf: Fit, h: Hypothesis,
                     free: list[str], s: Score, c: Candidate, sizes: list[float],
                     runs: Sequence[LoopRun], progress: Callable[[str], None]) -> Fit:
    """The best of the candidate's refit `cf` and refits from the loop's start models
    (`close_loop`): `start`, the model it was given, and for an effect with a state
    `prior` too."""
    lo, hi = c.bounds(h.model)
    values = [float(np.clip(s.predicted_value, lo, hi))]
    values += [v for v in sizes if _distinct(v, values)]
    per_start = [_from_start(start, h, free, s.name, values)]
    # the prior for an effect with a state only (a drift, a hysteresis), whose refits
    # from an absorbing fit stay furthest off: for a stateless one its lower refit at a
    # step led two unseen campaigns to worse ends (a friction 1.12 -> 3.84 x noise, a
    # one-sided spring then a drift 1.09 -> 8.75 x)
    if prior is not None and c.stateful:
        # a prior knows nothing of how the runs were recorded: each from a fresh state,
        # or carried over, both raced as in `candidate_refit` (an unseen thermal drift
        # from the report's constants: 85 x noise carried over, 1.02 x each run cool)
        per_start.append([h1 for h0 in _from_start(prior, h, free, s.name, values)
                          for h1 in (h0, replace(h0, fresh_states=not h0.fresh_states))])
    if not any(per_start):
        return cf
    progress(f"loop: refitting with {c.name} from the starting constants")
    names = free + [s.name] + c.shape_parameters(h.model)
    # a race per start model, and the lowest kept: the given model's race is then run
    # as without a prior, and a prior's entries cannot take the lead from it after ten
    # evaluations and end higher
    return min([cf] + [race(both_ways(entries, names), runs, {s.name: c})
                       for entries in per_start if entries], key=lambda f: f.rss)


def with_stop_freed(cf: Fit, free: Sequence[str], s: Score, c: Candidate,
                    runs: Sequence[LoopRun]) -> Fit | None:
    """The candidate's best refit `cf` refitted on with the dead band and stop velocity
    free too, where it ended above the noise with either held and that is lower and
    bounded; None otherwise. The judge takes it before `cf`, and `cf` where it is refused.

    The race frees them or holds them per start (`_held`), and the model identified
    again with the candidate in it frees the dead band only: a start that wins with the
    stop velocity held keeps the base fit's, which absorbed part of the effect. An
    unseen drift (cooling in 4.1 s) ended so at 10.5 x noise, ε at the base fit's
    19.4 mm/s; refitted on with it free, 2.07 x in 40 evaluations, ε 14.8 mm/s against
    the generator's 15.2 and τ 4.07 s against 4.08. Freed, they can also fit what the
    effect's shape misses in the runs fitted and lose the runs left out, and the judge's
    held-out check must then fall back on `cf`: a simulated Bouc-Wen loop with ε freed
    fell from 1.50 to 1.21 x noise and predicted runs B and C left out worse; kept
    alone, the judge refused it and named the Coulomb friction it resembles.
    """
    held = [n for n in STOP if n in free and n not in cf.names]
    if cf.residual_over_noise <= NOISE_LEVEL or not held:
        return None
    on = refit_free(cf.hypothesis, [r.data for r in runs], [*cf.names, *held], {s.name: c})
    return on if on.rss < cf.rss and not diverging_runs(on, runs) else None


RACE_NFEV = 10  # evaluations each raced start gets; the best then gets the rest of MAX_NFEV
# The run-through replaces the continued refit only where its residual sum of squares is
# more than 1 % below it. Two paths that end within a hair of each other sit in valleys
# a BLAS kernel's last bits choose between: on an unseen friction with a hardening spring
# they ended 0.08 % apart, in opposite order under Haswell and Sandybridge, and the cubic
# named next reached 1.05 x noise from one and 2.09 x from the other. On such a tie the
# continued refit is kept, on every machine. A margin of 20 % kept it where the run-through
# was the better path: an unseen drift then named a quadratic damping beside it under
# SkylakeX (9.5 x noise, against 10.5 x with the drift alone).
RUN_THROUGH_GAIN = 0.99


def race(entries: Sequence[tuple[Hypothesis, list[str]]], runs: Sequence[LoopRun],
          candidates: dict[str, Candidate]) -> Fit:
    """The best of several starts (hypothesis, free names), each given RACE_NFEV
    evaluations, refitted on from where it got to; where that stays above the noise,
    also from its start with all MAX_NFEV evaluations, and the lower is kept.

    The starts lie in different valleys of a cost that steps with every stick–slip
    event, and a start ten evaluations in is already in its valley: carried to the
    end, every start but the best one spent four times the simulations to lose (a
    campaign with the effect not in the library's shape ran them all, 64 of its 99 s).
    A restart where the race left it begins a new trust region and takes another
    path than the refit run through from its start would: an unseen thermal drift at
    50.9 x noise after ten evaluations stayed at 50 restarted and reached 1.33 x run
    through; three unseen stiffness effects ended lower restarted (1.76 against
    3.75 x, 1.62 against 3.34 x, 1.34 against 1.77 x). On a near-tie the continued
    refit is kept (`RUN_THROUGH_GAIN`).
    """
    data = [r.data for r in runs]
    short = [refit_free(h0, data, names, candidates, max_nfev=RACE_NFEV)
             for h0, names in entries]
    order = sorted(range(len(short)), key=lambda i: short[i].rss)
    # the lowest whose lone prediction stays bounded: a batch of rows can stay finite
    # where the one model it stands for runs away (`judge` refuses such a fit)
    best = next((i for i in order if not diverging_runs(short[i], runs)), order[0])
    if short[best].evaluations < RACE_NFEV:
        return short[best]  # converged within the race
    on = [refit_free(short[best].hypothesis, data, entries[best][1], candidates,
                     max_nfev=MAX_NFEV - RACE_NFEV)]
    if on[0].residual_over_noise > NOISE_LEVEL:
        # restarted where the race stopped it, the solver began a new trust region: run
        # through from its start it takes another path, and either may be the lower
        on.append(refit_free(entries[best][0], data, entries[best][1], candidates))
    bounded = [f for f in on if f.rss < short[best].rss and not diverging_runs(f, runs)]
    if len(bounded) == 2 and bounded[1].rss >= RUN_THROUGH_GAIN * bounded[0].rss:
        return bounded[0]
    return min(bounded, key=lambda f: f.rss) if bounded else short[best]


def alpha_moved(h: Hypothesis, free: Sequence[str]) -> list[Hypothesis]:
    """`h` with α a quarter and four times its own (`ALPHA_MOVES`), where α is among the
    `free` constants and k2 tanh(αz) acts: another spring's valley.

    A force candidate gets a start identified again with α searched (`reidentify`); a
    sensor's lag has no regressor there, and every other start keeps the α the base fit
    bent to mimic it. Unseen sensor delay 912 (2.2 ms, noise 2.8 times the rig's): the
    base fit's α 34 1/m against the generator's 56, the delay refitted from there
    stayed at 1.79–6.3 x noise wherever it started, from α 70 or 140 it reached 0.99 x
    (the generator's 2.18 ms to 0.1 %). The final fit's restarts move it so too
    (`polish`).
    """
    if "alpha" not in free or h.model.parameters().get("k2", 0.0) == 0.0:
        return []
    return [h.with_values({"alpha": f * h.value("alpha")}) for f in ALPHA_MOVES]


SPLIT = (0.3, 0.6, 0.9)  # fractions of the look-alike coefficient's force handed over


def _split_starts(h: Hypothesis, name: str, c: Candidate) -> list[Hypothesis]:
    """Starts with part of the force of the Eq 10 term the effect looks like handed to it.

    A base fit bends that term into the effect's shape (`Candidate.takes_over`), and
    output error from there cannot walk along the long valley where the two trade: on
    an unseen campaign with a 4.0 kN preload the base fit put k2 at 5.3 kN with α at
    101 1/m, the preload refitted from it stayed at 1.12 x noise with γ near nothing,
    and the truth (k2 1.3 kN, α 69 1/m, γ 4.0 kN) fits at 1.03 x.
    """
    if not c.takes_over or c.takes_over not in h.model.parameters():
        return []
    total = h.value(c.takes_over)
    lo, hi = c.bounds(h.model)
    return [h.with_values({c.takes_over: (1.0 - f) * total,
                           name: float(np.clip(f * abs(total), lo, hi))}) for f in SPLIT]


def _held(names: list[str]) -> list[str]:
    """`names` without the dead band and the stop velocity: each start is raced both ways.

    A base fit that absorbed an effect has moved the dead band and the stop velocity
    too, and only with them free does the effect's refit reach the noise (a hardening
    spring on an unseen campaign: 18.7 x noise with them held, 1.04 x free); along a
    stick–slip cliff, though, freeing them can walk into another valley.
    """
    return [n for n in names if n not in STOP]


def both_ways(starts: Sequence[Hypothesis], names: list[str]
              ) -> list[tuple[Hypothesis, list[str]]]:
    """Race entries: each start with `names` free, and with the dead band and the stop
    velocity held too (`_held`)."""
    return [(h0, n) for h0 in starts for n in _unique([names, _held(names)])]


def _unique(name_lists: Sequence[list[str]]) -> list[list[str]]:
    return [n for i, n in enumerate(name_lists) if n not in name_lists[:i]]


def _from_start(start: Hypothesis, h: Hypothesis, free: Sequence[str], name: str,
                values: Sequence[float]) -> list[Hypothesis]:
    """A start from the constants the loop was given, with the candidate at `value`.

    The base refit lets its constants soak up what the missing effect does (a force
    offset moves k1, k2 tanh(αz) and the damping to shift where the mass rests), and a
    refit from there with the effect added can stay in that valley: 16.7 σ for a
    181 N offset where the truth fits at 1.01 σ. The constants the loop started from
    never absorbed it. Effects added on earlier steps keep their fitted values.

    The candidate starts at the score's estimate and at the scan's best size (when they
    differ by more than a factor of two): along the offset the cost is rugged (where
    the mass rests against the dead band's edge moves in steps); on seed 1 a start at
    137.44 N ends at 1.19 σ, at 137.4386 N at 8.16 σ, at 30 N 1.35 σ, at 100 N 2.14 σ.
    """
    return [h.with_values({**constants, name: v}) for v in values
            for constants in constants_from(start, h, free)]


def constants_from(start: Hypothesis, h: Hypothesis, free: Sequence[str]) -> list[dict]:
    """Eq 10's constants among `free` as `start` has them, to put in `h`: α and β
    with the rest, and once more with the dead band and stop velocity from `start`
    too where its shape constants differ from `h`'s."""
    base = {n: start.value(n) for n in free if n in BASE_FREE}
    # δ and ε both as the base refit left them and as given: from the refit's a Bouc–Wen
    # refit stayed at 3.5 x noise (1.5 x from the given ones), a force offset's at 1.2 x
    # (4.2 x from the given ones)
    shapes = {n: start.value(n) for n in free if n in SHAPE_CONSTANTS}
    moved = any(shapes[n] != h.value(n) for n in shapes)
    return [base, {**base, **shapes}] if moved else [base]


SCAN = (0.3, 1.0, 3.0, 10.0, 30.0)  # multiples of the typical size tried as starts


def _distinct(v: float, others: Sequence[float]) -> bool:
    """True when size v differs from each of `others` by more than a factor of two."""
    return all(abs(v) > 2 * abs(o) or abs(o) > 2 * abs(v) for o in others)


def _starts(h: Hypothesis, data, s: Score, c: Candidate, keep: int = 1) -> list[float]:
    """Starts for a candidate's refit: the best `keep` of the score's estimate and a scan.

    Friction and dead band make the cost many-valleyed along an effect's size (where
    the mass sticks moves in steps), so one linearised estimate can start the refit in
    the wrong valley; one batch of simulations per run checks a few sizes, and the
    refit starts from the best (several: the best that differ by a factor of two).
    """
    lo, hi = c.bounds(h.model)
    signs = (c.sign,) if c.sign else (1.0, -1.0)
    trial = [s.predicted_value] + [g * m * c.typical(h.model) for g in signs for m in SCAN]
    trial = np.clip(np.array(trial, float), lo, hi)
    pred = predict(h, data, (s.name,), trial[:, None])
    with np.errstate(over="ignore", invalid="ignore"):
        cost = sum(np.sum(((p - d.x) / d.sigma_x) ** 2, axis=1) for p, d in zip(pred, data))
    cost = np.where(np.isfinite(cost), cost, np.inf)  # an unstable trial: damping gone negative
    starts: list[float] = []
    for i in np.argsort(cost):
        v = float(trial[i])
        if np.isfinite(cost[i]) and _distinct(v, starts):
            starts.append(v)
        if len(starts) == keep:
            break
    return starts or [0.0]


def _equation_error(h: Hypothesis, runs: Sequence[LoopRun], names: Sequence[str]):
    """Appendix A's least squares of the named coefficients (others fixed) on moving samples.

    Returns (names, values, residual sum of squares in N²), or None without measured
    derivatives or moving samples.
    """
    if any(r.zd is None or r.xdd is None for r in runs):
        return None
    model = h.model
    z = [r.data.x - r.data.motion(r.data.t) for r in runs]
    Z = campaign_regressors(model, z, [r.zd for r in runs], runs[0].data.dt)
    zd = np.concatenate([r.zd for r in runs])
    y = -model.mass * np.concatenate([r.xdd for r in runs])
    mask = moving(zd, model.stop_velocity)
    if mask is None:
        return None
    cols = [j for j, t in enumerate(model.terms) if t.name in names]
    fixed = [j for j in range(len(model.terms)) if j not in cols]
    known = Z[mask][:, fixed] @ np.array([model.terms[j].coef for j in fixed])
    A, b = Z[mask][:, cols], y[mask] - known
    coef, *_ = np.linalg.lstsq(A, b, rcond=None)
    rss = float(np.sum((b - A @ coef) ** 2))
    return [model.terms[j].name for j in cols], coef, rss


def equation_error_start(h: Hypothesis, runs: Sequence[LoopRun],
                         candidates: dict[str, Candidate]) -> list[Hypothesis]:
    """A start from appendix A's least squares with the candidates' regressors added
    (`candidates`, keyed by parameter).

    The fitted constants of the base model have soaked up what the missing effect
    did, and output error can stay in that valley; the equation-error solution of all
    linear coefficients together, from the measured z, ż, ẍ, has no valleys. Stateful
    terms are regressors too (`regressors.campaign_regressors`); sensor effects are not,
    and keep the values `h` gives them.
    """
    added = [n for n, c in candidates.items() if c.term_kind]
    if not added:
        return []
    names = [t.name for t in h.model.terms
             if t.name not in added and (t.name in LINEAR or t.coef != 0.0)] + added
    # with the softening terms held where the solution of all of them is no start: a
    # base fit with α small makes k2 tanh(αz) k1's twin, and the pair came out as
    # -317 and +114 kN/m beside an unseen thermal drift, whose refit from k1 and c1
    # solved alone with it reached the noise
    for held in ((), SOFTENING):
        solved = _equation_error(h, runs, [n for n in names if n not in held])
        if solved is None:
            return []
        values = dict(zip(solved[0], solved[1].tolist()))
        model = h.model.with_parameters(**values)  # bounds scale with the solved c1 and k1
        for n in added:
            values[n] = float(np.clip(values[n], *candidates[n].bounds(model)))
        if all(values[n] > 0 for n in LINEAR if n in values):
            return [h.with_values(values)]
    return []  # a negative stiffness or damping: not a start within the refit's bounds
