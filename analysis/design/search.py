"""Find the constants: a global sample of the box, then a local search from its best.

The peaks are non-smooth in the constants (a max over time and over threats, a
dead band, stick-slip), so no derivative is used. Every stage hands the
simulator a batch of constant sets at once — one `simulate_runs` call per stage
or round — so that both cores stay busy and the call's overhead is paid once.

1. A scrambled Sobol sample of the unit box (log-scaled constants on a log scale),
   with the current isolator: the trade-off's first picture and the starts.
2. From the best few distinct points, a local search: each round samples a box of
   half-width r around each start (Sobol again) plus the linear model's step of
   the round before (`problem`), moves to the best point that beats the start and
   widens r by half, else halves r. A start stops when r falls below `min_radius`
   of the box, or after `stall` moves in a row that gained less than `gain`.

Every evaluated point is kept (the `Archive`): the Pareto front is drawn from all.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.stats import qmc

from analysis.design.objective import Evaluator, Peaks
from analysis.design.problem import Problem, best, gradients
from analysis.design.space import DesignSpace

# progress(round, excess, value, radius) of the best point after each round
RoundProgress = Callable[[int, float, float, float], None]


@dataclass(frozen=True)
class Settings:
    samples: int = 256  # the global sample (a power of two: Sobol's balance)
    local: int = 0  # samples per start and round; 0: the least power of two ≥ max(16, d + 1)
    starts: int = 3  # distinct points the local search starts from
    radius: float = 0.125  # first half-width of the local box, of the unit box
    min_radius: float = 5e-3  # a start stops below this …
    stall: int = 4  # … or after this many moves in a row …
    gain: float = 1e-4  # … each of which gained less than this fraction
    rounds: int = 30  # at most
    seed: int = 0


class Archive:
    """Every design evaluated: free constants (N, d) SI and peaks (N, K) SI."""

    def __init__(self, d: int, k: int) -> None:
        self.values = np.zeros((0, d))
        self.accel = np.zeros((0, k))
        self.stroke = np.zeros((0, k))

    def add(self, values: np.ndarray, peaks: Peaks) -> np.ndarray:
        """Append; the new points' indices."""
        start = self.values.shape[0]
        self.values = np.vstack([self.values, values])
        self.accel = np.vstack([self.accel, peaks.accel])
        self.stroke = np.vstack([self.stroke, peaks.stroke])
        return np.arange(start, self.values.shape[0])

    @property
    def peaks(self) -> Peaks:
        return Peaks(self.accel, self.stroke)

    @property
    def worst_accel(self) -> np.ndarray:
        """(N,) the largest over the threats."""
        return self.peaks.worst_accel

    @property
    def worst_stroke(self) -> np.ndarray:
        return self.peaks.worst_stroke

    def score(self, problem: Problem) -> tuple[np.ndarray, np.ndarray]:
        return problem.score(self.worst_accel, self.worst_stroke)


def sample_size(settings: Settings) -> int:
    """Designs in the global sample: `samples` rounded up to a power of two."""
    return 2 ** _log2(settings.samples)


def evaluate_into(archive: Archive, space: DesignSpace, evaluate: Evaluator,
                  values: np.ndarray) -> np.ndarray:
    """Simulate designs (N, d) SI, keep them in the archive; their indices."""
    return archive.add(values, evaluate(space.rows(values)))


def global_sample(space: DesignSpace, evaluate: Evaluator, settings: Settings,
                  extra: np.ndarray | None = None) -> Archive:
    """Stage 1: `extra` designs (SI (M, d), first) and the Sobol sample of the box."""
    d = len(space.bounds)
    U = qmc.Sobol(d, scramble=True, seed=settings.seed).random_base2(_log2(settings.samples))
    values = space.values(U)
    if extra is not None:
        values = np.vstack([np.atleast_2d(extra), values])
    archive = Archive(d, evaluate.threats)
    evaluate_into(archive, space, evaluate, values)
    return archive


def starts(archive: Archive, space: DesignSpace, problem: Problem, count: int,
           apart: float = 0.2) -> list[int]:
    """The best `count` points at least `apart` (unit box, max-norm) from each other."""
    excess, value = archive.score(problem)
    order = np.lexsort((value, excess))
    X = space.coords(archive.values)
    chosen: list[int] = []
    for i in order:
        if not (np.isfinite(excess[i]) and np.isfinite(value[i])) or len(chosen) == count:
            break
        if all(np.max(np.abs(X[i] - X[j])) >= apart for j in chosen):
            chosen.append(int(i))
    return chosen or [int(order[0])]


@dataclass
class _Start:
    centre: int  # archive index
    radius: float
    step: np.ndarray  # the linear model's move for the next round, unit box
    stalled: int = 0  # moves in a row without a real gain

    def active(self, s: Settings) -> bool:
        return self.radius >= s.min_radius and self.stalled < s.stall


def local_search(archive: Archive, space: DesignSpace, evaluate: Evaluator, problem: Problem,
                 settings: Settings, begin: list[int],
                 progress: RoundProgress = lambda *a: None) -> tuple[int, int]:
    """Stage 2 from the archive's points `begin`; (index of the best point, rounds run)."""
    d = len(space.bounds)
    runs = [_Start(i, settings.radius, np.zeros(d)) for i in begin]
    rounds = 0
    while rounds < settings.rounds and any(s.active(settings) for s in runs):
        rounds += 1
        active = [s for s in runs if s.active(settings)]
        q = 2.0 * qmc.Sobol(d, scramble=True, seed=settings.seed + rounds).random_base2(
            _log2(settings.local or max(16, d + 1))) - 1.0
        X = space.coords(archive.values[[s.centre for s in active]])
        U = [np.clip(np.vstack([x + s.radius * q, x + s.step]), 0.0, 1.0)
             for x, s in zip(X, active)]
        new = evaluate_into(archive, space, evaluate, space.values(np.concatenate(U)))
        excess, value = archive.score(problem)
        for k, (x, s, u) in enumerate(zip(X, active, U)):
            mine = new[k * len(u):(k + 1) * len(u)]
            slopes = _slopes(archive, s.centre, u[:-1] - x, mine[:-1])
            _move(s, int(mine[best(excess[mine], value[mine])]), excess, value, settings)
            s.step = _model_step(archive, space, problem, s, slopes)
        _merge(runs, archive, space, excess, value)
        top = min(runs, key=lambda s: (excess[s.centre], value[s.centre]))
        progress(rounds, excess[top.centre], value[top.centre],
                 max(s.radius for s in runs))
    excess, value = archive.score(problem)
    return min(runs, key=lambda s: (excess[s.centre], value[s.centre])).centre, rounds


def _slopes(archive: Archive, centre: int, dX: np.ndarray, rows: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray] | None:
    """Both peaks' slopes in the unit box, fitted to a round's points around `centre`."""
    a, z = archive.worst_accel, archive.worst_stroke
    return gradients(dX, a[rows] - a[centre], z[rows] - z[centre])


def _model_step(archive: Archive, space: DesignSpace, problem: Problem, s: _Start,
                slopes: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """The linear model's move from the start's (new) centre, within its box and the
    unit box."""
    a, z = archive.worst_accel[s.centre], archive.worst_stroke[s.centre]
    x = space.coords(archive.values[s.centre])[0]
    if slopes is None or not (np.isfinite(a) and np.isfinite(z)):
        return np.zeros(x.size)
    return problem.step(a, z, *slopes, np.maximum(-s.radius, -x), np.minimum(s.radius, 1 - x))


def _move(s: _Start, j: int, excess: np.ndarray, value: np.ndarray, st: Settings) -> None:
    """Move start `s` to point j if it beats its centre; adapt the radius."""
    c = s.centre
    if (excess[j], value[j]) < (excess[c], value[c]):
        real = (excess[j] < excess[c] - st.gain * excess[c]
                or value[j] < value[c] - st.gain * abs(value[c]) or not np.isfinite(value[c]))
        s.stalled = 0 if real else s.stalled + 1
        s.centre, s.radius = j, min(1.5 * s.radius, 0.5)
    else:
        s.radius *= 0.5


def _merge(runs: list[_Start], archive: Archive, space: DesignSpace, excess: np.ndarray,
           value: np.ndarray) -> None:
    """Two starts that met (closer than the larger radius): the worse one stops."""
    live = [s for s in runs if s.radius > 0]
    X = space.coords(archive.values[[s.centre for s in live]])
    for i, a in enumerate(live):
        for j in range(i + 1, len(live)):
            b = live[j]
            if a.radius and b.radius and np.max(np.abs(X[i] - X[j])) < max(a.radius,
                                                                             b.radius):
                worse = b if (excess[a.centre], value[a.centre]) <= \
                    (excess[b.centre], value[b.centre]) else a
                worse.radius = 0.0


def _log2(n: int) -> int:
    return int(np.ceil(np.log2(max(n, 2))))
