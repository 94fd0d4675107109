"""The fit's figures as PNG, in the user's units, for the report page.

Per run, measured against model: relative displacement, relative velocity and
mass acceleration (the report's Figures 13–16), with the model after the loop's
effects where it added any; the spring force f1(z) and the damping force f2(ż) of
the identified model (Figures 17–18); and the profile of the equation-error
variance over α and β (minimised over δ and the linear coefficients), which shows
how weakly a saturating tanh pins them down.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from analysis.identify.pipeline import IsolatorFit
from analysis.identify.prepare import PreparedRun
from analysis.identify.run_data import initial_offset
from analysis.model.isolator import IsolatorModel
from analysis.simulate import simulate
from rig.units import POUND_FORCE, from_si

SPRING = ("k1", "k2")
DAMPER = ("c1", "c2")
# the report plots z in inches, ż in in/s and ẍ in g (Figures 13–18)
UNITS = {"us": {"z": "in", "zd": "in/s", "xdd": "g", "force": "lb", "alpha": "1/in",
                "beta": "s/in"},
         "si": {"z": "m", "zd": "m/s", "xdd": "m/s^2", "force": "N", "alpha": "1/m",
                "beta": "s/m"}}


@dataclass(frozen=True)
class Figure:
    """A PNG written beside the page, and what it shows."""

    path: Path
    caption: str


def fit_figures(fit: IsolatorFit, directory: Path, units: str = "us",
                after: Mapping[str, np.ndarray] | None = None) -> list[Figure]:
    """Write the fit's figures into `directory` in `units` ("us" or "si").

    `after`: run name → the mass displacement x (m, on the run's samples) that the model
    with the loop's effects predicts, drawn beside Eq 10's; None: Eq 10 only.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    out = [_response(fit.model, p, directory, units, (after or {}).get(p.run.name))
           for p in fit.prepared]
    out.append(_forces(fit.model, fit.prepared, directory, units))
    out.append(_profile(fit, directory, units))
    return out


def _response(model: IsolatorModel, p: PreparedRun, directory: Path, units: str,
              x_after: np.ndarray | None) -> Figure:
    r = simulate(model, p.oe.motion, duration=p.oe.t[-1] - p.oe.t[0], dt=p.oe.dt, t0=p.oe.t[0],
                 z0=initial_offset(p.oe))
    n = min(r.t.size, p.z.size)
    u = UNITS[units]
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(8, 8))
    rows = (("z", "a. relative displacement z", p.z, r.z),
            ("zd", "b. relative velocity ż", p.zd, r.zd),
            ("xdd", "c. mass acceleration ẍ", p.xdd, r.xdd))
    traces = _after_traces(p, x_after) if x_after is not None else None
    for ax, (key, label, meas, sim) in zip(axes, rows):
        ax.plot(p.run.t[:n], from_si(meas[:n], u[key]), lw=1.0, label="measured")
        ax.plot(r.t[:n], from_si(sim[:n], u[key]), "--", lw=1.0, label="model (Eq 10)")
        if traces is not None:
            m = min(n, traces[key].size)
            ax.plot(p.run.t[:m], from_si(traces[key][:m], u[key]), ":", lw=1.2,
                    label="model with the loop's effects")
        ax.set_ylabel(f"{label} ({u[key]})")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[0].set_title(f"run {p.run.name}: measured and model response")
    axes[-1].set_xlabel("t (s)")
    caption = (f"Run {p.run.name}: relative displacement, relative velocity and mass "
               f"acceleration, measured and model (as the report's Figures 13–16)")
    return Figure(_save(fig, directory / f"response_{p.run.name}.png"), caption)


def _after_traces(p: PreparedRun, x: np.ndarray) -> dict[str, np.ndarray]:
    """z, ż, ẍ of a predicted x as `run_errors.compare` takes them: differences of x."""
    t = p.oe.t[:x.size]
    xd = np.gradient(x, t)
    return {"z": x - p.oe.motion(t), "zd": xd - p.oe.motion.derivative()(t),
            "xdd": np.gradient(xd, t)}


def _curve(model: IsolatorModel, names: tuple[str, ...], z: np.ndarray, zd: np.ndarray
           ) -> np.ndarray:
    from analysis.identify.regressors import regressor_matrix

    Z = regressor_matrix(model, z, zd)
    coefs = np.array([t.coef if t.name in names else 0.0 for t in model.terms])
    return Z @ coefs


def _forces(model: IsolatorModel, runs: tuple[PreparedRun, ...], directory: Path,
            units: str) -> Figure:
    zmax = max(float(np.abs(p.z).max()) for p in runs)
    vmax = max(float(np.abs(p.zd).max()) for p in runs)
    z, v = np.linspace(-zmax, zmax, 401), np.linspace(-vmax, vmax, 401)
    u = UNITS[units]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    a.plot(from_si(z, u["z"]), from_si(_curve(model, SPRING, z, np.zeros_like(z)), u["force"]))
    a.set(xlabel=f"z ({u['z']})", ylabel=f"f1 ({u['force']})", title="spring force f1(z)")
    # the damper with |z| outside the dead band, as during a stroke
    f2 = _curve(model, DAMPER, np.full_like(v, 2 * model.dead_band + 1e-3), v)
    b.plot(from_si(v, u["zd"]), from_si(f2, u["force"]))
    b.set(xlabel=f"ż ({u['zd']})", ylabel=f"f2 ({u['force']})", title="damping force f2(ż)")
    for ax in (a, b):
        ax.grid(alpha=0.3)
    caption = ("The identified spring force f1(z) = k1 z + k2 tanh(αz) and damping force "
               "f2(ż) = c1 ż + c2 tanh(βż) (as the report's Figures 17–18)")
    return Figure(_save(fig, directory / "forces.png"), caption)


def _profile(fit: IsolatorFit, directory: Path, units: str) -> Figure:
    p = fit.projection
    u = UNITS[units]
    force = 1.0 if units == "si" else POUND_FORCE
    cost = np.where(np.isfinite(p.profile_cost), p.profile_cost, np.nan) / force ** 2
    fig, ax = plt.subplots(figsize=(6, 5))
    c = ax.contourf(from_si(p.profile_beta, u["beta"]), from_si(p.profile_alpha, u["alpha"]),
                    np.log10(cost), levels=20)
    fig.colorbar(c, label=f"log10 σ² ({u['force']}²)")
    shown = fit.model.parameters()
    ax.plot(from_si(shown["beta"], u["beta"]), from_si(shown["alpha"], u["alpha"]), "r+", ms=12,
            label="reported estimate")
    ax.set(xscale="log", yscale="log", xlabel=f"β ({u['beta']})", ylabel=f"α ({u['alpha']})",
           title="equation-error variance over α, β")
    ax.legend()
    caption = ("Equation-error variance over α and β, minimised over δ and the linear "
               "coefficients: how weakly the runs pin down the tanh shapes")
    return Figure(_save(fig, directory / "profile_alpha_beta.png"), caption)


def _save(fig: plt.Figure, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
