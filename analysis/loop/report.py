"""The loop's result for people and programs: text, JSON and evidence figures."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from analysis.identify.output_error import Z95
from analysis.identify.report_format import fit_json
from analysis.loop.refit import Fit
from analysis.loop.result import LoopResult, Step
from analysis.model.model_json import MODEL_KEY, covariance_from, model_json
from rig.units import from_si, us_unit

if TYPE_CHECKING:  # the pipeline's type only (as in `runs`)
    from analysis.identify.pipeline import IsolatorFit

# the model's own term coefficients are reported with the loop's effects
UNIT_OF_SENSOR = {"sensor_gain": "1", "sensor_delay": "s"}


def parameters_json(fit: Fit) -> dict[str, dict[str, float | str | None]]:
    """Every parameter of the final hypothesis: value (SI), std where fitted, unit."""
    model = fit.hypothesis.model
    units = model.units()
    out: dict[str, dict[str, float | str | None]] = {}
    for name, value in model.parameters().items():
        out[name] = {"value": value, "std": None, "unit": units[name]}
    for name, unit in UNIT_OF_SENSOR.items():
        value = fit.hypothesis.value(name)
        if value != 0.0 or name in fit.names:
            out[name] = {"value": value, "std": None, "unit": unit}
    for name, value, std in zip(fit.names, fit.values, fit.std):
        out[name]["value"] = float(value)
        out[name]["std"] = float(std) if np.isfinite(std) else None
    return out


def loop_json(result: LoopResult) -> dict[str, object]:
    """The loop's JSON: `loop`, `effects_added`, `error_before`, `error_after`, …"""
    return {
        "loop": [_step_json(s) for s in result.steps],
        "effects_added": result.effects_added,
        "error_before": result.error_before,
        "error_after": result.error_after,
        "residual_before": result.diagnosis_before.as_dict(),
        "residual_after": result.diagnosis_after.as_dict(),
        "unexplained": {"value": result.unexplained, "description": result.description},
        "refused": list(result.refused),
        "conditioning": [c.as_dict() for c in result.conditioning],
        "parameters": parameters_json(result.final),
    }


def _step_json(s: Step) -> dict[str, object]:
    return {"added": s.added, "parameter": s.parameter,
            "value": {"value": s.value, "std": s.std, "unit": s.unit},
            "evidence": s.evidence, "error_before": s.error_before,
            "error_after": s.error_after}


def format_loop(result: LoopResult, units: str = "us") -> str:
    """Closing the loop, as a person reads it: each step with its evidence and errors
    (the errors as the fit's table defines them, forces in `units`)."""
    lines = ["closing the loop",
             f"  base model: residual {result.diagnosis_before.residual_over_noise:.2f} x sensor "
             f"noise, {'white' if result.diagnosis_before.white else 'not white'} "
             f"(Ljung-Box p = {result.diagnosis_before.ljung_box_p:.2g})"]
    for i, s in enumerate(result.steps, 1):
        ev = s.evidence
        lines.append(f"  step {i}: added {s.added} {s.parameter} = {s.value:.4g} ± {s.std:.2g} "
                     f"{s.unit}")
        lines.append(f"    evidence: score χ²₁ = {ev['value']:.1f}, residual cut "
                     f"{100 * ev['rss_drop']:.1f} %, t = {ev['t']:.1f}; held out: {ev['heldout']}")
        lines.append(f"    why: {ev['explanation']}")
        lines.extend("    " + row for row in _error_rows(s.error_before, s.error_after, units))
    if not result.steps:
        lines.append("  no candidate effect was significant")
    for c in result.indistinguishable:
        lines.append(f"  not testable with these runs: {c.candidate} — "
                     f"{100 * (1 - c.unique_fraction):.2f} % of its force pattern is the "
                     f"model's own {', '.join(c.like)} (variance inflation "
                     f"{c.variance_inflation:.0f})")
    lines.append(f"  final: {result.description}")
    if result.unexplained:
        lines.append("  UNEXPLAINED STRUCTURE: no effect in the library accounts for it")
    lines.append("  before -> after, per run:")
    lines.extend("    " + row for row in _error_rows(result.error_before, result.error_after,
                                                       units))
    return "\n".join(lines)


def _error_rows(before: dict, after: dict, units: str = "us") -> list[str]:
    f_unit = "N" if units == "si" else "lb"
    rows = []
    for run in before:
        b, a = before[run], after[run]
        cells = [f"{label} {100 * b[k]:.2f} -> {100 * a[k]:.2f} %"
                 for k, label in (("z", "z"), ("zd", "ż"), ("xdd", "ẍ")) if k in b]
        if "force_rms" in b:
            fb, fa = (float(from_si(b["force_rms"], f_unit)), float(from_si(a["force_rms"],
                                                                            f_unit)))
            cells.append(f"force RMS {fb:.1f} -> {fa:.1f} {f_unit}")
        cells.append(f"residual/noise {b['residual_over_noise']:.2f} -> "
                     f"{a['residual_over_noise']:.2f}")
        rows.append(f"run {run}: NRMSE " + ", ".join(cells))
    return rows


# the variable a step's residual is plotted against: its name and SI unit
SIGNATURE = {"z": ("relative displacement z", "m"), "zd": ("relative velocity ż", "m/s"),
             "t": ("time over the campaign", "s"), "x": ("mass displacement x", "m"),
             "xd": ("mass velocity ẋ", "m/s")}


def loop_figures(result: LoopResult, out: Path, units: str = "si") -> list[Path]:
    """One PNG per step: the residual before it against the variable that exposed it
    (that variable in `units`: "si", or "us" for the report's in and in/s)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, s in enumerate(result.steps, 1):
        fig, ax = plt.subplots(figsize=(7, 4))
        label, si_unit = SIGNATURE[s.evidence["signature"]]
        unit = si_unit if units == "si" else us_unit(si_unit)
        v, r = np.asarray(from_si(s.signature_before, unit)), s.residual_before
        ax.plot(v, r, ",", alpha=0.4, color="tab:blue")
        edges = np.quantile(v, np.linspace(0, 1, 25))
        mid = 0.5 * (edges[1:] + edges[:-1])
        which = np.clip(np.searchsorted(edges, v, side="right") - 1, 0, 23)
        means = [r[which == b].mean() if np.any(which == b) else np.nan for b in range(24)]
        ax.plot(mid, means, "o-", color="tab:red", label="bin mean")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_xlabel(f"{label} ({unit})")
        ax.set_ylabel("residual x_model − x_meas (× sensor noise)")
        ax.set_title(f"step {i}: residual before adding {s.added}")
        ax.legend()
        fig.tight_layout()
        path = out / f"loop_step{i}_{s.added}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths


def fit_document(fit: IsolatorFit, loop: LoopResult | None) -> dict:
    """The document `analysis fit --json` writes (and a lot keeps per unit): the fit's
    JSON, with the loop's keys and the closed-loop model where the loop ran."""
    doc = fit_json(fit)
    if loop is not None:
        doc = with_loop(doc, loop_json(loop))
        doc[MODEL_KEY] = loop_model_json(loop)
    return doc


def loop_model_json(loop: LoopResult) -> dict:
    """The model after the loop, effects included, with the covariance of its refit."""
    f, h = loop.final, loop.final.hypothesis
    added = ", ".join(loop.effects_added) or "none"
    return model_json(h.model, f.names, covariance_from(f.std, f.correlation), h.sensor_gain,
                      h.sensor_delay, source=f"closed loop, effects added: {added}")


def with_loop(doc: dict, loop: dict) -> dict:
    """The fit's JSON with the loop's keys; `parameters` become the final model's.

    The loop refits the constants it frees: their values, std and 95 % interval replace
    the base fit's, and they are no longer held; what it held keeps the base fit's entry.
    """
    merged = {name: dict(entry) for name, entry in doc["parameters"].items()}
    for name, entry in loop["parameters"].items():
        mine = merged.setdefault(name, {"held": False})
        mine["value"], mine["unit"] = entry["value"], entry["unit"]
        if entry["std"] is not None:
            v, s = entry["value"], entry["std"]
            mine.update(std=s, ci95=[v - Z95 * s, v + Z95 * s])
            mine.pop("held", None)
        mine.setdefault("std", None)
    out = {**doc, **{k: v for k, v in loop.items() if k != "parameters"}}
    out["parameters_base_model"] = doc["parameters"]
    out["parameters"] = merged
    return out
