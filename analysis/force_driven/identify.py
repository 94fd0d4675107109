"""Least squares on the force balance, and the stepwise loop that adds effects.

`fit_terms` solves F − m q̈ (m known) or F (m identified) = Φ θ by ordinary least
squares on the prepared (filtered, decimated) rows of one or more records. The
standard deviations are the benchmark's: σ̂ √diag((ΦᵀΦ)⁻¹), σ̂² = RSS/(n − p).
The error is the benchmark's relative force error ‖F − F̂‖/‖F‖ on the same rows.

`close_force_loop` is forward stepwise selection over the candidates of
`model.CANDIDATES`. Each round refits the model with each candidate not yet in
it, and a candidate may be added only if

- it is significant: the partial F-test of the added column at p < 0.001. The
  equation-error residual is coloured (unmodelled dynamics, filtered noise), so
  test counts n / (1 + 2 Σ ρ_k) samples (ρ_k the residual's autocorrelation,
  lags 1…20) instead of n: n correlated samples carry fewer independent ones;
- it matters: it cuts the residual sum of squares by at least 2 % (≈ 1 % of the
  RMS), the isolator loop's rule;
- it is not a look-alike of a term already in: |correlation| of the estimates
  < 0.99;
- it predicts better what the fit has not seen. What is held out is the
  held-out records (EMPS: the pulse record), or else each of 4 contiguous
  stretches of every record in turn, predicted from a fit on the other three
  (blocked cross-validation; the fit also leaves out 20 rows, the residual's
  correlation length, on each side of the stretch, so that it cannot lean on
  its neighbours). Measured as the force error by default, or as the simulated
  position with `validation="simulation"` (output benchmarks such as
  Silverbox), the candidate must
  - cut the held-out sum of squares, all folds pooled, by at least 1 %;
  - cut it in most folds (3 of 4): one stretch that a term happens to fit
    must not carry it, as a single split of the record lets it;
  - not raise it by more than 1 % for either direction of motion (q̇ > 0,
    q̇ ≤ 0). A force that is in the system predicts better whichever way the
    mass moves; a term that only moves the error from one direction to the
    other stands for a direction-dependent effect it does not have the shape
    of (EMPS: a spring k_pos max(q, 0) that predicts the backward strokes 6 %
    better and the forward strokes 3 % worse). Within 1 %: a term that acts in
    one direction only leaves the other direction's sum of squares to chance.
  With held-out records there is one fold, so the first rule carries the second.

Of those passing the first three, the one with the largest cut is validated
first; the first that validates is added. The loop stops when none does, or
after `max_effects`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

from analysis.force_driven.model import CANDIDATES, MASS, VISCOUS, term
from analysis.force_driven.prepare import Prepared
from rig.errors import DataError

P_VALUE = 1e-3
MIN_DROP = 0.02  # of the residual sum of squares
MAX_CORRELATION = 0.99
HELDOUT_GAIN = 0.01  # the held-out sum of squares must fall by this fraction
MAX_LAG = 20
MAX_EFFECTS = 4
FOLDS = 4  # without held-out records: blocked cross-validation over this many stretches
FOLD_GAP = MAX_LAG  # rows kept out of the fit beside the predicted stretch (module doc)
VALIDATIONS = ("force", "simulation")
DIRECTIONS = ("forwards (q' > 0)", "backwards (q' <= 0)")  # HeldOutScore.cells' columns
Rows = slice | np.ndarray  # one record's rows: a slice, or the indices of several stretches


@dataclass(frozen=True)
class TermFit:
    """θ for `names` by least squares: values, std, covariance, and the force error."""

    names: tuple[str, ...]
    values: np.ndarray
    std: np.ndarray
    covariance: np.ndarray
    condition: float
    rss: float
    n: int
    force_norm: float  # ‖F‖ over the same rows, N
    residual: np.ndarray  # F − F̂ (decimated rows, records concatenated), N
    mass: float | None  # the known mass (kg), None when identified

    @property
    def relative_error(self) -> float:
        """The benchmark's ‖F − F̂‖/‖F‖ (fraction)."""
        return float(np.sqrt(self.rss) / self.force_norm)

    @property
    def sigma(self) -> float:
        return float(np.sqrt(self.rss / max(self.n - len(self.names), 1)))

    @property
    def correlation(self) -> np.ndarray:
        d = np.sqrt(np.diag(self.covariance))
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.covariance / np.outer(d, d)

    def value(self, name: str) -> float:
        if name == MASS and self.mass is not None:
            return self.mass
        return float(self.values[self.names.index(name)])

    def parameters(self) -> dict[str, float]:
        """Every term's coefficient by term name (the known mass included)."""
        out = {MASS: self.mass} if self.mass is not None else {}
        out.update({n: float(v) for n, v in zip(self.names, self.values)})
        return out


def design(records: Sequence[Prepared], names: Sequence[str], mass: float | None,
           rows: Sequence[Rows] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Φ, the left-hand side (F − m q̈ or F) and F, stacked over records (selected rows)."""
    phis, lhs, force = [], [], []
    for i, p in enumerate(records):
        s = rows[i] if rows is not None else slice(None)
        y = p.y[s]
        phis.append(np.column_stack([p.column(n)[s] for n in names]) if names
                    else np.zeros((y.size, 0)))
        lhs.append(y - mass * p.column(MASS)[s] if mass is not None else y)
        force.append(y)
    return np.vstack(phis), np.concatenate(lhs), np.concatenate(force)


def fit_terms(records: Sequence[Prepared], names: Sequence[str], mass: float | None = None,
              rows: Sequence[Rows] | None = None) -> TermFit:
    """Ordinary least squares of the force balance for the terms `names`."""
    names = tuple(names)
    if mass is not None and MASS in names:
        raise ValueError("the mass is either known or a term to fit, not both")
    phi, lhs, force = design(records, names, mass, rows)
    n, p = phi.shape
    if n <= p:
        raise DataError(f"{n} rows for {p} parameters: record too short after decimation")
    theta, *_ = np.linalg.lstsq(phi, lhs, rcond=None)
    resid = lhs - phi @ theta
    rss = float(resid @ resid)
    sv = np.linalg.svd(phi, compute_uv=False)
    condition = float(sv[0] / sv[-1]) if sv.size and sv[-1] > 0 else float("inf")
    cov = rss / max(n - p, 1) * np.linalg.pinv(phi.T @ phi)
    return TermFit(names, theta, np.sqrt(np.clip(np.diag(cov), 0, None)), cov, condition, rss,
                   n, float(np.linalg.norm(force)), resid, mass)


def predict(fit: TermFit, records: Sequence[Prepared], rows: Sequence[Rows] | None = None
            ) -> tuple[np.ndarray, np.ndarray]:
    """(F − F̂, F) of `fit` on other records (or rows): the cross-test of the benchmark."""
    phi, lhs, force = design(records, fit.names, fit.mass, rows)
    return lhs - phi @ fit.values, force


def relative_error(fit: TermFit, records: Sequence[Prepared]) -> float:
    """‖F − F̂‖/‖F‖ of `fit` on `records` (fraction)."""
    resid, force = predict(fit, records)
    return float(np.linalg.norm(resid) / np.linalg.norm(force))


def inflation(residual: np.ndarray) -> float:
    """1 + 2 Σ ρ_k over lags 1..MAX_LAG (≥ 1): how much a coloured residual overstates n."""
    r = residual - residual.mean()
    den = float(r @ r)
    if den == 0:
        return 1.0
    rho = [float(r[k:] @ r[:-k]) / den for k in range(1, min(MAX_LAG, r.size - 1) + 1)]
    return max(1.0, 1.0 + 2.0 * float(np.sum(rho)))


def ljung_box_p(residual: np.ndarray) -> float:
    """p-value of the Ljung–Box test of whiteness over lags 1..MAX_LAG."""
    r = residual - residual.mean()
    n = r.size
    den = float(r @ r)
    if den == 0 or n <= MAX_LAG + 1:
        return 1.0
    rho = np.array([float(r[k:] @ r[:-k]) / den for k in range(1, MAX_LAG + 1)])
    q = n * (n + 2) * float(np.sum(rho**2 / (n - np.arange(1, MAX_LAG + 1))))
    return float(stats.chi2.sf(q, MAX_LAG))


@dataclass(frozen=True)
class AddedEffect:
    """One effect added: its estimate, the evidence, and the force errors around it."""

    added: str
    parameter: str
    value: float
    std: float
    unit: str
    evidence: dict[str, object]
    error_before: float  # relative force error on the identification records
    error_after: float
    heldout_before: float  # on the held-out rows, in the loop's `heldout_measure`
    heldout_after: float


@dataclass(frozen=True)
class ForceLoop:
    """The loop's result: base and final fits, the steps, what was refused, what remains."""

    base: TermFit
    final: TermFit
    steps: tuple[AddedEffect, ...]
    refused: tuple[dict[str, object], ...]
    heldout: str  # what the validation used
    heldout_measure: str  # relative force error, or simulation RMS error (m)
    heldout_before: float
    heldout_after: float
    unexplained: bool
    description: str

    @property
    def effects_added(self) -> list[str]:
        return [s.added for s in self.steps]


@dataclass(frozen=True)
class Fold:
    """One held-out check: fit on `fit_rows` of each record (None: all), predict `test`."""

    fit_rows: tuple[Rows, ...] | None
    test: tuple[tuple[Prepared, slice], ...]  # (record, its rows) predicted


@dataclass(frozen=True)
class HeldOutScore:
    """A model's prediction of what is held out: sums of squares by fold and by direction of
    motion (`cells[fold]` = [q̇ > 0, q̇ ≤ 0]), and the error over all of it."""

    cells: np.ndarray  # (folds, 2)
    error: float  # in the check's `measure`, everything held out pooled

    @property
    def ss(self) -> float:
        return float(self.cells.sum())

    @property
    def fold_ss(self) -> np.ndarray:
        return self.cells.sum(axis=1)

    @property
    def direction_ss(self) -> np.ndarray:
        return self.cells.sum(axis=0)


@dataclass
class _Validation:
    """Where a candidate's prediction is checked: held-out records, or folds of the records.

    `kind` "force" scores the relative force error there (equation error, any data);
    "simulation" simulates the position there from the measured force and scores its RMS
    (m): the check for output benchmarks, where a term can cut the equation error by
    fitting derivative noise yet make the simulated motion worse (Silverbox: q̇|q̇|).
    """

    records: Sequence[Prepared]
    folds: Sequence[Fold]
    kind: str = "force"
    text: str = ""

    @property
    def measure(self) -> str:
        return "relative force error" if self.kind == "force" else "simulation RMS error (m)"

    def score(self, names: Sequence[str], mass: float | None) -> HeldOutScore:
        """Fit `names` without each fold and predict the fold; pool the folds."""
        cells, scale = [], 0.0
        for fold in self.folds:
            fit = fit_terms(self.records, names, mass, fold.fit_rows)
            ss, weight = (_simulated(fit, fold.test) if self.kind == "simulation"
                          else _force(fit, fold.test))
            cells.append(ss)
            scale += weight
        table = np.array(cells, float)
        total = float(table.sum())
        error = float(np.sqrt(total / scale)) if np.isfinite(total) and scale > 0 else np.inf
        return HeldOutScore(table, error)

    def earns_place(self, before: HeldOutScore, after: HeldOutScore) -> str | None:
        """None if `after` predicts what is held out better (module doc), else why not."""
        change = (f"{self.measure} {_show(before.error, self.kind)} -> "
                  f"{_show(after.error, self.kind)}")
        if not after.ss <= (1 - HELDOUT_GAIN) * before.ss:
            return (f"does not predict held-out data better by {100 * HELDOUT_GAIN:.0f} % of "
                    f"the sum of squares ({change})")
        better, folds = _folds_better(before, after), before.cells.shape[0]
        if 2 * better <= folds:
            return (f"predicts held-out data better in only {better} of {folds} folds "
                    f"({change} pooled)")
        for direction, ratio in zip(DIRECTIONS, _direction_ratios(before, after)):
            if ratio > 1 + HELDOUT_GAIN:
                return (f"predicts held-out data worse while moving {direction}: sum of "
                        f"squares x{ratio:.3f} there ({change} overall)")
        return None


def _folds_better(before: HeldOutScore, after: HeldOutScore) -> int:
    return int(np.sum(after.fold_ss < before.fold_ss))


def _direction_ratios(before: HeldOutScore, after: HeldOutScore) -> np.ndarray:
    """Held-out sum of squares after / before, for q̇ > 0 and q̇ ≤ 0 (1 where none)."""
    b, a = before.direction_ss, after.direction_ss
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(b > 0, a / b, 1.0)


def _by_direction(e: np.ndarray, velocity: np.ndarray) -> list[float]:
    """[Σ e² where q̇ > 0, Σ e² where q̇ ≤ 0]."""
    up = velocity > 0
    return [float(e[up] @ e[up]), float(e[~up] @ e[~up])]


def _force(fit: TermFit, test: Sequence[tuple[Prepared, slice]]) -> tuple[list[float], float]:
    """(Σ (F − F̂)² by direction of motion, Σ F²) of `fit` on the test rows."""
    records, rows = [p for p, _ in test], [s for _, s in test]
    resid, force = predict(fit, records, rows)
    velocity = np.concatenate([p.column(VISCOUS)[s] for p, s in test])
    return _by_direction(resid, velocity), float(force @ force)


def _simulated(fit: TermFit, test: Sequence[tuple[Prepared, slice]]
               ) -> tuple[list[float], float]:
    """(Σ (q_sim − q)² by direction of motion, samples scored) of `fit` simulated over each
    test stretch."""
    from analysis.force_driven.simulate import SKIP, initial_state, simulate_position

    ss, n = np.zeros(2), 0
    failed = [float("inf"), float("inf")], 1.0
    for p, rows in test:
        a, b = _record_span(p, rows)
        rec = p.record
        q0, v0 = initial_state(rec.position[a:b], rec.dt)
        try:
            q = simulate_position(fit.parameters(), rec.force[a:b], rec.dt, q0, v0)
        except ValueError:  # no positive mass: not a model that can be simulated
            return failed
        e = q[SKIP:] - rec.position[a + SKIP:b]
        if not np.all(np.isfinite(e)):
            return failed
        ss += _by_direction(e, p.qd[a + SKIP - p.start:b - p.start])
        n += e.size
    return list(ss), float(n)


def _record_span(p: Prepared, rows: slice) -> tuple[int, int]:
    """[a, b) in the record of the full-rate samples that decimated `rows` stand for."""
    a = p.start if rows.start is None else p.record_index(rows.start)
    end = p.start + p.q.size
    b = end if rows.stop is None or rows.stop >= p.rows else p.record_index(rows.stop)
    return a, b


def blocked_folds(records: Sequence[Prepared], k: int) -> list[Fold]:
    """k folds; fold j predicts the j-th of k contiguous stretches of every record from a
    fit on the rest, less FOLD_GAP rows on each side of the stretch (fewer in a short
    record: at most a quarter of a stretch, so that the fit keeps most of the rest)."""
    if k < 2:
        raise ValueError(f"cross-validation needs at least 2 folds, got {k}")
    folds = []
    for j in range(k):
        fit_rows, test = [], []
        for p in records:
            edges = np.linspace(0, p.rows, k + 1).round().astype(int)
            a, b = int(edges[j]), int(edges[j + 1])
            gap = min(FOLD_GAP, p.rows // (4 * k))
            fit_rows.append(np.r_[0:max(a - gap, 0), min(b + gap, p.rows):p.rows])
            test.append((p, slice(a, b)))
        folds.append(Fold(tuple(fit_rows), tuple(test)))
    return folds


def _validation(records: Sequence[Prepared], heldout: Sequence[Prepared],
                kind: str, folds: int) -> _Validation:
    if kind not in VALIDATIONS:
        raise ValueError(f"unknown validation {kind!r} (known: {', '.join(VALIDATIONS)})")
    if heldout:
        whole = Fold(None, tuple((p, slice(None)) for p in heldout))
        return _Validation(records, [whole], kind,
                           text="held-out records " + ", ".join(p.name for p in heldout))
    return _Validation(records, blocked_folds(records, folds), kind,
                       text=f"blocked {folds}-fold cross-validation, each of {folds} "
                            "contiguous stretches of each record predicted from a fit on "
                            "the rest")


def close_force_loop(records: Sequence[Prepared], base: Sequence[str], mass: float | None = None,
                     heldout: Sequence[Prepared] = (), candidates: Sequence[str] | None = None,
                     max_effects: int = MAX_EFFECTS, validation: str = "force",
                     folds: int = FOLDS) -> ForceLoop:
    """Fit the base terms, then add candidates while the data ask for them (module doc).

    `validation` is "force" (held-out relative force error) or "simulation" (held-out
    simulated position, for data whose figure of merit is the simulated output); `folds`
    is the number of blocked cross-validation folds used when no `heldout` is given.
    """
    names = list(base)
    pool = [c for c in (candidates if candidates is not None else CANDIDATES) if c not in names]
    check = _validation(records, heldout, validation, folds)
    fit = fit_terms(records, names, mass)
    first, steps, refused = fit, [], []
    held = first_held = check.score(names, mass)
    while len(steps) < max_effects and pool:
        ranked, why = _significant(fit, records, names, pool, mass)
        refused.extend({"round": len(steps) + 1, **w} for w in why)
        added = None
        for cand, trial, evidence in ranked:
            score = check.score(names + [cand], mass)
            evidence["heldout"] = (f"{check.text}: {check.measure} "
                                   f"{_show(held.error, check.kind)} -> "
                                   f"{_show(score.error, check.kind)}")
            evidence["heldout_folds"] = {"better": _folds_better(held, score),
                                         "folds": int(score.cells.shape[0]),
                                         "ss_before": held.cells.tolist(),
                                         "ss_after": score.cells.tolist()}
            reason = check.earns_place(held, score)
            if reason is not None:
                refused.append({"round": len(steps) + 1, "candidate": cand, "reason": reason})
                continue
            t = term(cand)
            value, std = trial.value(cand), float(trial.std[trial.names.index(cand)])
            steps.append(AddedEffect(cand, t.parameter, value, std, t.unit, evidence,
                                     fit.relative_error, trial.relative_error, held.error,
                                     score.error))
            added, fit, held = cand, trial, score
            cut = evidence["rss_drop"]
            refused.extend({"round": len(steps), "candidate": c,
                            "reason": f"passes, but {cand} cuts more "
                                      f"({100 * e['rss_drop']:.1f} % < {100 * cut:.1f} % of "
                                      "the residual sum of squares)"}
                           for c, _, e in ranked if c != cand and e["rss_drop"] <= cut)
            break
        if added is None:
            break
        names.append(added)
        pool.remove(added)
    white_p = ljung_box_p(fit.residual)
    unexplained = white_p < P_VALUE
    text = (f"relative force error {100 * fit.relative_error:.3f} %; the residual is "
            + ("white" if not unexplained else
               f"not white (Ljung-Box p = {white_p:.2g}): structure no candidate explains "
               f"remains, {_band_text(fit, records)}"))
    return ForceLoop(first, fit, tuple(steps), tuple(refused), check.text, check.measure,
                     first_held.error, held.error, unexplained, text)


def _show(value: float, kind: str) -> str:
    return f"{100 * value:.3f} %" if kind == "force" else f"{value:.4g} m"


def _significant(fit: TermFit, records: Sequence[Prepared], names: list[str],
                 pool: Sequence[str], mass: float | None):
    """Candidates that pass the F-test, the 2 % cut and the look-alike check, best first."""
    passed, why = [], []
    infl = inflation(fit.residual)
    for cand in pool:
        trial = fit_terms(records, names + [cand], mass)
        drop = (fit.rss - trial.rss) / fit.rss if fit.rss > 0 else 0.0
        dof = max(trial.n / infl - len(trial.names), 1.0)
        f_stat = (fit.rss - trial.rss) / (trial.rss / dof) if trial.rss > 0 else np.inf
        p = float(stats.f.sf(f_stat, 1, dof)) if np.isfinite(f_stat) else 0.0
        j = trial.names.index(cand)
        corr = np.nan_to_num(np.abs(np.delete(trial.correlation[j], j)), nan=1.0)
        evidence = {"statistic": "partial F (1 dof), residual autocorrelation counted",
                    "F": float(f_stat), "p": p, "variance_inflation": infl,
                    "rss_drop": float(drop), "explanation": term(cand).explanation}
        if p >= P_VALUE:
            why.append({"candidate": cand, "reason": f"not significant: p = {p:.2g}"})
        elif drop < MIN_DROP:
            why.append({"candidate": cand,
                        "reason": f"cuts the residual sum of squares by only "
                                  f"{100 * drop:.2f} % (< {100 * MIN_DROP:.0f} %)"})
        elif corr.size and corr.max() > MAX_CORRELATION:
            other = [n for n in trial.names if n != cand][int(np.argmax(corr))]
            why.append({"candidate": cand,
                        "reason": f"a look-alike of {other}: correlation {corr.max():.3f}"})
        else:
            passed.append((cand, trial, evidence))
    passed.sort(key=lambda c: -c[2]["rss_drop"])
    return passed, why


def _band_text(fit: TermFit, records: Sequence[Prepared]) -> str:
    from analysis.loop.evidence import band_power

    dt = records[0].record.dt * records[0].settings.factor
    power = band_power([fit.residual], dt)
    top = max(power, key=power.get)
    return f"{100 * power[top]:.0f} % of its power in {top}"
