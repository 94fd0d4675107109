"""Simulate the isolator model against a base motion: fast enough to fit with.

`simulate` returns one response with every force term; `simulate_batch` runs
many parameter sets of one model structure in parallel and returns only the
motion (what identification needs).
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import CubicSpline, PPoly

from analysis.model.isolator import IsolatorModel
from analysis.model.terms import kind
from analysis.simulate.kernel import simulate_jobs, simulate_one, workspace

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
    breaks = np.ascontiguousarray(motion.x, float)
    coefs = kernel_coefs(motion)
    simulate_one(kinds, gated, model.vector(), breaks, coefs, start, dt, n, substeps,
                 z0, zd0, _initial_states(s0, 1, nt)[0], z, zd, xdd, f, s, st, *workspace(nt))
    t = start + dt * np.arange(n)
    u, ud, udd = _table(motion, t)
    forces = {term.name: f[j] for j, term in enumerate(model.terms)}
    forces["static_friction"] = f[nt]
    states = {term.name: s[j] for j, term in enumerate(model.terms)
              if kind(term.kind).has_state}
    return Response(t=t, u=u, ud=ud, udd=udd, x=z + u, z=z, zd=zd, xdd=xdd, forces=forces,
                    states=states, stuck=st > 0.5)


def kernel_coefs(motion: PPoly) -> np.ndarray:
    """`motion`'s coefficients as a strided view, the array type simulate_jobs hands over
    (numba's layout "A"): every caller shares one compiled simulate_one, where a contiguous
    array was a second compile in full, 70 s on a 2-core machine's first `sim` command."""
    padded = np.zeros((motion.c.shape[0], motion.c.shape[1] + 1))
    padded[:, :-1] = motion.c
    return padded[:, :-1]


def _initial_states(s0: ArrayLike | None, rows: int, nt: int) -> np.ndarray:
    """(rows, J) initial internal states from None, one (J,) row or (rows, J)."""
    if s0 is None:
        return np.zeros((rows, nt))
    S = np.atleast_2d(np.asarray(s0, float))
    if S.shape[1] != nt or S.shape[0] not in (1, rows):
        raise ValueError(f"initial states have shape {S.shape}, need ({rows}, {nt}) or ({nt},)")
    # a copy: broadcast_to's view is read-only, and a read-only array is another numba
    # type, so another full compile of the integrator (`sim serve` hands its states)
    return np.broadcast_to(S, (rows, nt)).copy()


def _table(motion: PPoly, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """u, u̇, ü on t, held outside the breaks exactly as the kernel does."""
    tc = np.clip(t, motion.x[0], motion.x[-1])
    inside = (t > motion.x[0]) & (t < motion.x[-1])
    ud = np.where(inside, motion(tc, 1), 0.0)
    return _held(motion, t), ud, np.where(inside, motion(tc, 2), 0.0)


def _held(motion: PPoly, t: np.ndarray) -> np.ndarray:
    """u on t, held at its end values outside the breaks."""
    return motion(np.clip(t, motion.x[0], motion.x[-1]))


# motion → {(start, dt, n): u}: a fit simulates the same runs thousands of times, and
# evaluating a sampled table motion's thousands of pieces at every sample again took
# 2 % of a campaign; weak, so a run's motion takes its grids with it when it goes
_HELD: weakref.WeakKeyDictionary[PPoly, dict[tuple[float, float, int], np.ndarray]] = \
    weakref.WeakKeyDictionary()


def _held_on_grid(motion: PPoly, t: np.ndarray, dt: float) -> np.ndarray:
    """`_held` on the uniform grid t of step dt, read-only: shared by every batch of it."""
    grids = _HELD.setdefault(motion, {})
    key = (float(t[0]), dt, t.size)
    u = grids.get(key)
    if u is None:
        u = grids[key] = _held(motion, t)
        u.flags.writeable = False
    return u


@dataclass(frozen=True)
class BatchResponse:
    """Responses of N parameter sets: arrays are (N, n)."""

    t: np.ndarray
    u: np.ndarray  # (n,), shared between batches (read-only)
    z: np.ndarray
    zd: np.ndarray
    xdd: np.ndarray
    rk4_steps: int = 0  # RK4 steps of every row, an event's trial steps included: the work


@dataclass(frozen=True)
class RunSetup:
    """One run of a batch: the table motion that drives it and where it starts (SI)."""

    motion: PPoly
    duration: float | None = None  # s; None: to the motion's last break
    dt: float = DEFAULT_DT
    t0: float | None = None  # s; None: the motion's first break
    z0: float = 0.0  # relative displacement at t0, m
    zd0: float = 0.0  # relative velocity at t0, m/s


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
    return simulate_runs(model, [RunSetup(motion, duration, dt, t0, z0, zd0)], [vectors],
                         substeps, None if s0 is None else [s0])[0]


def simulate_runs(model: IsolatorModel, setups: Sequence[RunSetup],
                  vectors: Sequence[ArrayLike], substeps: int = DEFAULT_SUBSTEPS,
                  s0: Sequence[ArrayLike | None] | None = None) -> list[BatchResponse]:
    """`simulate_batch` of several runs at once: vectors[k] (N_k rows) on setups[k].

    All rows of all runs share the cores in one parallel call (rows interleaved
    across runs, so that each core gets a share of every run's work).
    s0[k]: run k's initial internal states, as `simulate_batch`'s s0.
    """
    if not setups:
        return []
    for s in setups:
        _check_step(s.dt, substeps)
    nv = model.vector().size
    Ps = [np.atleast_2d(np.asarray(v, float)) for v in vectors]
    for P in Ps:
        if P.shape[1] != nv:
            raise ValueError(f"parameter rows have {P.shape[1]} values, model needs {nv}")
    grids = [_grid(s.motion, s.duration, s.dt, s.t0) for s in setups]
    nt = len(model.terms)
    states = [_initial_states(None if s0 is None else s0[k], P.shape[0], nt)
              for k, P in enumerate(Ps)]
    # job order (row i of every run, then row i + 1, …): static chunks stay balanced
    jobs = sorted(((i, k) for k, P in enumerate(Ps) for i in range(P.shape[0])))
    job_run = np.array([k for _, k in jobs], np.int64)
    P_all = np.ascontiguousarray([Ps[k][i] for i, k in jobs]).reshape(len(jobs), nv)
    S_all = np.ascontiguousarray([states[k][i] for i, k in jobs]).reshape(len(jobs), nt)
    n_breaks = np.array([s.motion.x.size for s in setups], np.int64)
    degree = max(s.motion.c.shape[0] for s in setups)
    breaks = np.zeros((len(setups), n_breaks.max()))
    coefs = np.zeros((len(setups), degree, n_breaks.max() - 1))
    for m, s in enumerate(setups):
        breaks[m, :n_breaks[m]] = s.motion.x
        coefs[m, degree - s.motion.c.shape[0]:, :n_breaks[m] - 1] = s.motion.c
    n_out = np.array([n for _, n in grids], np.int64)
    z, zd, xdd = (np.empty((len(jobs), n_out.max())) for _ in range(3))
    kinds, gated = model.structure()
    steps = np.zeros(len(jobs), np.int64)
    simulate_jobs(kinds, gated, P_all, job_run, breaks, n_breaks, coefs,
                  np.array([g[0] for g in grids]), np.array([s.dt for s in setups]), n_out,
                  substeps, np.array([s.z0 for s in setups], float),
                  np.array([s.zd0 for s in setups], float), S_all, z, zd, xdd, steps)
    out = []
    for k, (s, (start, n)) in enumerate(zip(setups, grids)):
        rows = [j for j, (_, kk) in enumerate(jobs) if kk == k]
        t = start + s.dt * np.arange(n)
        out.append(BatchResponse(t=t, u=_held_on_grid(s.motion, t, s.dt), z=z[rows, :n],
                                 zd=zd[rows, :n], xdd=xdd[rows, :n],
                                 rk4_steps=int(steps[rows].sum())))
    return out
