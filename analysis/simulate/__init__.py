"""Simulate the isolator model against a base motion: fast enough to fit with.

`simulate` returns one response with every force term; `simulate_batch` runs
many parameter sets of one model structure in parallel and returns only the
motion (what identification needs).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import CubicSpline, PPoly

from analysis.model.isolator import IsolatorModel
from analysis.model.terms import kind
from analysis.simulate.kernel import simulate_many, simulate_one

DEFAULT_DT = 1e-3  # s, output sample interval (the sensors' 1 kHz)
DEFAULT_SUBSTEPS = 1  # RK4 steps per output sample: at 1 ms, 0.3 µm error on run A


@dataclass(frozen=True)
class Response:
    """A simulated run on the output grid; SI. Arrays are (n,) unless stated."""

    t: np.ndarray  # s
    u: np.ndarray  # table displacement, m
    ud: np.ndarray  # table velocity, m/s
    udd: np.ndarray  # table acceleration, m/s²
    x: np.ndarray  # mass displacement, m
    z: np.ndarray  # relative displacement x − u, m
    zd: np.ndarray  # relative velocity, m/s
    xdd: np.ndarray  # mass acceleration, m/s²
    forces: dict[str, np.ndarray]  # each term's force and "static_friction", N
    states: dict[str, np.ndarray]  # internal state of stateful terms
    stuck: np.ndarray  # bool, static friction holding

    @property
    def total_force(self) -> np.ndarray:
        """Force the isolator exerts on the mass's opposite: m ẍ = −F (N)."""
        return np.sum(list(self.forces.values()), axis=0)


def motion_from_samples(t: ArrayLike, u: ArrayLike) -> PPoly:
    """A sampled table displacement as the piecewise cubic the simulator reads."""
    spline = CubicSpline(np.asarray(t, float), np.asarray(u, float), bc_type="natural")
    return PPoly(spline.c, spline.x)


def _grid(motion: PPoly, duration: float | None, dt: float, t0: float | None):
    start = float(motion.x[0]) if t0 is None else t0
    if duration is None:
        duration = float(motion.x[-1]) - start
    n = int(round(duration / dt)) + 1
    if n < 2:
        raise ValueError(f"duration {duration} s is shorter than one sample of {dt} s")
    return start, n


def _check_step(dt: float, substeps: int) -> None:
    if not (dt > 0 and np.isfinite(dt)):
        raise ValueError(f"output interval must be positive, got {dt} s")
    if substeps < 1:
        raise ValueError(f"substeps must be >= 1, got {substeps}")


def simulate(model: IsolatorModel, motion: PPoly, duration: float | None = None,
             dt: float = DEFAULT_DT, substeps: int = DEFAULT_SUBSTEPS,
             t0: float | None = None, z0: float = 0.0, zd0: float = 0.0,
             s0: ArrayLike | None = None) -> Response:
    """Integrate m ẍ = −F(z, ż, s) for table motion `motion`; samples every `dt` s.

    s0: initial internal state of each term (J,), e.g. the fluid temperature a
    previous run left; zeros by default.
    """
    _check_step(dt, substeps)
    start, n = _grid(motion, duration, dt, t0)
    kinds, gated = model.structure()
    nt = len(model.terms)
    z, zd, xdd = np.empty(n), np.empty(n), np.empty(n)
    f, s, st = np.empty((nt + 1, n)), np.empty((nt, n)), np.empty(n)
    breaks, coefs = np.ascontiguousarray(motion.x, float), np.ascontiguousarray(motion.c, float)
    simulate_one(kinds, gated, model.vector(), breaks, coefs, start, dt, n, substeps,
                 z0, zd0, _initial_states(s0, 1, nt)[0], z, zd, xdd, f, s, st, True)
    t = start + dt * np.arange(n)
    u, ud, udd = _table(motion, t)
    forces = {term.name: f[j] for j, term in enumerate(model.terms)}
    forces["static_friction"] = f[nt]
    states = {term.name: s[j] for j, term in enumerate(model.terms)
              if kind(term.kind).has_state}
    return Response(t=t, u=u, ud=ud, udd=udd, x=z + u, z=z, zd=zd, xdd=xdd, forces=forces,
                    states=states, stuck=st > 0.5)


def _initial_states(s0: ArrayLike | None, rows: int, nt: int) -> np.ndarray:
    """(rows, J) initial internal states from None, one (J,) row or (rows, J)."""
    if s0 is None:
        return np.zeros((rows, nt))
    S = np.atleast_2d(np.asarray(s0, float))
    if S.shape[1] != nt or S.shape[0] not in (1, rows):
        raise ValueError(f"initial states have shape {S.shape}, need ({rows}, {nt}) or ({nt},)")
    return np.ascontiguousarray(np.broadcast_to(S, (rows, nt)))


def _table(motion: PPoly, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """u, u̇, ü on t, held outside the breaks exactly as the kernel does."""
    tc = np.clip(t, motion.x[0], motion.x[-1])
    inside = (t > motion.x[0]) & (t < motion.x[-1])
    return motion(tc), np.where(inside, motion(tc, 1), 0.0), np.where(inside, motion(tc, 2), 0.0)


@dataclass(frozen=True)
class BatchResponse:
    """Responses of N parameter sets: arrays are (N, n)."""

    t: np.ndarray
    u: np.ndarray  # (n,), shared
    z: np.ndarray
    zd: np.ndarray
    xdd: np.ndarray


def simulate_batch(model: IsolatorModel, vectors: ArrayLike, motion: PPoly,
                   duration: float | None = None, dt: float = DEFAULT_DT,
                   substeps: int = DEFAULT_SUBSTEPS, t0: float | None = None,
                   s0: ArrayLike | None = None, z0: float = 0.0, zd0: float = 0.0
                   ) -> BatchResponse:
    """Simulate N parameter vectors (rows laid out as `model.vector()`) in parallel.

    s0: initial internal states, (J,) for every row or (N, J) one per row.
    z0: initial relative displacement (m): a mass the dead band let settle off
    centre starts the next run there. zd0: initial relative velocity (m/s): a
    mass still creeping when the run starts (a constant force beyond breakaway).
    """
    _check_step(dt, substeps)
    P = np.ascontiguousarray(np.atleast_2d(np.asarray(vectors, float)))
    if P.shape[1] != model.vector().size:
        raise ValueError(f"parameter rows have {P.shape[1]} values, model needs "
                         f"{model.vector().size}")
    start, n = _grid(motion, duration, dt, t0)
    kinds, gated = model.structure()
    z, zd, xdd = (np.empty((P.shape[0], n)) for _ in range(3))
    simulate_many(kinds, gated, P, np.ascontiguousarray(motion.x, float),
                  np.ascontiguousarray(motion.c, float), start, dt, n, substeps, z0, zd0,
                  _initial_states(s0, P.shape[0], len(model.terms)), z, zd, xdd)
    t = start + dt * np.arange(n)
    return BatchResponse(t=t, u=_table(motion, t)[0], z=z, zd=zd, xdd=xdd)
