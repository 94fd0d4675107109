"""The lot for people (text tables, the report's units) and programs (JSON, SI)."""

from __future__ import annotations

import math

import numpy as np

from analysis.identify.pipeline import REFINED
from analysis.lot.average import average_model
from analysis.lot.family import Spread
from analysis.lot.schedule import LotResult
from analysis.lot.unit import UnitResult
from analysis.model.model_json import MODEL_KEY, model_json
from rig.units import from_si, us_unit


def us_value(value: float, si_unit: str) -> tuple[float, str]:
    u = us_unit(si_unit)
    return float(from_si(value, u)), u


def format_lot(lot: LotResult) -> str:
    """The summary line, the spread of each constant, one row per unit, the verdicts."""
    return "\n\n".join([_headline(lot), format_spread(lot), format_units(lot),
                        format_verdicts(lot)])


def _headline(lot: LotResult) -> str:
    f, units = lot.family, lot.units.values()
    fitted = sum(r.ok for r in units)
    how = {"ogk": "Mahalanobis distance under a robust (OGK) covariance",
           "mad": "robust z-score of each constant (median, MAD), squares summed",
           "": "not judged: fewer than 5 units fitted"}[f.method]
    kept = len(lot.units) - len(lot.fitted)
    return (f"lot of {len(lot.units)} units: {fitted} fitted, {len(lot.units) - fitted} failed; "
            f"{len(f.in_family)} in family, {len(f.out_of_family)} out of family\n"
            f"constants: {how}" + (f", out beyond distance² {f.threshold:.1f}"
                                   if f.threshold is not None else "") + "\n"
            f"fitted in this run: {len(lot.fitted)}; kept from an earlier run: {kept}")


def format_spread(lot: LotResult) -> str:
    f = lot.family
    spread = f.spread or f.spread_all
    over = (f"the {len(f.in_family)} units in family" if f.spread
            else "every fitted unit (none in family)")
    lines = [f"constants over {over} (the report's units; SI in the JSON)",
             (f"{'constant':<10}{'unit':<8}{'mean':>11}{'std':>11}{'CV':>9}{'min':>11}"
              f"{'max':>11}  estimated by")]
    for s in spread.values():
        lines.append(_spread_row(s))
    return "\n".join(lines)


def _spread_row(s: Spread) -> str:
    mean, unit = us_value(s.mean, s.unit)
    if s.n == 0:
        return (f"{s.name:<10}{unit:<8}{mean:>11.4g}  held by every unit (not determined "
                "by the runs)")
    std, low, high = (us_value(v, s.unit)[0] for v in (s.std, s.low, s.high))
    cv = f"{100 * s.cv:.2f} %" if math.isfinite(s.cv) else "—"
    std_text = f"{std:.3g}" if math.isfinite(std) else "—"
    return (f"{s.name:<10}{unit:<8}{mean:>11.4g}{std_text:>11}{cv:>9}{low:>11.4g}{high:>11.4g}"
            f"  {s.n}" + (f" ({s.held} held)" if s.held else ""))


def format_units(lot: LotResult) -> str:
    """One row per unit: status, effects, residual/noise (own fit and the lot average's,
    worst run), each constant's deviation from the lot's average."""
    average = lot.family.average
    names = [n for n in REFINED if n in lot.family.judged]
    lines = [("per unit: residual/noise of its own fit and of the lot average (worst run), "
              "constants off the lot's average (%)"),
             f"{'unit':<14}{'status':<8}{'own':>6}{'lot avg':>9}  "
             + "".join(f"{n:>8}" for n in names) + "  effects"]
    for name, r in lot.units.items():
        if not r.ok:
            lines.append(f"{name:<14}{'failed':<8}  {r.reason}")
            continue
        own = max(r.residual_over_noise.values(), default=float("nan"))
        pred = lot.predictions.get(name)
        avg = (max(e["residual_over_noise"] for e in pred.values()) if pred else float("nan"))
        cells = "".join(_deviation(r, n, average) for n in names)
        lines.append(f"{name:<14}{'ok':<8}{own:>6.2f}{avg:>9.1f}  {cells}  "
                     + (", ".join(r.effects) or "-"))
    return "\n".join(lines)


def _deviation(r: UnitResult, name: str, average: dict[str, float]) -> str:
    e = r.constants.get(name)
    if e is None or not e.estimated or not average.get(name):
        return f"{'held':>8}"
    return f"{100 * (e.value / average[name] - 1):>+8.2f}"


def format_verdicts(lot: LotResult) -> str:
    f = lot.family
    lines = ["out of family:" if f.out_of_family else "out of family: none"]
    for u in f.out_of_family:
        lines.append(f"  {u}: " + "; ".join(f.verdicts[u].reasons))
    noted = [u for u, v in f.verdicts.items() if v.notes]
    lines.append("notes:" if noted else "notes: none")
    lines.extend(f"  {u}: " + "; ".join(f.verdicts[u].notes) for u in noted)
    bad = [r for r in lot.units.values() if not r.ok]
    lines.append("failed:" if bad else "failed: none")
    lines.extend(f"  {r.unit}: {r.reason}" for r in bad)
    lines.extend(f"  {u}: no prediction by the lot average: {why}"
                 for u, why in lot.problems.items())
    return "\n".join(lines)


def lot_json(lot: LotResult, kept_in: dict[str, str] | None = None) -> dict:
    """The lot as JSON (SI); `kept_in`: unit → the file its result is kept in."""
    f = lot.family
    units = {}
    for name, r in lot.units.items():
        doc = {k: v for k, v in r.to_json().items() if k != "fit"}
        v = f.verdicts.get(name)
        doc.update({"in_family": None if v is None else v.in_family,
                    "reasons": [] if v is None else list(v.reasons),
                    "distance2": None if v is None else v.distance2,
                    "notes": [] if v is None else list(v.notes),
                    "z": {} if v is None else v.z,
                    "lot_average": lot.predictions.get(name),
                    "lot_average_problem": lot.problems.get(name),
                    "result_file": (kept_in or {}).get(name)})
        units[name] = doc
    fitted = [r for r in lot.units.values() if r.ok]
    out = {
        "lot": {"units": len(lot.units), "fitted": len(fitted),
                "in_family": f.in_family, "out_of_family": f.out_of_family,
                "failed": [r.unit for r in lot.units.values() if not r.ok],
                "fitted_in_this_run": list(lot.fitted)},
        "spread": {"family": {n: _spread_json(s) for n, s in f.spread.items()},
                   "all_fitted": {n: _spread_json(s) for n, s in f.spread_all.items()}},
        "average": f.average,
        "effects": {"counts": f.effects, "family": list(f.common)},
        "distance": {"method": f.method, "constants": list(f.judged),
                     "threshold": f.threshold},
        "units": units,
    }
    if fitted and f.average:
        mass = float(np.median([r.mass for r in fitted]))
        out[MODEL_KEY] = _average_model_json(lot, mass)
    return _finite(out)


def _spread_json(s: Spread) -> dict:
    return {"unit": s.unit, "mean": s.mean, "std": s.std, "cv": s.cv, "min": s.low,
            "max": s.high, "estimated_by": s.n, "held_by": s.held}


def _average_model_json(lot: LotResult, mass: float) -> dict:
    """The lot average as `sim response --model` reads it, its covariance the spread of
    the constants across the family's units (a draw is a unit of the lot, not an error
    bar of one fit)."""
    f = lot.family
    members = [lot.units[u] for u in f.in_family] or [r for r in lot.units.values() if r.ok]
    names = [n for n in f.average if all(n in r.constants and r.constants[n].estimated
                                         for r in members)]
    cov = None
    if len(members) > 1 and names:
        cov = np.atleast_2d(np.cov([[r.constants[n].value for n in names] for r in members],
                                   rowvar=False))
    return model_json(average_model(f.average, mass), names if cov is not None else (), cov,
                      source=f"lot average of {len(members)} units; covariance: the spread "
                             "across units")


def _finite(x: object) -> object:
    """NaN and infinities as null: JSON has neither."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    return x
