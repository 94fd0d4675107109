"""The runs simulated at given constants: the scaled residual (x_sim − x)/σ_x, its
Jacobian in log coordinates (one parallel batch of perturbed simulations per run),
and slices of the cost along one constant."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from analysis.identify.run_data import RunData, start_state
from analysis.model.isolator import IsolatorModel
from analysis.simulate import RunSetup, simulate_runs

FD_STEP = 1e-3  # log step: large enough to see slopes, not single stick/slip event flips
UNSTABLE = 1e6  # residual (noise units) of a sample whose simulation diverged


def _vectors(model: IsolatorModel, names: Sequence[str], theta: np.ndarray) -> np.ndarray:
    """Rows of kernel parameter vectors: the base point, then each log-step."""
    idx = model.vector_index()
    base = model.vector()
    rows = np.tile(base, (len(names) + 1, 1))
    for j, n in enumerate(names):
        rows[:, idx[n]] = np.exp(theta[j])
        rows[j + 1, idx[n]] = np.exp(theta[j] + FD_STEP)
    return rows


def _setups(model: IsolatorModel, runs: Sequence[RunData]) -> list[RunSetup]:
    return [RunSetup(run.motion, run.t[-1] - run.t[0], run.dt, run.t[0],
                     *start_state(run, dead_band=model.dead_band)) for run in runs]


def _simulated_x(run: RunData, z: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Simulated x (rows, n); a diverged simulation far off."""
    return np.where(np.isfinite(z), z + u, UNSTABLE * run.sigma_x)


def slice_residuals(model: IsolatorModel, runs: Sequence[RunData], name: str,
                    values: Sequence[float]) -> np.ndarray:
    """(len(values), n) scaled residual of all runs with constant `name` at each of
    `values`, the rest as in `model`: one parallel batch. A slice of the cost, not a
    profile: the other constants are not refitted, so it can only understate how far
    a value can go."""
    rows = np.tile(model.vector(), (len(values), 1))
    rows[:, model.vector_index()[name]] = values
    batches = simulate_runs(model, _setups(model, runs), [rows] * len(runs))
    return np.hstack([(_simulated_x(run, b.z, b.u) - run.x) / run.sigma_x
                      for run, b in zip(runs, batches)])


def residual_and_jacobian(model: IsolatorModel, names: Sequence[str], theta: np.ndarray,
                          runs: Sequence[RunData], with_jacobian: bool,
                          base: Sequence[np.ndarray] | None = None
                          ) -> tuple[np.ndarray, np.ndarray | None, list[np.ndarray]]:
    """Scaled residual (x_sim − x)/σ_x of all runs, its Jacobian in log coordinates,
    and the simulated x of each run at θ.

    `base`: each run's simulated x at θ when already known (the optimiser asks for
    the residual at θ before the Jacobian there), so the batch simulates only the
    perturbed rows: 8 instead of 9 per run, one round fewer on two cores.
    """
    rows = _vectors(model, names, theta)
    rows = rows if with_jacobian else rows[:1]
    if base is not None:
        rows = rows[1:]
    batches = simulate_runs(model, _setups(model, runs), [rows] * len(runs))
    res, jac, xs = [], [], []
    for k, (run, b) in enumerate(zip(runs, batches)):
        x = _simulated_x(run, b.z, b.u)
        if base is not None:
            x = np.vstack([base[k][None, :], x])
        xs.append(x[0])
        res.append((x[0] - run.x) / run.sigma_x)
        if with_jacobian:
            jac.append(((x[1:] - x[0]) / run.sigma_x / FD_STEP).T)
    return np.concatenate(res), (np.vstack(jac) if with_jacobian else None), xs


def scaled_residual(model: IsolatorModel, runs: Sequence[RunData]) -> np.ndarray:
    """(x_sim − x)/σ_x of all runs, concatenated, at `model`."""
    return residual_and_jacobian(model, (), np.empty(0), runs, False)[0]
