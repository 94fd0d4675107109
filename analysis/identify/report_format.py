"""The identified isolator as text (SI or the report's units) and as the fit document's
schema (analysis/fit_schema.py)."""

from __future__ import annotations

import numpy as np

from analysis.fit_schema import (
    AppendixA,
    ChannelSkew,
    Estimate,
    FitResult,
    ModelTerm,
    Preparation,
    RunError,
    VariableProjection,
)
from analysis.identify.output_error import Z95
from analysis.identify.pipeline import IsolatorFit
from analysis.model.model_json import model_json
from analysis.model.terms import kind
from rig.units import from_si, us_unit

SHOWN = ("k1", "k2", "c1", "c2", "alpha", "beta", "delta", "F_break", "epsilon")


def _convert(value: float, si_unit: str, units: str) -> tuple[float, str]:
    if units == "si":
        return value, si_unit
    u = us_unit(si_unit)
    return float(from_si(value, u)), u


def _cell(value: float | None, width: int = 11) -> str:
    return " " * width if value is None else f"{value:>{width}.4g}"


def format_constants(fit: IsolatorFit, units: str = "us") -> str:
    """Table 1's shape: the reported estimate ± 95 %, each run, the projection, appendix A."""
    values, stds = fit.values_std()
    si_units = fit.model.units()
    runs = list(fit.per_run)
    label = "the report's units" if units == "us" else "SI"
    # a run's column as wide as its name: a rig run's timestamped name ran into the next
    widths = {r: max(11, len(r) + 6) for r in runs}
    head = (f"{'constant':<9}{'unit':<11}{'estimate':>11}{'± 95 %':>10}"
            + "".join(f"{'run ' + r:>{widths[r]}}" for r in runs)
            + f"{'varpro':>11}{'app. A':>11}")
    title = (f"identified isolator, {label} ({fit.estimate}; varpro = equation error with "
             "alpha, beta, delta searched; app. A = the report's least squares at its "
             "alpha, beta, delta)")
    lines = [title, head]
    app_a, proj = fit.appendix_a.as_dict(), fit.projection.model.parameters()
    for n in SHOWN:
        v, unit = _convert(values[n], si_units[n], units)
        ci = "held" if n in fit.held else (
            f"{_convert(stds[n], si_units[n], units)[0] * Z95:.2g}" if n in stds else "")
        row = f"{n:<9}{unit:<11}{v:>11.4g}{ci:>10}"
        for r in runs:
            row += _cell(_convert(fit.per_run[r].model.parameters()[n], si_units[n], units)[0],
                         widths[r])
        row += _cell(_convert(proj[n], si_units[n], units)[0])
        row += _cell(_convert(app_a[n], si_units[n], units)[0] if n in app_a else None)
        lines.append(row)
    if fit.held:
        lines.append(f"held at the start value (not determined by these runs): "
                     f"{', '.join(fit.held)}")
    for n, (low, high) in (fit.joint.consistent.items() if fit.joint else ()):
        lo, unit = _convert(low, si_units[n], units)
        hi, _ = _convert(high, si_units[n], units)
        scanned = "a decade either way scanned, other constants at the fit"
        lines.append(f"  {n}: the runs cannot tell {lo:.3g} to {hi:.3g} {unit} apart ({scanned})"
                     if hi > lo else f"  {n}: the scan's lowest cost is at {lo:.3g} {unit}, "
                     f"not significantly below the held value ({scanned})")
    if fit.skew:
        lines.append("table channel time offset (at the table motion's centroid), fitted (ms, "
                     "± 95 %), and its rate (ppm): " + ", ".join(
                         f"{r} {s * 1e3:+.4f} ± {Z95 * e * 1e3:.4f}, {d * 1e6:+.1f} ± "
                         f"{Z95 * de * 1e6:.1f}" for r, (s, e, d, de) in fit.skew.items()))
    return "\n".join(lines)


def format_errors(fit: IsolatorFit, units: str = "us") -> str:
    """Per run: NRMSE of z, ż, ẍ, the force left unexplained and residual / sensor noise
    (`analysis.identify.run_errors`: the loop's lines use the same definitions)."""
    f_unit = "N" if units == "si" else "lb"
    w = max([8, *(len(r) + 2 for r in fit.errors)])
    lines = [(f"{'run':<{w}}{'NRMSE z':>9}{'NRMSE ż':>9}{'NRMSE ẍ':>9}"
              f"{'force RMS':>13}{'resid/noise':>13}")]
    for r, e in fit.errors.items():
        lines.append(f"{r:<{w}}{e.z:>9.2%}{e.zd:>9.2%}{e.xdd:>9.2%}"
                     f"{_convert(e.force_rms, 'N', units)[0]:>10.4g} {f_unit:<2}"
                     f"{e.residual_over_noise:>13.3f}")
    lines.append("NRMSE: RMS(model - measured) / RMS(measured); force RMS: mass x RMS of the "
                 "acceleration the model misses; resid/noise: RMS(x model - x measured) / the "
                 "sensor noise (1 for a right model)")
    a = fit.appendix_a
    lines.append(f"appendix A: sigma^2 = {a.sigma2:.4g} N^2, condition number of A = "
                 f"{a.condition:.3g}, {a.samples} samples with relative motion")
    for r, names in fit.flagged.items():
        lines.append(f"run {r} differs significantly from the other runs in "
                     f"{', '.join(names)} (as the report's run C)")
    return "\n".join(lines)


def format_fit(fit: IsolatorFit) -> str:
    """Both tables, in the report's units and in SI, and the error per run."""
    return "\n\n".join([format_constants(fit, "us"), format_constants(fit, "si"),
                        format_errors(fit, "us")])


def _entry(value: float, std: float | None, unit: str, held: bool = False) -> Estimate:
    ci95 = None if std is None else (float(value - Z95 * std), float(value + Z95 * std))
    return Estimate(float(value), None if std is None else float(std), unit, ci95,
                    True if held else None)


def _rows(a: np.ndarray) -> tuple[tuple[float, ...], ...]:
    return tuple(map(tuple, a.tolist()))


def fit_result(fit: IsolatorFit) -> FitResult:
    """The fit as the document's schema, without the loop (SI)."""
    values, stds = fit.values_std()
    si_units = fit.model.units()
    a, p = fit.appendix_a, fit.projection
    estimated = fit.joint if fit.joint is not None else p.fit  # what `values_std` reports
    return FitResult(
        parameters={n: _entry(values[n], stds.get(n), si_units[n], n in fit.held)
                    for n in values},
        runs={r: {n: _entry(v, s, si_units[n]) for n, v, s in zip(f.names, f.values, f.std)}
              for r, f in fit.per_run.items()},
        error={r: RunError(e.z, e.zd, e.xdd, e.force_rms, e.residual_over_noise)
               for r, e in fit.errors.items()},
        model=tuple(ModelTerm(t.name, t.kind, kind(t.kind).formula, t.is_gated)
                    for t in fit.model.terms),
        # the model to predict with (`sim response --model`)
        identified_model=model_json(fit.model, estimated.names, estimated.covariance,
                                    source=fit.estimate),
        estimate=fit.estimate, held=tuple(fit.held),
        flagged_runs={r: tuple(names) for r, names in fit.flagged.items()},
        consistent_range={n: tuple(r) for n, r in
                          (fit.joint.consistent.items() if fit.joint else ())},
        channel_skew_s=(None if fit.skew is None else
                        {r: ChannelSkew(s, e, d, de) for r, (s, e, d, de) in fit.skew.items()}),
        appendix_a=AppendixA(tuple(a.names), a.as_dict(), dict(zip(a.names, a.std.tolist())),
                             a.sigma2, _rows(a.A), tuple(a.b.tolist()), _rows(a.covariance),
                             a.condition, _rows(np.nan_to_num(a.correlation)), a.samples),
        variable_projection=VariableProjection(p.shapes, p.fit.as_dict(), p.fit.sigma2,
                                               p.evaluations),
        preparation={pr.run.name: Preparation(pr.method, pr.settings.get("cutoff_hz"),
                                              pr.sigma_x, pr.table.sigma, pr.table.method,
                                              float(pr.active.mean()))
                     for pr in fit.prepared})


def fit_json(fit: IsolatorFit) -> dict:
    """`fit_result` as the JSON document."""
    return fit_result(fit).to_json_dict()
