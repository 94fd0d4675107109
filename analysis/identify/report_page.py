"""The fit's sections of the report page: what was fitted, the constants in both unit
systems with their 95 % intervals, the errors per run and the comparison figures.

Every number is read from the `IsolatorFit` the CLI prints (`report_format`) and
writes as JSON (`fit_json`): the page formats, it does not compute again.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from importlib import metadata
from pathlib import Path

from analysis.identify.figures import Figure
from analysis.identify.output_error import Z95
from analysis.identify.pipeline import IsolatorFit
from analysis.identify.report_format import SHOWN
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
from rig.units import from_si

PACKAGE = "isolator-rig"
NOT_DETERMINED = "held at the start value (Table 1's average): not determined by these runs"


def software_version() -> str:
    try:
        return f"{PACKAGE} {metadata.version(PACKAGE)}"
    except metadata.PackageNotFoundError:  # run from a checkout that was never installed
        return f"{PACKAGE} (not installed: version unknown)"


def header(fit: IsolatorFit, sources: Sequence[Path], when: datetime, units: str) -> Html:
    """What was fitted, from which files, with which mass, when and by which software."""
    mass_lb = float(from_si(fit.model.mass, "lbm"))
    mass = (f"{mass_lb:.6g} lbm ({fit.model.mass:.6g} kg)" if units == "us" else
            f"{fit.model.mass:.6g} kg ({mass_lb:.6g} lbm)")
    names = ", ".join(p.run.name for p in fit.prepared)
    return Html(tag("h1", "Isolator identification: Eq 10 of CERL TR M-226")
                + facts([("runs fitted", names),
                         ("files", ", ".join(str(s) for s in sources) or "(given in-process)"),
                         ("isolated mass", mass),
                         ("reported estimate", fit.estimate),
                         ("figures in", "the report's units (in, in/s, g, lb)" if units == "us"
                          else "SI (m, m/s, m/s², N)"),
                         ("generated", when.isoformat(timespec="seconds")),
                         ("software", software_version())])
                + _runs_table(fit, units))


def _runs_table(fit: IsolatorFit, units: str) -> Html:
    rows = []
    for p in fit.prepared:
        sigma, unit = in_units(p.sigma_x, "m", units)
        cutoff = p.settings.get("cutoff_hz")
        rows.append([p.run.name, p.oe.t.size, f"{p.oe.t[-1] - p.oe.t[0]:.3f}",
                     f"{1.0 / p.oe.dt:.0f}", f"{sigma:.3g} {unit}",
                     p.method + (f", cutoff {cutoff:.1f} Hz" if cutoff else ""),
                     p.table.method, f"{p.active.mean():.0%}"])
    return table(["run", "samples", "duration (s)", "rate (Hz)", "mass sensor noise σx",
                  "differentiation", "table motion", "moving"], rows, text=(0, 5, 6),
                 caption="The runs as prepared for the fit")


def constants_section(fit: IsolatorFit, units: str, loop_follows: bool = False) -> Html:
    """The reported constants in both unit systems; Table 1's shape in `units`.
    `loop_follows`: the page goes on to the loop, whose final model refits them."""
    values, stds = fit.values_std()
    si_units = fit.model.units()
    rows, classes = [], []
    for n in SHOWN:
        row: list[object] = [n]
        for system in ("us", "si"):
            v, unit = in_units(values[n], si_units[n], system)
            ci = in_units(Z95 * stds[n], si_units[n], system)[0] if n in stds else None
            row += [num(v), num(ci, ".2g"), unit]
        rows.append(row + [_status(fit, n, stds, units)])
        classes.append("held" if n in fit.held else "")
    main = table(["constant", "report's units", "± 95 %", "unit", "SI", "± 95 %", "unit",
                  "status"], rows, caption=f"Eq 10 as the fit reports it ({fit.estimate})",
                 text=(0, 3, 6, 7), row_classes=classes, cls="constants")
    parts: list[object] = [main, _table1(fit, units)]
    if loop_follows:
        parts.insert(1, tag("p", "The loop refits these constants with the effects it adds: "
                                 "its final model closes the section “Closing the loop”."))
    if fit.skew:
        parts.append(table(["run", "offset (ms)", "± 95 %", "rate (ppm)", "± 95 %"],
                           [[r, f"{s * 1e3:+.4f}", f"{Z95 * e * 1e3:.4f}", f"{d * 1e6:+.1f}",
                             f"{Z95 * de * 1e6:.1f}"] for r, (s, e, d, de) in fit.skew.items()],
                           caption="Table channel time offset (at the table motion's centroid), "
                                   "fitted"))
    return section("constants", "Identified constants", *parts)


def _status(fit: IsolatorFit, name: str, stds: dict[str, float], units: str) -> str:
    if name in fit.held:
        consistent = fit.joint.consistent.get(name) if fit.joint else None
        if consistent is None:
            return NOT_DETERMINED
        (lo, unit), (hi, _) = (in_units(v, fit.model.units()[name], units) for v in consistent)
        span = (f"the runs cannot tell {lo:.3g} to {hi:.3g} {unit} apart" if hi > lo else
                f"the scan's lowest cost, {lo:.3g} {unit}, is not significantly better")
        return f"{NOT_DETERMINED}; {span} (a decade either way scanned)"
    if name in stds:
        return "fitted"
    if fit.joint is None and name in fit.projection.shapes:
        return "searched by variable projection (no interval: output error gives one)"
    return f"not estimated by {fit.estimate}: the start value"


def _table1(fit: IsolatorFit, units: str) -> Html:
    """Table 1's shape: the estimate, each run alone, variable projection, appendix A."""
    values, stds = fit.values_std()
    si_units = fit.model.units()
    app_a, proj = fit.appendix_a.as_dict(), fit.projection.model.parameters()
    runs = list(fit.per_run)
    rows = []
    for n in SHOWN:
        v, unit = in_units(values[n], si_units[n], units)
        ci = ("held" if n in fit.held else
              num(in_units(Z95 * stds[n], si_units[n], units)[0], ".2g") if n in stds else "")
        rows.append([n, unit, num(v), ci]
                    + [num(in_units(fit.per_run[r].model.parameters()[n], si_units[n],
                                    units)[0]) for r in runs]
                    + [num(in_units(proj[n], si_units[n], units)[0]),
                       num(in_units(app_a[n], si_units[n], units)[0]) if n in app_a else ""])
    return table(["constant", "unit", "estimate", "± 95 %", *(f"run {r}" for r in runs),
                  "varpro", "app. A"], rows, text=(0, 1),
                 caption="As the report's Table 1: each run alone, variable projection "
                         "(α, β, δ searched) and appendix A (the report's least squares at "
                         "its α, β, δ)")


def errors_section(fit: IsolatorFit, units: str) -> Html:
    """Per run: the errors `analysis.identify.run_errors` defines, as the CLI prints them."""
    f_unit = "N" if units == "si" else "lb"
    rows = [[r, percent(e.z), percent(e.zd), percent(e.xdd),
             num(None if e.force_rms is None else in_units(e.force_rms, "N", units)[0]),
             f"{e.residual_over_noise:.3f}"]
            for r, e in fit.errors.items()]
    notes = [f"Run {r} differs significantly from the other runs in {', '.join(names)} "
             "(as the report's run C)." for r, names in fit.flagged.items()]
    return section("errors", "Errors per run",
                   table(["run", "NRMSE z", "NRMSE ż", "NRMSE ẍ", f"force RMS ({f_unit})",
                          "residual / noise"], rows, cls="errors"),
                   tag("p", "NRMSE: RMS(model − measured) / RMS(measured). Force RMS: mass × "
                            "RMS of the acceleration the model misses. Residual / noise: "
                            "RMS(x model − x measured) / the mass sensor's noise, 1 for a "
                            "right model."),
                   *(tag("p", n, cls="warn") for n in notes))


def comparisons_section(figures: Sequence[Figure]) -> Html:
    return section("comparisons", "Measured and model",
                   tag("p", "Each run driven by its estimated table motion through the "
                            "identified model, against the measurement; then the model's "
                            "force curves and the equation-error profile over the tanh "
                            "shapes."),
                   *(figure(f.path, f.caption) for f in figures))


def conditioning_notes(fit: IsolatorFit) -> list[str]:
    """What the runs cannot tell apart or determine, from the fit's own statistics."""
    a = fit.appendix_a
    notes = [(f"Appendix A: σ² = {a.sigma2:.4g} N², condition number of A = "
              f"{a.condition:.3g}, {a.samples} samples with relative motion.")]
    if fit.held:
        notes.append(f"The fit held at the start value, not determined by these runs: "
                     f"{', '.join(fit.held)} (see the constants table).")
    return notes


def conditioning_section(notes: Sequence[str]) -> Html:
    return section("conditioning", "Conditioning", bullets(notes))
