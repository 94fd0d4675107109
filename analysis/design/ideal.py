"""The ideal isolator of the report's Figure 1, as a reference for every design.

Figure 1's dotted lines: a force that rises at once to F and stays at F over the
whole stroke — the isolator that dissipates the most energy for the force it
passes to the equipment. As a passive device it is rigid-plastic: the mass rides
with the table until keeping it there takes more than F, then slides against a
constant F until the relative velocity is zero again. That is exactly a dry
friction term F sgn(ż) with breakaway F and nothing else, which the simulator
already integrates (stick and slip located as events), so the curve comes from
one parallel call over a range of F: each F gives a peak acceleration (F/m, or
less if it never slides) and a peak stroke, each the worst over the threats.

For a base velocity change ΔV it reproduces the textbook bound a = ΔV²/(2 S)
(tests/test_design.py, to the ramp's own share). It is not a proof that no
isolator can do better on every threat — a spring can return the mass between
two pulses where friction leaves it offset — but it is the standard the report
measures designs against. A minimum-stroke optimal control (the limiting
performance of Sevin and Pilkey, a linear programme) would be a true lower bound,
but it is not causal: it moves the mass before the shock arrives. Measured (HiGHS,
2 ms grid): a 1 m/s velocity step 0.1 s into a 1 s record, 0.1 m of stroke, needs
2.5 m/s² by it, where any isolator that waits for the shock needs 5.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from analysis.design.objective import Evaluator
from analysis.design.threat import Threat
from analysis.model.isolator import IsolatorModel, Term

POINTS = 48  # forces on the curve: neighbours 16 % apart over three decades
SPAN = 1e-3  # lowest F/m as a fraction of the threats' peak table acceleration
STOP = 1e-3  # m/s: the relative velocity below which the sliding mass sticks again


@dataclass(frozen=True)
class IdealCurve:
    """Figure 1's isolator at POINTS forces: (M,) arrays, SI, by increasing force."""

    force: np.ndarray  # N
    accel: np.ndarray  # m/s², worst over the threats
    stroke: np.ndarray  # m, worst over the threats
    simulations: int

    def accel_at(self, stroke: float) -> float:
        """The least acceleration whose stroke is within `stroke` (m/s²), interpolated
        between the two forces around it; inf when even the largest F needs more."""
        ok = np.flatnonzero(self.stroke <= stroke)
        if ok.size == 0:
            return float("inf")
        i = int(ok[0])
        if i == 0:
            return float(self.accel[0])
        z0, z1 = self.stroke[i - 1], self.stroke[i]
        w = (z0 - stroke) / (z0 - z1) if z0 > z1 else 1.0
        return float(np.exp((1 - w) * np.log(self.accel[i - 1]) + w * np.log(self.accel[i])))


def ideal_model(mass: float, force: float = 1.0) -> IsolatorModel:
    """Rigid-plastic: dry friction F with breakaway F; mass in kg, F in N."""
    return IsolatorModel(mass, (Term("coulomb", "F", force),), breakaway=force,
                         stop_velocity=STOP, description="ideal isolator (Figure 1)")


def ideal_curve(threats: Sequence[Threat], mass: float, points: int = POINTS) -> IdealCurve:
    """The ideal isolator's (peak acceleration, peak stroke) for POINTS forces."""
    peak_accel = max(th.peak_acceleration() for th in threats)
    accel = peak_accel * np.geomspace(SPAN, 1.0, points)
    model = ideal_model(mass)
    rows = np.tile(model.vector(), (points, 1))
    idx = model.vector_index()
    rows[:, idx["F"]] = rows[:, idx["F_break"]] = mass * accel
    evaluate = Evaluator(model, threats)
    peaks = evaluate(rows)
    return IdealCurve(mass * accel, peaks.worst_accel, peaks.worst_stroke,
                      evaluate.simulations)

