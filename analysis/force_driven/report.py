"""The force-driven loop as a person reads it (table, steps) and as JSON.

The JSON keys mirror analysis/identify/report_format.py `fit_json` (`parameters`,
`model`) and analysis/loop/report.py `loop_json` (`loop`, `effects_added`,
`error_before`, `error_after`, `unexplained`), so a reader of either layout finds
the same names. Errors are fractions (the benchmark's ‖F − F̂‖/‖F‖); text shows %.
"""

from __future__ import annotations

import numpy as np

from analysis.force_driven.identify import AddedEffect, ForceLoop, TermFit
from analysis.force_driven.model import MASS, term
from analysis.force_driven.prepare import Prepared


def parameters_json(fit: TermFit) -> dict[str, dict[str, object]]:
    """{parameter: {value, std, unit, term, held}}; a known mass is held (std None)."""
    out: dict[str, dict[str, object]] = {}
    if fit.mass is not None:
        out["m"] = {"value": fit.mass, "std": None, "unit": "kg", "term": MASS, "held": True}
    for name, value, std in zip(fit.names, fit.values, fit.std):
        t = term(name)
        out[t.parameter] = {"value": float(value), "std": float(std), "unit": t.unit,
                            "term": name, "held": False}
    return out


def model_json(fit: TermFit) -> list[dict[str, object]]:
    names = ([MASS] if fit.mass is not None else []) + list(fit.names)
    return [{"name": n, "parameter": term(n).parameter, "formula": term(n).formula,
             "explanation": term(n).explanation} for n in names]


def _step_json(s: AddedEffect) -> dict[str, object]:
    return {"added": s.added, "parameter": s.parameter,
            "value": {"value": s.value, "std": s.std, "unit": s.unit},
            "evidence": s.evidence, "error_before": s.error_before,
            "error_after": s.error_after, "heldout_error_before": s.heldout_before,
            "heldout_error_after": s.heldout_after}


def force_loop_json(loop: ForceLoop, records: list[Prepared]) -> dict[str, object]:
    """The machine-readable result (SI; errors as fractions)."""
    return {
        "layout": "force-driven",
        "convention": "F = m q'' + sum theta_k phi_k(q, q'): every term resists the force",
        "parameters": parameters_json(loop.final),
        "parameters_base_model": parameters_json(loop.base),
        "error_definition": "||F - F_hat|| / ||F|| on the filtered, decimated rows, i.e. "
                            "over 0 to records.*.band_hz: compare with a figure measured "
                            "over the same band",
        "error_band_hz": _band(records),
        "error_before": loop.base.relative_error,
        "error_after": loop.final.relative_error,
        "heldout": {"what": loop.heldout, "measure": loop.heldout_measure,
                    "error_before": loop.heldout_before,
                    "error_after": loop.heldout_after},
        "effects_added": loop.effects_added,
        "loop": [_step_json(s) for s in loop.steps],
        "refused": list(loop.refused),
        "unexplained": {"value": loop.unexplained, "description": loop.description},
        "model": model_json(loop.final),
        "records": {p.name: {"rows": p.rows, "force_column": p.record.force_column,
                             "position_column": p.record.position_column,
                             "dt_s": p.record.dt, **p.settings.as_dict()} for p in records},
    }


def format_parameters(fit: TermFit) -> list[str]:
    rows = [("parameter", "value", "± std", "unit", "term")]
    for name, entry in parameters_json(fit).items():
        std = "(given)" if entry["std"] is None else f"± {entry['std']:.3g}"
        rows.append((name, f"{entry['value']:.6g}", std, str(entry["unit"]), str(entry["term"])))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return ["  " + "  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]


def format_force_loop(loop: ForceLoop, records: list[Prepared]) -> str:
    """Records, base fit, each step with its evidence and errors, final parameters."""
    lines = ["force-driven fit: F = m q'' + sum of resisting terms"]
    for p in records:
        s = p.settings
        lines.append(f"  {p.name}: force {p.record.force_column}, position "
                     f"{p.record.position_column}, {p.record.t.size} samples at "
                     f"{1 / p.record.dt:.6g} Hz; Butterworth {s.cutoff_hz:.4g} Hz, "
                     f"{s.method} derivatives, decimated by {s.factor} -> {p.rows} rows "
                     f"(band 0-{s.band_hz:.4g} Hz)")
    lines.append(f"base model ({', '.join(_base_names(loop.base))}): relative force error "
                 f"{_pct(loop.base.relative_error)}")
    lines.extend(format_parameters(loop.base))
    lines.append("closing the loop")
    for i, s in enumerate(loop.steps, 1):
        ev = s.evidence
        lines.append(f"  step {i}: added {s.added} {s.parameter} = {s.value:.4g} ± {s.std:.2g} "
                     f"{s.unit}")
        folds = ev["heldout_folds"]
        lines.append(f"    evidence: F = {ev['F']:.1f} (p = {ev['p']:.2g}), residual cut "
                     f"{100 * ev['rss_drop']:.1f} %; held out: {ev['heldout']}"
                     + (f", better in {folds['better']} of {folds['folds']} folds"
                        if folds["folds"] > 1 else ""))
        lines.append(f"    why: {ev['explanation']}")
        lines.append(f"    relative force error {_pct(s.error_before)} -> {_pct(s.error_after)}")
    if not loop.steps:
        lines.append("  no candidate effect was significant")
    last = len(loop.steps) + 1
    for r in (r for r in loop.refused if r["round"] == last):
        lines.append(f"  not added: {r['candidate']}: {r['reason']}")
    lines.append(f"  final: {loop.description}")
    if loop.unexplained:
        lines.append("  UNEXPLAINED STRUCTURE: no effect in the library accounts for it")
    held = (_pct if loop.heldout_measure.startswith("relative") else _metres)
    lines.append(f"final model: relative force error {_pct(loop.base.relative_error)} -> "
                 f"{_pct(loop.final.relative_error)}; held out ({loop.heldout}): "
                 f"{loop.heldout_measure} {held(loop.heldout_before)} -> "
                 f"{held(loop.heldout_after)}")
    band = _band(records)
    if band is not None:
        lines.append(f"  the force error is over 0-{band:.4g} Hz, the band kept: a figure over "
                     "another band (another --decimate or --cutoff) does not compare with it")
    lines.extend(format_parameters(loop.final))
    return "\n".join(lines)


def _band(records: list[Prepared]) -> float | None:
    """The band every record keeps (Hz), or None without records or when they differ."""
    bands = {p.settings.band_hz for p in records}
    return bands.pop() if len(bands) == 1 else None


def _base_names(fit: TermFit) -> list[str]:
    return ([MASS + " (given)"] if fit.mass is not None else []) + list(fit.names)


def _metres(x: float) -> str:
    return f"{x:.4g} m" if np.isfinite(x) else "n/a"


def _pct(x: float) -> str:
    return f"{100 * x:.3f} %" if np.isfinite(x) else "n/a"
