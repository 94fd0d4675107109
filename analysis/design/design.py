"""`design`: the constants that protect the equipment best, or why none can.

The problem (the report's second use of a model, chapter 1): under every threat,
keep the relative displacement within the rattle space S (the stroke limit) and,
among the constants that do, take the ones with the least peak mass acceleration;
then say whether that acceleration is within the equipment's fragility a_max.

1. The box of sensible constants (`space`) and the evaluator (`objective`).
2. The search (`search`): a global sample with the current isolator, then a local
   search from its best points, by the feasibility rule.
3. If the optimum misses a limit: a second local search for the closest design,
   the one that needs both limits relaxed by the least common factor.
4. The optimum and the current isolator once more at 1 ms with 8 substeps and a
   longer tail (`verify`), the ideal isolator's curve (`ideal`), the tolerances
   (`sensitivity`) and the Pareto front of everything simulated (`pareto`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from analysis.design.ideal import IdealCurve, ideal_curve
from analysis.design.objective import Evaluator
from analysis.design.pareto import pareto_front
from analysis.design.problem import Limits, closest, within_stroke
from analysis.design.search import (
    Archive,
    Settings,
    global_sample,
    local_search,
    sample_size,
    starts,
)
from analysis.design.sensitivity import TOLERANCE, Tolerance, tolerances
from analysis.design.space import CENTRING, DesignSpace, Scales
from analysis.design.threat import Threat
from analysis.model.isolator import IsolatorModel
from rig.units import STANDARD_GRAVITY as G

VERIFY_DT = 1e-3  # s
VERIFY_SUBSTEPS = 8
VERIFY_TAIL = 5.0  # s after each record: the slowest sensible isolator has settled
CLOSEST_STARTS = 2
EDGE = 1e-3  # of the box: a constant this close to a bound is reported as at it


@dataclass(frozen=True)
class Checked:
    """A design's peaks at the verification step, per threat (K,), SI."""

    accel: np.ndarray
    stroke: np.ndarray


@dataclass(frozen=True)
class DesignResult:
    """Everything `design` found; SI. Indices point into `archive`."""

    model: IsolatorModel  # the user's isolator, every term, the equipment's mass
    designed: IsolatorModel  # the same with the optimum's constants
    space: DesignSpace
    threats: tuple[str, ...]
    limits: Limits
    archive: Archive
    current: int
    optimum: int
    closest: int | None  # the design nearest to meeting both, when the optimum does not
    checked: dict[str, Checked]  # "optimum", "current" at the verification step
    ideal: IdealCurve
    front: np.ndarray  # archive indices of the Pareto front
    tolerances: list[Tolerance]
    tolerance: float  # `within` level of the tolerances
    at_edge: dict[str, str]  # free constants of the optimum at a bound: name → "low"/"high"
    simulations: dict[str, int]  # stage → single runs simulated
    rounds: int
    elapsed: float  # s

    @property
    def stroke_met(self) -> bool:
        return bool(self.archive.worst_stroke[self.optimum] <= self.limits.stroke)

    @property
    def feasible(self) -> bool:
        return self.stroke_met and bool(self.archive.worst_accel[self.optimum]
                                        <= self.limits.accel)

    @property
    def ideal_accel(self) -> float:
        """The ideal isolator's least acceleration within the stroke limit (m/s²)."""
        return self.ideal.accel_at(self.limits.stroke)


def scales(mass: float, threats: Sequence[Threat], stroke: float, ideal: IdealCurve
           ) -> Scales:
    """What the default box is scaled by: the ideal isolator's acceleration within
    `stroke`, and no less than the softest centring spring's at it."""
    a0 = ideal.accel_at(stroke)
    if not np.isfinite(a0):  # not even the stiffest ideal isolator keeps it
        a0 = float(np.max(ideal.accel))
    return Scales(mass, max(a0, (2 * np.pi * CENTRING) ** 2 * stroke), stroke,
                  max(th.peak_velocity() for th in threats))


def design(model: IsolatorModel, space: DesignSpace, threats: Sequence[Threat],
           limits: Limits, settings: Settings | None = None, tolerance: float = TOLERANCE,
           progress: Callable[[str], None] = lambda m: None,
           ideal: IdealCurve | None = None) -> DesignResult:
    """Search `space` for the optimum under `threats` and `limits` (see the module's doc).

    `ideal`: the ideal isolator's curve for these threats and this mass, if already drawn.
    """
    start = time.perf_counter()
    settings = settings or Settings()
    evaluate = Evaluator(space.model, threats)
    counts = {}
    progress(f"global sample: the current isolator and {sample_size(settings)} designs of "
             f"the box, x {len(threats)} threat(s)")
    archive = global_sample(space, evaluate, settings, extra=space.current())
    counts["global sample"] = evaluate.simulations
    optimum, near, rounds = optimise(archive, space, evaluate, limits, settings, progress)
    counts["local search"] = evaluate.simulations - counts["global sample"]
    progress("tolerances")
    tol = tolerances(space, evaluate, archive.values[optimum], limits, tolerance)
    counts["tolerances"] = evaluate.simulations - sum(counts.values())
    if ideal is None:
        progress("the ideal isolator")
        ideal = ideal_curve(threats, model.mass)
    progress("fine-step check of the optimum and the current isolator")
    counts["ideal isolator"] = ideal.simulations
    checked, counts["fine-step check"] = verify(space, threats, archive.values[[0, optimum]])
    return DesignResult(
        model=model, designed=space.designed(model, archive.values[optimum]), space=space,
        threats=tuple(th.name for th in threats), limits=limits, archive=archive, current=0,
        optimum=optimum, closest=near,
        checked={"current": checked[0], "optimum": checked[1]}, ideal=ideal,
        front=pareto_front(archive.worst_accel, archive.worst_stroke), tolerances=tol,
        tolerance=tolerance, at_edge=at_edge(space, archive.values[optimum]),
        simulations=counts, rounds=rounds, elapsed=time.perf_counter() - start)


def optimise(archive: Archive, space: DesignSpace, evaluate: Evaluator, limits: Limits,
             settings: Settings, progress: Callable[[str], None]
             ) -> tuple[int, int | None, int]:
    """The optimum within the stroke and, if it misses a limit, the closest design:
    (optimum, closest or None, local rounds run), archive indices."""
    score = within_stroke(limits)
    optimum, rounds = local_search(archive, space, evaluate, score, settings,
                                   starts(archive, space, score, settings.starts),
                                   _rounds(progress, "local search", G, "g"))
    if (archive.worst_stroke[optimum] <= limits.stroke
            and archive.worst_accel[optimum] <= limits.accel):
        return optimum, None, rounds
    progress("no design meets both limits: searching for the closest")
    score = closest(limits)
    # from the best points of everything simulated so far: fewer starts do
    near, more = local_search(archive, space, evaluate, score, settings,
                              starts(archive, space, score, CLOSEST_STARTS),
                              _rounds(progress, "closest", 1.0, "x the limits"))
    return optimum, near, rounds + more


def _rounds(progress: Callable[[str], None], what: str, unit: float, name: str
            ) -> Callable[[int, float, float, float], None]:
    def report(k: int, excess: float, value: float, radius: float) -> None:
        beyond = f", stroke {100 * excess:.2g} % beyond" if excess > 0 else ""
        progress(f"{what} round {k}: best {value / unit:.4g} {name}{beyond}, "
                 f"radius {radius:.2g}")
    return report


def verify(space: DesignSpace, threats: Sequence[Threat], values: np.ndarray
           ) -> tuple[list[Checked], int]:
    """Designs (N, d) at 1 ms, 8 substeps, a 5 s tail: their peaks, and the runs it took."""
    evaluate = Evaluator(space.model, threats, dt=VERIFY_DT, tail=VERIFY_TAIL,
                         substeps=VERIFY_SUBSTEPS)
    peaks = evaluate(space.rows(values))
    return ([Checked(peaks.accel[i], peaks.stroke[i]) for i in range(values.shape[0])],
            evaluate.simulations)


def at_edge(space: DesignSpace, values: np.ndarray) -> dict[str, str]:
    """Free constants of `values` (d,) within EDGE of a bound of the box: "low" or "high"."""
    u = space.coords(values)[0]
    return {n: "low" if x <= EDGE else "high" for n, x in zip(space.names, u)
            if x <= EDGE or x >= 1 - EDGE}
