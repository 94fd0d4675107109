"""The lot as a family: which units are out of it and why, each constant's spread, and
the lot's average.

A unit is out of family when

* its constants lie beyond the lot's robust distance (`distance`), judged on the
  constants most units determined (one a unit held is put at the lot's median: it
  says nothing either way); with fewer than `MIN_JUDGED` fitted units there is no
  family to differ from and constants are not judged;
* the loop named an effect in it that at most half the fitted units have (three units
  of forty with Coulomb friction: worn seals);
* it lacks an effect more than half the units have: the family's own effect.

Structure the loop found in a unit's residual but could not name is a note beside the
unit, not a verdict: it says the unit's model is not the whole story, not that the
unit differs from the others (a unit whose constants it moved is caught by them).

The spread (mean, standard deviation, coefficient of variation) is over the units in
family, the lot as it is meant to be; the same over every fitted unit is kept beside
it. The lot's average model is Eq 10 with the family's mean constants: effects are
compared by presence, not averaged.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from analysis.identify.pipeline import REFINED
from analysis.lot.distance import robust_distances
from analysis.lot.unit import UnitResult

MIN_JUDGED = 5
DETERMINED = 0.5  # a constant is judged where more than this share of the units estimated it
NAMED_Z = 3.0  # a constant named in a unit's reason: beyond this many robust σ
UNEXPLAINED = "unexplained residual"


@dataclass(frozen=True)
class Spread:
    """One constant over a set of units (SI): over those that estimated it."""

    name: str
    unit: str
    n: int  # units that estimated it
    held: int  # units that held it at the start value
    mean: float
    std: float  # nan with fewer than two
    low: float
    high: float

    @property
    def cv(self) -> float:
        return self.std / abs(self.mean) if self.mean else float("nan")


@dataclass(frozen=True)
class Verdict:
    """One fitted unit against the lot."""

    in_family: bool
    reasons: tuple[str, ...] = ()
    distance2: float | None = None
    z: dict[str, float] = field(default_factory=dict)  # judged constant → robust σ
    notes: tuple[str, ...] = ()  # worth a look, not a verdict (unexplained residual)


@dataclass(frozen=True)
class Family:
    verdicts: dict[str, Verdict]  # fitted unit → its verdict
    spread: dict[str, Spread]  # over the units in family
    spread_all: dict[str, Spread]  # over every fitted unit
    effects: dict[str, int]  # effect → fitted units that have it
    common: tuple[str, ...]  # the family's own effects (more than half the units)
    judged: tuple[str, ...]  # the constants in the robust distance
    method: str  # "ogk", "mad" or "" (constants not judged: too few units)
    threshold: float | None

    @property
    def in_family(self) -> list[str]:
        return [u for u, v in self.verdicts.items() if v.in_family]

    @property
    def out_of_family(self) -> list[str]:
        return [u for u, v in self.verdicts.items() if not v.in_family]

    @property
    def average(self) -> dict[str, float]:
        """The lot's average constants (SI): the family's means (every fitted unit's where
        no unit is in family)."""
        spread = self.spread or self.spread_all
        return {n: s.mean for n, s in spread.items() if np.isfinite(s.mean)}


def judge_lot(results: Sequence[UnitResult]) -> Family:
    """Judge every fitted unit (failed ones are not judged) against the others."""
    fitted = [r for r in results if r.ok]
    traits = {r.unit: set(r.effects) for r in fitted}
    named = sorted(set().union(*traits.values()))
    counts = {e: sum(e in t for t in traits.values()) for e in named}
    half = len(fitted) / 2
    common = tuple(e for e, k in counts.items() if k > half)
    reasons: dict[str, list[str]] = {r.unit: [] for r in fitted}
    for r in fitted:
        for e in sorted(traits[r.unit] - set(common)):
            reasons[r.unit].append(_has(r, e, counts[e], len(fitted)))
        for e in common:
            if e not in traits[r.unit]:
                reasons[r.unit].append(f"lacks {e}, which {counts[e]} of {len(fitted)} "
                                       "units have")
    judged = tuple(n for n in REFINED if sum(_estimated(r, n) for r in fitted)
                   > DETERMINED * len(fitted))
    method, threshold, d2, zs = "", None, {}, {}
    if len(fitted) >= MIN_JUDGED and judged:
        d = robust_distances(*_matrix(fitted, judged))
        method, threshold = d.method, d.threshold
        for i, r in enumerate(fitted):
            d2[r.unit] = float(d.d2[i])
            zs[r.unit] = {n: float(d.z[i, j]) for j, n in enumerate(judged)}
            if d.outside[i]:
                reasons[r.unit].append(_far(zs[r.unit], d2[r.unit], d.threshold, d.method))
    verdicts = {r.unit: Verdict(not reasons[r.unit], tuple(reasons[r.unit]),
                                d2.get(r.unit), zs.get(r.unit, {}), _notes(r)) for r in fitted}
    members = [r for r in fitted if verdicts[r.unit].in_family]
    return Family(verdicts, spreads(members), spreads(fitted), counts, common, judged, method,
                  threshold)


def _estimated(r: UnitResult, name: str) -> bool:
    return name in r.constants and r.constants[name].estimated


def _matrix(fitted: Sequence[UnitResult], names: Sequence[str]
            ) -> tuple[np.ndarray, np.ndarray]:
    """values, stds (units × constants); a held constant at the lot's median, std 0."""
    V = np.array([[r.constants[n].value if _estimated(r, n) else np.nan for n in names]
                  for r in fitted])
    S = np.array([[r.constants[n].std if _estimated(r, n) else 0.0 for n in names]
                  for r in fitted])
    median = np.nanmedian(V, axis=0)
    return np.where(np.isnan(V), median, V), S


def _notes(r: UnitResult) -> tuple[str, ...]:
    if not r.unexplained:
        return ()
    worst = max(r.residual_over_noise.values(), default=float("nan"))
    note = (f"{UNEXPLAINED}: up to {worst:.2f} x noise in a run, no effect of the library "
            "explains it")
    return (note,)


def _has(r: UnitResult, effect: str, count: int, n: int) -> str:
    share = f"{count} of {n} units"
    e = r.effects[effect]
    size = f"{e.value:.4g}" + (f" ± {e.std:.2g}" if e.std is not None else "") + f" {e.unit}"
    return f"{effect} {size} ({share})"


def _far(z: dict[str, float], d2: float, threshold: float, method: str) -> str:
    named = sorted((n for n in z if abs(z[n]) > NAMED_Z), key=lambda n: -abs(z[n]))[:3]
    what = (", ".join(f"{n} {z[n]:+.1f} σ" for n in named) if named else
            "no one constant beyond 3 σ: their combination")
    return f"constants off the lot's: {what} (distance² {d2:.1f} > {threshold:.1f}, {method})"


def spreads(units: Sequence[UnitResult]) -> dict[str, Spread]:
    """Each constant of REFINED over the units (the estimated values; where no unit
    estimated it, the value they held)."""
    out = {}
    for n in REFINED:
        have = [r.constants[n] for r in units if n in r.constants]
        if not have:
            continue
        est = [e.value for e in have if e.estimated]
        v = np.array(est or [e.value for e in have])
        out[n] = Spread(n, have[0].unit, len(est), len(have) - len(est), float(v.mean()),
                        float(v.std(ddof=1)) if v.size > 1 else float("nan"),
                        float(v.min()), float(v.max()))
    return out
