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
- it predicts better what the fit has not seen: the held-out records (EMPS: the
  pulse record) or, without them, the last quarter of each record from a fit on
  the first three quarters; the held-out sum of squares must fall by at least
  1 %: of the force error by default, of the simulated position with
  `validation="simulation"` (output benchmarks such as Silverbox).

Of those passing the first three, the one with the largest cut is validated
first; the first that validates is added. The loop stops when none does, or
after `max_effects`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

from analysis.force_driven.model import CANDIDATES, MASS, term
from analysis.force_driven.prepare import Prepared
from rig.errors import DataError

P_VALUE = 1e-3
MIN_DROP = 0.02  # of the residual sum of squares
MAX_CORRELATION = 0.99
HELDOUT_GAIN = 0.01  # the held-out sum of squares must fall by this fraction
MAX_LAG = 20
MAX_EFFECTS = 4
ESTIMATION_SHARE = 0.75  # without held-out records: fit on this leading share of each record
VALIDATIONS = ("force", "simulation")


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
           rows: Sequence[slice] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
              rows: Sequence[slice] | None = None) -> TermFit:
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


def predict(fit: TermFit, records: Sequence[Prepared], rows: Sequence[slice] | None = None
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


@dataclass
class _Validation:
    """Where a candidate's prediction is checked: held-out records, or the tail of each record.

    `kind` "force" scores the relative force error there (equation error, any data);
    "simulation" simulates the position there from the measured force and scores its RMS
    (m): the check for output benchmarks, where a term can cut the equation error by
    fitting derivative noise yet make the simulated motion worse (Silverbox: q̇|q̇|).
    """

    records: Sequence[Prepared]
    heldout: Sequence[Prepared] = ()
    kind: str = "force"
    fit_rows: list[slice] | None = None
    test_rows: list[slice] | None = None
    text: str = ""

    @property
    def measure(self) -> str:
        return "relative force error" if self.kind == "force" else "simulation RMS error (m)"

    def error(self, names: Sequence[str], mass: float | None) -> tuple[float, float]:
        """(sum of squares, error in `measure`) of a fit of `names` on what is held out."""
        fit = fit_terms(self.records, names, mass, None if self.heldout else self.fit_rows)
        if self.kind == "simulation":
            return self._simulated(fit)
        if self.heldout:
            resid, force = predict(fit, self.heldout)
        else:
            resid, force = predict(fit, self.records, self.test_rows)
        ss = float(resid @ resid)
        return ss, float(np.sqrt(ss) / np.linalg.norm(force))

    def _simulated(self, fit: TermFit) -> tuple[float, float]:
        from analysis.force_driven.simulate import SKIP, initial_state, simulate_position

        ss, n = 0.0, 0
        spans = ([(p, p.start, p.start + p.q.size) for p in self.heldout] if self.heldout else
                 [(p, p.record_index(r.start), p.start + p.q.size)
                  for p, r in zip(self.records, self.test_rows or [])])
        for p, a, b in spans:
            rec = p.record
            q0, v0 = initial_state(rec.position[a:b], rec.dt)
            try:
                q = simulate_position(fit.parameters(), rec.force[a:b], rec.dt, q0, v0)
            except ValueError:  # no positive mass: not a model that can be simulated
                return float("inf"), float("inf")
            e = q[SKIP:] - rec.position[a + SKIP:b]
            if not np.all(np.isfinite(e)):
                return float("inf"), float("inf")
            ss, n = ss + float(e @ e), n + e.size
        return ss, float(np.sqrt(ss / max(n, 1)))


def _validation(records: Sequence[Prepared], heldout: Sequence[Prepared],
                kind: str) -> _Validation:
    if kind not in VALIDATIONS:
        raise ValueError(f"unknown validation {kind!r} (known: {', '.join(VALIDATIONS)})")
    if heldout:
        return _Validation(records, heldout, kind,
                           text="held-out records " + ", ".join(p.name for p in heldout))
    fit_rows, test_rows = [], []
    for p in records:
        cut = int(ESTIMATION_SHARE * p.rows)
        fit_rows.append(slice(0, cut))
        test_rows.append(slice(cut, None))
    return _Validation(records, (), kind, fit_rows, test_rows,
                       text=f"the last {100 * (1 - ESTIMATION_SHARE):.0f} % of each record, "
                            f"predicted from a fit on the first {100 * ESTIMATION_SHARE:.0f} %")


def close_force_loop(records: Sequence[Prepared], base: Sequence[str], mass: float | None = None,
                     heldout: Sequence[Prepared] = (), candidates: Sequence[str] | None = None,
                     max_effects: int = MAX_EFFECTS, validation: str = "force") -> ForceLoop:
    """Fit the base terms, then add candidates while the data ask for them (module doc).

    `validation` is "force" (held-out relative force error) or "simulation" (held-out
    simulated position, for data whose figure of merit is the simulated output).
    """
    names = list(base)
    pool = [c for c in (candidates if candidates is not None else CANDIDATES) if c not in names]
    check = _validation(records, heldout, validation)
    fit = fit_terms(records, names, mass)
    first, steps, refused = fit, [], []
    held_ss, held_err = check.error(names, mass)
    first_held = held_err
    while len(steps) < max_effects and pool:
        ranked, why = _significant(fit, records, names, pool, mass)
        refused.extend({"round": len(steps) + 1, **w} for w in why)
        added = None
        for cand, trial, evidence in ranked:
            ss, err = check.error(names + [cand], mass)
            change = f"{check.measure} {_show(held_err, check.kind)} -> {_show(err, check.kind)}"
            evidence["heldout"] = f"{check.text}: {change}"
            if not ss <= (1 - HELDOUT_GAIN) * held_ss:
                refused.append({"round": len(steps) + 1, "candidate": cand,
                                "reason": f"does not predict held-out data better by "
                                          f"{100 * HELDOUT_GAIN:.0f} % of the sum of "
                                          f"squares ({change})"})
                continue
            t = term(cand)
            value, std = trial.value(cand), float(trial.std[trial.names.index(cand)])
            steps.append(AddedEffect(cand, t.parameter, value, std, t.unit, evidence,
                                     fit.relative_error, trial.relative_error, held_err, err))
            added, fit, held_ss, held_err = cand, trial, ss, err
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
                     first_held, held_err, unexplained, text)


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
