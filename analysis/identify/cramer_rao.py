"""Cramér–Rao bounds for the output-error constants of step-pulse runs.

Both sensors are noisy, so there are two bounds worth knowing:

- **x only**: the table motion known exactly, only the mass sensor's white
  noise σ_x: cov(log θ) ≥ (JᵀJ)⁻¹, J = ∂x_sim/∂log θ / σ_x.
- **errors in variables**: the table motion unknown too. A step-pulse run is a
  handful of numbers p (the start level, each segment's duration, each ramp's
  end level; `rig.profile`), seen through the table sensor (σ_u) and, through
  the isolator, the mass sensor. The Fisher information of (θ, p) is

      [ JᵀJ        JᵀJ_xp                ]
      [ J_xpᵀJ     J_xpᵀJ_xp + J_upᵀJ_up ]

  with J_xp = ∂x_sim/∂p / σ_x and J_up = ∂u/∂p / σ_u, p's block one per run.
  The bound on θ is the inverse of its Schur complement: the information on θ
  less what is spent on not knowing the input. No unbiased estimator that
  treats u as measured can beat it; the x-only bound can be beaten by none
  that knows u exactly, which no real rig does.

Relative standard deviations (log coordinates) are returned.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from analysis.identify.residuals import residual_and_jacobian
from analysis.identify.run_data import RunData
from analysis.model.isolator import IsolatorModel
from analysis.simulate import simulate
from rig.profile import Profile, load_profile

STEP_TIME = 1e-5  # s: a segment's duration perturbed by this moves x smoothly
STEP_LEVEL = 1e-6  # m


@dataclass(frozen=True)
class Bounds:
    """Relative std bounds (σ(θ)/θ) of `names`: x only, and errors in variables."""

    names: tuple[str, ...]
    x_only: np.ndarray
    errors_in_variables: np.ndarray


def profile_parameters(profile: Profile) -> np.ndarray:
    """p: [start level, then each segment's duration, then each ramp's end level]."""
    return np.array([profile.start, *[s.duration for s in profile.segments],
                     *[s.target for s in profile.segments if s.is_ramp]])


def with_parameters(profile: Profile, p: np.ndarray) -> Profile:
    """`profile` with the numbers of `profile_parameters` replaced by p."""
    n = len(profile.segments)
    targets = iter(p[1 + n:])
    segments = tuple(replace(s, duration=float(d),
                             target=float(next(targets)) if s.is_ramp else s.target)
                     for s, d in zip(profile.segments, p[1:1 + n]))
    return replace(profile, start=float(p[0]), segments=segments)


def _steps(profile: Profile) -> np.ndarray:
    n, r = len(profile.segments), sum(s.is_ramp for s in profile.segments)
    return np.r_[STEP_LEVEL, np.full(n, STEP_TIME), np.full(r, STEP_LEVEL)]


def _input_jacobians(model: IsolatorModel, profile: Profile, t: np.ndarray, sigma_u: float,
                     sigma_x: float) -> tuple[np.ndarray, np.ndarray]:
    """(J_xp, J_up): the simulated x's and u's derivatives over p, in noise units."""
    p0, h = profile_parameters(profile), _steps(profile)
    dt, span = float(t[1] - t[0]), float(t[-1] - t[0])

    def response(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r = simulate(model, with_parameters(profile, p).motion(), duration=span, dt=dt)
        return r.x[:t.size], r.u[:t.size]

    x0, u0 = response(p0)
    Jx, Ju = np.empty((t.size, p0.size)), np.empty((t.size, p0.size))
    for j in range(p0.size):
        p = p0.copy()
        p[j] += h[j]
        x, u = response(p)
        Jx[:, j] = (x - x0) / sigma_x / h[j]
        Ju[:, j] = (u - u0) / sigma_u / h[j]
    # a number that moves nothing in the record (the final hold's length) is no parameter
    acts = (np.abs(Jx).max(axis=0) > 0) | (np.abs(Ju).max(axis=0) > 0)
    return Jx[:, acts], Ju[:, acts]


def cramer_rao(model: IsolatorModel, names: Sequence[str], profiles: Sequence[str] =
               ("A", "B", "C"), sigma_u: float = 2.54e-5, sigma_x: float = 2.54e-5,
               rate: float = 1000.0) -> Bounds:
    """Both bounds for the constants `names` of `model`, from runs of `profiles`."""
    names = tuple(names)
    runs, profs = [], []
    for name in profiles:
        prof = load_profile(name)
        r = simulate(model, prof.motion(), duration=prof.duration, dt=1.0 / rate)
        runs.append(RunData(prof.name, r.t, prof.motion(), r.x, sigma_x))
        profs.append(prof)
    theta = np.log([model.parameters()[n] for n in names])
    _, J, _ = residual_and_jacobian(model, names, theta, runs, True)
    info = J.T @ J
    schur = info.copy()
    start = 0
    for run, prof in zip(runs, profs):
        rows = slice(start, start + run.t.size)
        start += run.t.size
        Jx, Ju = _input_jacobians(model, prof, run.t, sigma_u, sigma_x)
        cross = J[rows].T @ Jx
        schur -= cross @ np.linalg.solve(Jx.T @ Jx + Ju.T @ Ju, cross.T)
    return Bounds(names, np.sqrt(np.diag(np.linalg.inv(info))),
                  np.sqrt(np.diag(np.linalg.inv(schur))))


__all__ = ["Bounds", "cramer_rao", "profile_parameters", "with_parameters"]
