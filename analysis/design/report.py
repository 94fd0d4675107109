"""A design as text (in, lb, g, or SI) and as JSON (SI, with the designed model's block).

The JSON carries the designed isolator under `identified_model` in the schema of
analysis/model/model_json.py, so `sim response --model d.json --motion C` simulates
the design exactly as it simulates a fitted isolator.
"""

from __future__ import annotations

import numpy as np

from analysis.design.design import DesignResult
from analysis.design.sensitivity import MAX_DOWN, STEPS, Tolerance
from analysis.model.model_json import MODEL_KEY, model_json
from rig.units import from_si, us_unit

SCHEMA_VERSION = 1


def unit_of(result: DesignResult, name: str, units: str) -> str:
    si = result.model.units()[name]
    return us_unit(si) if units == "us" else si


def shown(value: float, unit_si: str, units: str) -> float:
    return float(from_si(value, us_unit(unit_si))) if units == "us" else float(value)


def accel_text(a: float, units: str) -> str:
    return f"{from_si(a, 'g'):.3f} g" if units == "us" else f"{a:.3f} m/s^2"


def stroke_text(z: float, units: str) -> str:
    return f"{from_si(z, 'in'):.3f} in" if units == "us" else f"{z:.4f} m"


def format_design(r: DesignResult, units: str = "us") -> str:
    """The verdict, the constants, the peaks, the tolerances and the cost."""
    mass = f"{from_si(r.model.mass, 'lbm'):.6g} lb" if units == "us" else f"{r.model.mass:.6g} kg"
    lines = [(f"design against {len(r.threats)} threat(s) ({', '.join(r.threats)}): stroke "
              f"within {stroke_text(r.limits.stroke, units)}, acceleration within "
              f"{accel_text(r.limits.accel, units)}; mass {mass}"),
             f"free: {', '.join(r.space.names)}; held: {_held(r, units)}", ""]
    lines += _verdict(r, units) + [""] + _constants(r, units) + [""] + _peaks(r, units)
    lines += [""] + _tolerances(r, units) + [""]
    parts = ", ".join(f"{k} {v}" for k, v in r.simulations.items())
    lines.append(f"{sum(r.simulations.values())} simulations ({parts}), "
                 f"{r.rounds} local rounds, {r.elapsed:.1f} s")
    return "\n".join(lines)


def _held(r: DesignResult, units: str) -> str:
    p = r.model.parameters()
    held = [f"{n} {shown(v, r.model.units()[n], units):.4g} {unit_of(r, n, units)}"
            for n, v in p.items() if n not in r.space.names and n != "m"]
    return ", ".join(held) or "nothing"


def _verdict(r: DesignResult, units: str) -> list[str]:
    a, z = r.archive.worst_accel, r.archive.worst_stroke
    o, lim = r.optimum, r.limits
    ideal = r.ideal_accel
    ideal_line = (f"the ideal isolator (Figure 1: a constant force over the stroke) needs "
                  f"{accel_text(ideal, units)} within {stroke_text(lim.stroke, units)}"
                  if np.isfinite(ideal) else
                  "the ideal isolator (Figure 1) cannot keep the stroke within the limit")
    if r.feasible:
        out = [(f"verdict: meets both limits: peak acceleration {accel_text(a[o], units)} "
                f"({100 * a[o] / lim.accel:.0f} % of the limit), peak stroke "
                f"{stroke_text(z[o], units)}"),
               f"  {ideal_line}: this design needs {a[o] / ideal:.2f} x that"
               if np.isfinite(ideal) and ideal > 0 else f"  {ideal_line}"]
    else:
        out = ["verdict: no isolator of this form (within the box) meets both limits"]
        if r.stroke_met:
            out.append(f"  within {stroke_text(lim.stroke, units)} the least peak "
                       f"acceleration is {accel_text(a[o], units)}: "
                       f"{100 * (a[o] / lim.accel - 1):.1f} % over the limit")
        else:
            out.append(f"  the least stroke any design in the box reaches is "
                       f"{stroke_text(z[o], units)}: {100 * (z[o] / lim.stroke - 1):.1f} % "
                       f"beyond the limit (at {accel_text(a[o], units)})")
        if r.closest is not None:
            c = r.closest
            factor = max(a[c] / lim.accel, z[c] / lim.stroke)
            out.append(f"  closest to both: {accel_text(a[c], units)} and "
                       f"{stroke_text(z[c], units)}; it meets both limits relaxed by "
                       f"{100 * (factor - 1):.1f} %")
        out.append(f"  {ideal_line}")
    high = [n for n, side in r.at_edge.items() if side == "high"]
    low = [n for n, side in r.at_edge.items() if side == "low"]
    if high:
        out.append(f"  at the top of its box: {', '.join(high)} (the box may hold the "
                   "design back: widen it with --bound NAME=LOW:HIGH)")
    if low:
        out.append(f"  at the bottom of its box: {', '.join(low)}")
    return out


def _constants(r: DesignResult, units: str) -> list[str]:
    cur, opt = r.archive.values[r.current], r.archive.values[r.optimum]
    head = f"{'constant':<10}{'unit':<12}{'current':>12}{'optimum':>12}   box"
    lines = [head]
    for j, b in enumerate(r.space.bounds):
        si = r.model.units()[b.name]
        row = [shown(v, si, units) for v in (cur[j], opt[j], b.low, b.high)]
        scale = " (log)" if b.log else ""
        lines.append(f"{b.name:<10}{unit_of(r, b.name, units):<12}{row[0]:>12.4g}"
                     f"{row[1]:>12.4g}   {row[2]:.4g} .. {row[3]:.4g}{scale}")
    return lines


def _peaks(r: DesignResult, units: str) -> list[str]:
    au, zu = ("g", "in") if units == "us" else ("m/s^2", "m")
    head = f"{'peaks':<22}{'current':>11}{'optimum':>11}   "
    lines = [head + "(1 ms, 8 substeps, 5 s tail: current, optimum)"]
    series = (("accel", r.archive.accel, au), ("stroke", r.archive.stroke, zu))
    for k, name in enumerate(r.threats):
        for label, arr, unit in series:
            shown_ = [arr[r.current, k], arr[r.optimum, k]] + [
                getattr(r.checked[w], label)[k] for w in ("current", "optimum")]
            v = [float(from_si(x, unit)) for x in shown_]
            lines.append(f"{f'{name}: {label} ({unit})':<22}{v[0]:>11.4f}{v[1]:>11.4f}"
                         f"   {v[2]:.4f}, {v[3]:.4f}")
    return lines


def _tolerances(r: DesignResult, units: str) -> list[str]:
    lines = [(f"tolerances, each constant alone (others at the optimum): the change that "
              f"keeps both limits, and the change that keeps both peaks within "
              f"{100 * r.tolerance:.0f} % of the optimum's")]
    lines.append(f"{'constant':<10}{'optimum':>12} {'unit':<11}{'limits met':<40}"
                 "peaks within")
    for t in r.tolerances:
        si = r.model.units()[t.name]
        lim = ("(the optimum misses a limit)" if t.limits is None else
               f"-{_pct(t.limits[0], MAX_DOWN)}{_by(t.crossed[0])} .. "
               f"+{_pct(t.limits[1], STEPS[-1])}{_by(t.crossed[1])}")
        lines.append(f"{t.name:<10}{shown(t.value, si, units):>12.4g} "
                     f"{unit_of(r, t.name, units):<11}{lim:<40}"
                     f"-{_pct(t.within[0], MAX_DOWN)} .. +{_pct(t.within[1], STEPS[-1])}")
    left_out = [n for n in r.space.names if n not in {t.name for t in r.tolerances}]
    if left_out:
        lines.append(f"(at 0, no relative tolerance: {', '.join(left_out)})")
    return lines


def _pct(x: float, tried: float) -> str:
    return f"over {100 * tried:.0f} %" if not np.isfinite(x) else f"{100 * x:.1f} %"


def _by(limit: str) -> str:
    return f" ({limit})" if limit else ""


def design_json(r: DesignResult) -> dict:
    """The result, SI, with the designed model's block under MODEL_KEY."""
    a, z = r.archive.worst_accel, r.archive.worst_stroke

    def point(i: int) -> dict:
        return {"constants": dict(zip(r.space.names, map(float, r.archive.values[i]))),
                "peak_accel": float(a[i]), "peak_stroke": float(z[i]),
                "by_threat": {name: {"accel": float(r.archive.accel[i, k]),
                                     "stroke": float(r.archive.stroke[i, k])}
                              for k, name in enumerate(r.threats)}}

    def checked(w: str) -> dict:
        c = r.checked[w]
        return {name: {"accel": float(c.accel[k]), "stroke": float(c.stroke[k])}
                for k, name in enumerate(r.threats)}

    f = r.front
    doc = {
        "schema_version": SCHEMA_VERSION, "units": "SI", "threats": list(r.threats),
        "limits": {"accel": r.limits.accel, "stroke": r.limits.stroke},
        "mass": r.model.mass, "feasible": r.feasible, "stroke_met": r.stroke_met,
        "box": {b.name: {"low": b.low, "high": b.high, "log": b.log} for b in r.space.bounds},
        "current": point(r.current) | {"checked": checked("current")},
        "optimum": point(r.optimum) | {"checked": checked("optimum")},
        "closest": None if r.closest is None else point(r.closest),
        "at_edge": r.at_edge,
        "ideal": {"accel_at_stroke_limit": _finite(r.ideal_accel),
                  "force": r.ideal.force.tolist(), "accel": r.ideal.accel.tolist(),
                  "stroke": r.ideal.stroke.tolist()},
        "pareto_front": {"accel": a[f].tolist(), "stroke": z[f].tolist(),
                         "constants": r.archive.values[f].tolist()},
        "tolerance_level": r.tolerance,
        "tolerances": [_tolerance_json(t) for t in r.tolerances],
        "simulations": dict(r.simulations), "elapsed_s": r.elapsed,
    }
    return {"design": doc, MODEL_KEY: model_json(
        r.designed, source=f"analysis design against {', '.join(r.threats)}")}


def _tolerance_json(t: Tolerance) -> dict:
    return {"name": t.name, "value": t.value,
            "limits": None if t.limits is None else [_finite(x) for x in t.limits],
            "crossed": list(t.crossed), "within": [_finite(x) for x in t.within]}


def _finite(x: float) -> float | None:
    """JSON has no infinity: None stands for 'beyond every change tried'."""
    return float(x) if np.isfinite(x) else None
