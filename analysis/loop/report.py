"""The loop's result for people and programs: text, JSON and evidence figures."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from analysis.fit_schema import (
    Conditioning,
    Estimate,
    Evidence,
    FitResult,
    LoopOutcome,
    LoopStep,
    Refusal,
    ResidualTests,
    RunError,
    Unexplained,
)
from analysis.identify.output_error import Z95
from analysis.identify.report_format import fit_result
from analysis.loop.refit import Fit
from analysis.loop.result import LoopResult, Step
from analysis.model.model_json import covariance_from, model_json
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


def loop_outcome(result: LoopResult) -> LoopOutcome:
    """The loop as the fit document's schema (`loop`, `effects_added`, `error_before`, …).

    The loop's parts that already come as the document's objects (a run's errors, the
    residual's tests, a step's evidence, a refusal) are read through the schema, so a
    key it does not know fails here, where the document is written.
    """
    return LoopOutcome(
        steps=tuple(_step(s, f"loop[{i}]") for i, s in enumerate(result.steps)),
        effects_added=tuple(result.effects_added),
        error_before=_errors(result.error_before, "error_before"),
        error_after=_errors(result.error_after, "error_after"),
        residual_before=ResidualTests.from_json_dict(result.diagnosis_before.as_dict(),
                                                     "residual_before"),
        residual_after=ResidualTests.from_json_dict(result.diagnosis_after.as_dict(),
                                                    "residual_after"),
        unexplained=Unexplained(result.unexplained, result.description),
        refused=tuple(Refusal.from_json_dict(r, f"refused[{i}]")
                      for i, r in enumerate(result.refused)),
        conditioning=tuple(Conditioning.from_json_dict(c.as_dict(), f"conditioning[{i}]")
                           for i, c in enumerate(result.conditioning)))


def _step(s: Step, where: str) -> LoopStep:
    return LoopStep(s.added, s.parameter, Estimate(s.value, s.std, s.unit),
                    Evidence.from_json_dict(s.evidence, f"{where}.evidence"),
                    _errors(s.error_before, f"{where}.error_before"),
                    _errors(s.error_after, f"{where}.error_after"))


def _errors(by_run: dict[str, dict[str, float]], where: str) -> dict[str, RunError]:
    return {r: RunError.from_json_dict(e, f"{where}.{r}") for r, e in by_run.items()}


def loop_json(result: LoopResult) -> dict[str, object]:
    """The loop's keys of the fit document, with `parameters` the final refit's own."""
    return {**loop_outcome(result).to_json_dict(), "parameters": parameters_json(result.final)}


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
    if result.final.hypothesis.fresh_states:
        lines.append("  each run fitted from rest with the seals unloaded and the fluid cool "
                     "(fits better than the state carried from the run before)")
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


def fit_document(fit: IsolatorFit, loop: LoopResult | None) -> FitResult:
    """The document `analysis fit --json` writes (and a lot keeps per unit): the fit,
    with the loop's outcome, its refit constants and the closed-loop model where it ran."""
    doc = fit_result(fit)
    if loop is None:
        return doc
    return replace(doc, parameters=merged_parameters(doc.parameters, parameters_json(loop.final)),
                   identified_model=loop_model_json(loop), loop=loop_outcome(loop),
                   parameters_base_model=doc.parameters)


def loop_model_json(loop: LoopResult) -> dict:
    """The model after the loop, effects included, with the covariance of its refit."""
    f, h = loop.final, loop.final.hypothesis
    added = ", ".join(loop.effects_added) or "none"
    return model_json(h.model, f.names, covariance_from(f.std, f.correlation), h.sensor_gain,
                      h.sensor_delay, source=f"closed loop, effects added: {added}",
                      states_reset_each_run=h.fresh_states)


def merged_parameters(base: dict[str, Estimate], loop: dict[str, dict]) -> dict[str, Estimate]:
    """The fit's constants with the loop's refit (`parameters_json`) laid over them.

    The loop refits the constants it frees: their values, std and 95 % interval replace
    the base fit's, and they are no longer held; what it held keeps the base fit's std
    and interval. A constant the loop added but could not estimate is `held` false.
    """
    merged = dict(base)
    for name, entry in loop.items():
        v, s, unit = entry["value"], entry["std"], entry["unit"]
        if s is not None:
            merged[name] = Estimate(v, s, unit, (v - Z95 * s, v + Z95 * s))
        elif name in merged:
            merged[name] = replace(merged[name], value=v, unit=unit)
        else:
            merged[name] = Estimate(v, None, unit, held=False)
    return merged
