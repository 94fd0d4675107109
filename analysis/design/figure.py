"""`--report DIR`: the trade-off as a figure, and a page that shows it with the text.

Every simulated design as a point (peak stroke, peak acceleration, the worst over
the threats), the non-dominated ones joined as the Pareto front, the ideal
isolator's curve below them, the limits as the corner of the acceptable region,
and the current isolator, the optimum and (when no design meets both limits) the
closest design marked.
"""

from __future__ import annotations

import html
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from analysis.design.design import DesignResult
from analysis.design.report import format_design
from rig.units import from_si


def write_report(r: DesignResult, directory: Path, units: str = "us") -> Path:
    """Write pareto.png and index.html into `directory`; returns the page's path."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    image = pareto_figure(r, directory / "pareto.png", units)
    page = directory / "index.html"
    page.write_text("<!doctype html><html><head><meta charset='utf-8'><title>analysis design"
                    "</title></head><body><h1>Isolator design</h1><pre>"
                    f"{html.escape(format_design(r, units))}</pre>\n"
                    f'<figure><img src="{image.name}" alt="Pareto front"></figure>\n'
                    "</body></html>\n", encoding="utf-8")
    return page


def pareto_figure(r: DesignResult, path: Path, units: str = "us") -> Path:
    au, zu = ("g", "in") if units == "us" else ("m/s^2", "m")

    def A(v):
        return from_si(np.asarray(v, float), au)

    def Z(v):
        return from_si(np.asarray(v, float), zu)

    a, z = r.archive.worst_accel, r.archive.worst_stroke
    lim_a, lim_z = float(A(r.limits.accel)), float(Z(r.limits.stroke))
    fig, ax = plt.subplots(figsize=(8, 6))
    ok = np.isfinite(a) & np.isfinite(z)
    ax.scatter(Z(z[ok]), A(a[ok]), s=4, c="0.75", label=f"designs simulated ({ok.sum()})")
    f = r.front
    ax.plot(Z(z[f]), A(a[f]), "-", color="tab:blue", lw=1.5, label="Pareto front")
    ax.plot(Z(r.ideal.stroke), A(r.ideal.accel), "--", color="k", lw=1.2,
            label="ideal isolator (Figure 1: constant force)")
    ax.axvline(lim_z, color="tab:red", lw=0.8, ls=":")
    ax.axhline(lim_a, color="tab:red", lw=0.8, ls=":")
    ax.fill_between([0, lim_z], 0, lim_a, color="tab:green", alpha=0.08,
                    label="within both limits")
    marks = [(r.current, "o", "tab:orange", "current isolator"),
             (r.optimum, "*", "tab:red", "optimum")]
    if r.closest is not None:
        marks.append((r.closest, "D", "tab:purple", "closest to both limits"))
    for i, marker, color, label in marks:
        ax.plot(Z(z[i]), A(a[i]), marker, color=color, ms=12, mec="k", label=label)
    shown = [a[i] for i, *_ in marks] + [r.limits.accel]
    top = 2.5 * float(A(max(v for v in shown if np.isfinite(v))))
    right = 1.6 * max(lim_z, float(Z(max(z[i] for i, *_ in marks if np.isfinite(z[i])))))
    ax.set_xlim(0, right)
    ax.set_ylim(0, top)
    ax.set_xlabel(f"peak relative displacement |z| ({zu}), worst over the threats")
    ax.set_ylabel(f"peak mass acceleration |ẍ| ({au}), worst over the threats")
    ax.set_title(f"trade-off over the free constants ({', '.join(r.space.names)}); "
                 f"threats {', '.join(r.threats)}", fontsize=9)
    ax.legend(fontsize=8, loc="upper right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
