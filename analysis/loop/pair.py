"""Two effects equation error named together, confirmed together by output error.

The loop refits one named effect at a time. Where two effects are in the data, each
alone can fail where the two together fit: on an independent generator's campaign of
Coulomb friction with a hardening spring (each 24 % of the peak force), equation error
named the friction, then the cubic, but the friction refitted alone, with the cubic's
force left for Eq 10's constants to mimic, was not significant (|t| 0.1) and the loop
named nothing at 14.9 x the noise. So when the top name is refused alone and equation
error's forward selection named a second one with it, the pair is refitted together,
from the two lone refits' constants and from appendix A's solution with both columns,
and each of the two is judged against the model with the other one only (refitted from
the pair's constants): significant, explaining at least a noise RMS, no look-alike, and
predicting held-out runs better. Both pass, or neither is named.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

from analysis.loop.candidate_fit import both_ways, equation_error_start, race
from analysis.loop.candidates import Candidate
from analysis.loop.evidence import Diagnosis, diagnose_fit
from analysis.loop.judge import MIN_DROP, WITHOUT_NFEV, make_step, own_parameters, why_refused
from analysis.loop.refit import Fit, Hypothesis, Score, refit_free
from analysis.loop.result import Step
from analysis.loop.runs import LoopRun, diverging_runs
from analysis.loop.validation import held_out


def pair_step(fit: Fit, free: list[str], runs: Sequence[LoopRun], diag: Diagnosis,
              members: Sequence[tuple[Score, Candidate, Hypothesis, Fit | None]],
              progress: Callable[[str], None]
              ) -> tuple[tuple[tuple[Step, Step], Fit] | None, list[dict[str, object]]]:
    """The two `members` (score, candidate, hypothesis with it, its lone refit or None)
    refitted together and judged (`diag`: the diagnosis of `fit`): ((step, step), fit with
    both) or None, and the refusals."""
    data = [r.data for r in runs]
    (sa, ca, _, fa), (sb, cb, _, fb) = members
    label = f"{ca.name} with {cb.name}"
    progress(f"loop: refitting with {label} together")
    model, _ = ca.add_to(cb.add_to(fit.hypothesis.model)[0])
    h = replace(fit.hypothesis, model=model)
    cands = {sa.name: ca, sb.name: cb}
    names = list(dict.fromkeys(free + [sa.name, sb.name] + ca.shape_parameters(model)
                               + cb.shape_parameters(model)))
    sizes = {sa.name: _size(sa, ca, fa, h), sb.name: _size(sb, cb, fb, h)}
    starts = [h.with_values(sizes)]
    for lone in (fa, fb):
        if lone is not None:  # a lone refit's constants, the other member at its size
            # (and its runs' states: carried over, or each run started afresh)
            h_lone = replace(h, fresh_states=lone.hypothesis.fresh_states)
            starts.append(h_lone.with_values({**dict(zip(lone.names, lone.values.tolist())),
                                              **{n: v for n, v in sizes.items()
                                                 if n not in lone.names}}))
    starts += equation_error_start(h.with_values(sizes), runs, cands)
    both = race(both_ways(starts, names), runs, cands)
    if away := diverging_runs(both, runs):
        return None, [{"candidate": label, "reason": "their fit drives run "
                       f"{', '.join(away)} unstable: the prediction runs away"}]
    if not both.rss < (1.0 - MIN_DROP) * fit.rss:
        return None, [{"candidate": label, "reason": "together they cut the residual by "
                       f"{100 * (1 - both.rss / fit.rss):.1f} % (< {100 * MIN_DROP:.0f} %)"}]
    refused: list[dict[str, object]] = []
    alone: dict[str, tuple[Fit, dict[str, object]]] = {}
    for (s, c), (so, co) in (((sa, ca), (sb, cb)), ((sb, cb), (sa, ca))):
        keep = [n for n in both.names if n not in own_parameters(both, s.name)]
        other = refit_free(both.hypothesis.with_values({s.name: 0.0}), data, keep,
                           {so.name: co}, max_nfev=WITHOUT_NFEV)
        reason = why_refused(other, both, s.name, f" over {co.name} alone")
        if not reason:
            progress(f"loop: validating {c.name} beside {co.name} on held-out runs")
            held = held_out(other, both, keep, s.name, c, runs)
            if not held["accepted"]:
                reason = "does not predict held-out runs better: " + str(held["text"])
            alone[s.name] = (other, held)
        if reason:
            refused.append({"candidate": label, "reason": f"{c.name}: {reason}"})
    if refused:
        return None, refused
    # named in equation error's order: the first with the model it had alone, the second
    # on top of it
    with_a, held_a = alone[sb.name][0], alone[sa.name][1]
    held_b = alone[sb.name][1]
    first = make_step(diag, sa, ca, fit, with_a, held_a, runs)
    second = make_step(diagnose_fit(with_a, runs), sb, cb, with_a, both, held_b, runs)
    return ((first, second), both), []


def _size(s: Score, c: Candidate, lone: Fit | None, h: Hypothesis) -> float:
    """A member's starting size: its lone refit's, else the score's estimate (in bounds)."""
    if lone is not None:
        return lone.param(s.name)[0]
    lo, hi = c.bounds(h.model)
    return min(max(s.predicted_value, lo), hi)
