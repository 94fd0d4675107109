"""`--report DIR`: the report's figures as PNG and one HTML page that shows them.

Per run, measured against model: relative displacement, relative velocity and
mass acceleration (the report's Figures 13–16); the spring force f1(z) and the
damping force f2(ż) of the identified model (Figures 17–18); and the profile of
the equation-error variance over α and β (minimised over δ and the linear
coefficients), which shows how weakly a saturating tanh pins them down.
"""

from __future__ import annotations

import html
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from analysis.identify.output_error import initial_offset
from analysis.identify.pipeline import IsolatorFit, PreparedRun
from analysis.identify.report_format import format_fit
from analysis.model.isolator import IsolatorModel
from analysis.simulate import simulate

SPRING = ("k1", "k2")
DAMPER = ("c1", "c2")


def write_report(fit: IsolatorFit, directory: Path) -> Path:
    """Write every figure and index.html into `directory`; returns the page's path."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    images = [_response(fit.model, p, directory) for p in fit.prepared]
    images.append(_forces(fit.model, fit.prepared, directory))
    images.append(_profile(fit, directory))
    page = directory / "index.html"
    body = "\n".join(f'<figure><img src="{i.name}" alt="{i.stem}"></figure>' for i in images)
    page.write_text("<!doctype html><html><head><meta charset='utf-8'><title>analysis fit"
                    "</title></head><body><h1>Identified isolator</h1><pre>"
                    f"{html.escape(format_fit(fit))}</pre>\n{body}\n</body></html>\n",
                    encoding="utf-8")
    return page


def _response(model: IsolatorModel, p: PreparedRun, directory: Path) -> Path:
    r = simulate(model, p.oe.motion, duration=p.oe.t[-1] - p.oe.t[0], dt=p.oe.dt, t0=p.oe.t[0],
                 z0=initial_offset(p.oe))
    n = min(r.t.size, p.z.size)
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(8, 8))
    for ax, meas, sim, label in ((axes[0], p.z, r.z, "z (m)"), (axes[1], p.zd, r.zd, "ż (m/s)"),
                                 (axes[2], p.xdd, r.xdd, "ẍ (m/s²)")):
        ax.plot(p.run.t[:n], meas[:n], lw=1.0, label="measured")
        ax.plot(r.t[:n], sim[:n], "--", lw=1.0, label="model")
        ax.set_ylabel(label)
    axes[0].legend()
    axes[0].set_title(f"run {p.run.name}: measured and model response")
    axes[-1].set_xlabel("t (s)")
    return _save(fig, directory / f"response_{p.run.name}.png")


def _curve(model: IsolatorModel, names: tuple[str, ...], z: np.ndarray, zd: np.ndarray
           ) -> np.ndarray:
    from analysis.identify.regressors import regressor_matrix

    Z = regressor_matrix(model, z, zd)
    coefs = np.array([t.coef if t.name in names else 0.0 for t in model.terms])
    return Z @ coefs


def _forces(model: IsolatorModel, runs: tuple[PreparedRun, ...], directory: Path) -> Path:
    zmax = max(float(np.abs(p.z).max()) for p in runs)
    vmax = max(float(np.abs(p.zd).max()) for p in runs)
    z, v = np.linspace(-zmax, zmax, 401), np.linspace(-vmax, vmax, 401)
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    a.plot(z, _curve(model, SPRING, z, np.zeros_like(z)))
    a.set(xlabel="z (m)", ylabel="f1 (N)", title="spring force f1(z)")
    # the damper with |z| outside the dead band, as during a stroke
    b.plot(v, _curve(model, DAMPER, np.full_like(v, 2 * model.dead_band + 1e-3), v))
    b.set(xlabel="ż (m/s)", ylabel="f2 (N)", title="damping force f2(ż)")
    return _save(fig, directory / "forces.png")


def _profile(fit: IsolatorFit, directory: Path) -> Path:
    p = fit.projection
    cost = np.where(np.isfinite(p.profile_cost), p.profile_cost, np.nan)
    fig, ax = plt.subplots(figsize=(6, 5))
    c = ax.contourf(p.profile_beta, p.profile_alpha, np.log10(cost), levels=20)
    fig.colorbar(c, label="log10 σ² (N²)")
    shown = fit.model.parameters()
    ax.plot(shown["beta"], shown["alpha"], "r+", ms=12, label="reported estimate")
    ax.set(xscale="log", yscale="log", xlabel="β (s/m)", ylabel="α (1/m)",
           title="equation-error variance over α, β")
    ax.legend()
    return _save(fig, directory / "profile_alpha_beta.png")


def _save(fig: plt.Figure, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
