"""`sim response`: the response of the report's or an identified model to a base motion.

The computation is `analysis.predict`; this module reads the inputs (a fit's
JSON, a motion CSV) and writes the outputs (peaks as text, every sample as CSV,
a figure), converting units at the edge.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from analysis.model.report_constants import report_model
from analysis.predict import (
    Peak,
    Prediction,
    peak,
)
from analysis.simulate import Response, simulate
from rig.profile import load_profile
from rig.units import STANDARD_GRAVITY, from_si

# column → SI unit; the US unit comes from rig.units
COLUMNS = {"t": "s", "u": "m", "x": "m", "z": "m", "zd": "m/s", "xdd": "m/s^2"}
US = {"s": "s", "m": "in", "m/s": "in/s", "m/s^2": "in/s^2", "N": "lb"}


def run_response(run: str, constants: str = "average") -> Response:
    """Simulate profile `run` (A, B, C or a TOML file) with Table 1 column `constants`."""
    return simulate(report_model(constants), load_profile(run).motion())


def peaks(r: Response) -> list[Peak]:
    """Largest magnitude of each response variable and when it occurs."""
    return [peak(name, getattr(r, name), r.t, unit)
            for name, unit in (("u", "m"), ("z", "m"), ("zd", "m/s"), ("xdd", "m/s^2"))]


LABELS = {"u": "table displacement u", "z": "relative displacement z",
          "zd": "relative velocity ż", "xdd": "mass acceleration ẍ"}


def _shown(value: float, unit: str, units: str) -> tuple[float, str]:
    return (float(from_si(value, US[unit])), US[unit]) if units == "us" else (value, unit)


def format_peaks(r: Response, units: str) -> str:
    return format_prediction(Prediction(r, tuple(peaks(r)), ()), units)


def format_prediction(p: Prediction, units: str) -> str:
    """The peaks (with the band where there is one) and each term's peak force."""
    band = f"   {p.level:g} % band ({p.draws - p.diverged} draws)" if p.band else ""
    lines = [f"{'peak':<26}{'value':>12}  {'unit':<8}{'at t (s)':>9}{band}"]
    for k in p.peaks:
        value, unit = _shown(k.value, k.unit, units)
        row = f"{LABELS[k.name]:<26}{value:>+12.4f}  {unit:<8}{k.time:>9.3f}"
        if k.name == "xdd":
            row += f"   ({k.value / STANDARD_GRAVITY:+.3f} g)"
        if k.name in p.band:
            lo, hi = p.band[k.name]
            if k.name == "xdd":  # as the peak's own reading in g: the isolator's measure
                row += "   " + _band(lo / STANDARD_GRAVITY, hi / STANDARD_GRAVITY, "g", 3)
            else:
                row += "   " + _band(_shown(lo, k.unit, units)[0], _shown(hi, k.unit, units)[0],
                                     unit, 4)
        lines.append(row)
    if p.force_peaks:
        lines.append("peak force of each term")
        for k in p.force_peaks:
            value, unit = _shown(k.value + 0.0, k.unit, units)  # + 0.0: no "-0.0" for none
            lines.append(f"  {'F_' + k.name:<24}{value:>+12.1f}  {unit:<8}{k.time:>9.3f}")
    if p.diverged:
        lines.append(f"{p.diverged} of {p.draws} draws diverged and are not in the band")
    return "\n".join(lines)


def _band(lo: float, hi: float, unit: str, decimals: int) -> str:
    # enough decimals for the band's width to show with two significant digits
    width = hi - lo
    if width > 0:
        decimals = min(max(decimals, 1 - int(np.floor(np.log10(width)))), 9)
    return f"{lo:+.{decimals}f} to {hi:+.{decimals}f} {unit}"


def write_csv(r: Response, path: Path, units: str) -> None:
    """Every sample with the force terms; header names carry the units."""
    columns = {name: (getattr(r, name), unit) for name, unit in COLUMNS.items()}
    columns.update({f"F_{k}": (v, "N") for k, v in r.forces.items()})
    header, data = [], []
    for name, (values, unit) in columns.items():
        shown = US[unit] if units == "us" else unit
        header.append(f"{name} [{shown}]")
        data.append(from_si(values, shown) if units == "us" else values)
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(np.column_stack(data).tolist())


def write_plot(p: Prediction, path: Path, units: str, title: str) -> None:
    """z, ż, ẍ against time with the band's envelope, and each term's force."""
    import matplotlib  # only when a figure is asked for

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r = p.response
    fig, axes = plt.subplots(4, 1, figsize=(8, 9), sharex=True)
    for ax, name in zip(axes, ("z", "zd", "xdd")):
        unit = COLUMNS[name]
        shown = US[unit] if units == "us" else unit
        ax.plot(r.t, from_si(getattr(r, name), shown), lw=1, label="nominal")
        if name in p.envelope:
            lo, hi = (from_si(e, shown) for e in p.envelope[name])
            ax.fill_between(r.t, lo, hi, alpha=0.3, label=f"{p.level:g} % band")
            ax.legend(loc="upper right")
        ax.set_ylabel(f"{LABELS[name]} ({shown})")
    f_unit = "lb" if units == "us" else "N"
    for name, f in r.forces.items():
        axes[3].plot(r.t, from_si(f, f_unit), lw=1, label=name)
    axes[3].set_ylabel(f"term force ({f_unit})")
    axes[3].set_xlabel("t (s)")
    axes[3].legend(loc="upper right", ncol=4, fontsize="small")
    fig.suptitle(title, fontsize="medium")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
