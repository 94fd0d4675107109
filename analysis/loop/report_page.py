"""The loop's section of the report page: each effect added with its size, evidence,
errors before and after and evidence figure; what stayed unexplained; the final model.

The numbers are the `LoopResult`'s, which the CLI prints (`report.format_loop`) and
writes as JSON (`report.loop_json`): this module formats them as HTML only.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

from analysis.identify.output_error import Z95
from analysis.identify.report_format import SHOWN
from analysis.loop.report import parameters_json
from analysis.loop.result import LoopResult, Step
from analysis.report_html import (
    Html,
    bullets,
    facts,
    figure,
    in_units,
    num,
    percent,
    section,
    table,
    tag,
)

ERRORS = (("z", "NRMSE z"), ("zd", "NRMSE ż"), ("xdd", "NRMSE ẍ"))


def loop_section(result: LoopResult, figures: Sequence[Path], units: str) -> Html:
    """"Closing the loop": one part per step (figure `figures[i]` for step i + 1), then
    what is left, the candidates refused, the errors before and after, the final model."""
    before = result.diagnosis_before
    parts: list[object] = [tag(
        "p", f"The fitted Eq 10 leaves a residual of {before.residual_over_noise:.2f} × the "
             f"sensor noise, {'white' if before.white else 'not white'} (Ljung–Box p = "
             f"{before.ljung_box_p:.2g}). The loop tries each effect of its library on that "
             "residual, adds the best one only if it is significant and predicts held-out "
             "runs better, refits, and repeats.")]
    for i, (step, fig) in enumerate(zip(result.steps, figures), 1):
        parts.append(_step(i, step, fig, units))
    if not result.steps:
        parts.append(tag("p", "No candidate effect was significant: nothing was added."))
    parts += [tag("h3", "What stayed unexplained"), _left(result)]
    if result.refused:
        parts += [tag("h3", "Candidates refused"),
                  bullets(f"{r['candidate']}: {r['reason']}" for r in result.refused)]
    parts += [tag("h3", "Before and after the loop, per run"),
              error_table(result.error_before, result.error_after, units),
              tag("h3", "The final model"), _final_table(result, units)]
    return section("loop", "Closing the loop", *parts)


def _step(i: int, s: Step, fig: Path, units: str) -> Html:
    ev = s.evidence
    # in the page's units, and in SI too where the report has a name for the unit
    systems = [units] + (["si"] if in_units(1.0, s.unit, units)[1] != s.unit else [])
    size = " = ".join(_value(s.value, s.std, s.unit, system) for system in systems)
    t = "" if ev.get("t") is None else f", t = {ev['t']:.1f}"
    return Html(tag("h3", f"Step {i}: added {s.added}", id=f"step{i}")
                + facts([("effect", s.added), ("why", ev["explanation"]),
                         ("size (± 95 %)", f"{s.parameter} = {size}"),
                         ("evidence", (f"score χ²₁ = {ev['value']:.1f}, residual cut "
                                       f"{100 * ev['rss_drop']:.1f} %{t}")),
                         ("held-out runs", ev["heldout"])])
                + error_table(s.error_before, s.error_after, units)
                + figure(fig, f"Step {i}: the residual before adding {s.added}, against the "
                              "variable that exposed it (bin means in red)"))


def _value(value: float, std: float, si_unit: str, units: str) -> str:
    v, unit = in_units(value, si_unit, units)
    ci = in_units(Z95 * std, si_unit, units)[0]
    return f"{v:.4g} ± {ci:.2g} {unit}"


def error_table(before: Mapping[str, Mapping[str, float]],
                after: Mapping[str, Mapping[str, float]], units: str) -> Html:
    """Per run, each error before → after (`analysis.identify.run_errors`' definitions)."""
    f_unit = "N" if units == "si" else "lb"
    rows = []
    for run, b in before.items():
        a = after[run]
        row: list[object] = [run]
        row += [f"{percent(b[k])} → {percent(a[k])}" if k in b else "" for k, _ in ERRORS]
        row.append(f"{num(in_units(b['force_rms'], 'N', units)[0], '.1f')} → "
                   f"{num(in_units(a['force_rms'], 'N', units)[0], '.1f')}"
                   if "force_rms" in b else "")
        row.append(f"{b['residual_over_noise']:.2f} → {a['residual_over_noise']:.2f}")
        rows.append(row)
    return table(["run", *(h for _, h in ERRORS), f"force RMS ({f_unit})", "residual / noise"],
                 rows, cls="errors")


def _left(result: LoopResult) -> Html:
    d = result.diagnosis_after
    text = tag("p", f"Final: {result.description}. The residual is "
                    f"{'white' if d.white else 'not white'} (Ljung–Box p = {d.ljung_box_p:.2g}); "
                    f"it concentrates at {d.region_text}; {d.band_text}.")
    if result.unexplained:
        return Html(text + tag("p", "Unexplained structure: no effect in the library accounts "
                                    "for it.", cls="warn"))
    return text


def _final_table(result: LoopResult, units: str) -> Html:
    """Every constant of the final model; ± 95 % where the loop's last refit estimated it."""
    rows = []
    params = parameters_json(result.final)
    # Eq 10's constants in Table 1's order, then what the loop added
    for name in [*(n for n in SHOWN if n in params), *(n for n in params if n not in SHOWN)]:
        p = params[name]
        if name == "m" or (p["value"] == 0.0 and p["std"] is None):
            continue  # the mass is given; a term at zero is not in the model
        row: list[object] = [name]
        for system in (units, "si"):
            v, unit = in_units(p["value"], p["unit"], system)
            ci = None if p["std"] is None else in_units(Z95 * p["std"], p["unit"], system)[0]
            row += [num(v), num(ci, ".2g"), unit]
        rows.append(row + ["refitted by the loop" if p["std"] is not None else
                           "as the fit left it"])
    first = "report's units" if units == "us" else "SI"
    return table(["constant", first, "± 95 %", "unit", "SI", "± 95 %", "unit", "source"], rows,
                 caption="The model after the loop, as --json writes its parameters",
                 text=(0, 3, 6, 7), cls="final")


def conditioning_notes(result: LoopResult) -> list[str]:
    """The force candidates the final model's own terms reproduce almost entirely."""
    return [f"Not testable with these runs: {c.candidate} — "
            f"{100 * (1 - c.unique_fraction):.2f} % of its force pattern is the model's own "
            f"{', '.join(c.like)} (variance inflation {c.variance_inflation:.0f})."
            for c in result.indistinguishable]
