"""The loop refit's Jacobian from the motion's forward sensitivities (`simulate.tangent`)
against the finite differences it replaces, sensor map and start state included."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from analysis.identify.run_data import RunData
from analysis.model.isolator import Term
from analysis.simulate import simulate
from rig.profile import load_profile

R = importlib.import_module("analysis.loop.refit")  # `analysis.loop.refit` names the function

# numeric; the first call compiles the tangent integrator where the cache is cold
pytestmark = [pytest.mark.numeric, pytest.mark.timeout(900)]

SIGMA = 2.54e-5  # m, the rig's sensor noise


def _runs(model, seed: int = 3) -> list[RunData]:
    rng = np.random.default_rng(seed)
    runs = []
    for name in "ABC":
        prof = load_profile(name)
        r = simulate(model, prof.motion(), duration=prof.duration)
        runs.append(RunData(name, r.t, prof.motion(), r.x + SIGMA * rng.standard_normal(r.x.size),
                            SIGMA))
    return runs


def _jacobian(h, runs, names, tangent: bool, step: float) -> np.ndarray:
    scales = np.array([abs(h.value(n)) for n in names])
    ev = R._Evaluator(h, runs, tuple(names), scales, list(range(len(runs))), step, tangent)
    theta = np.ones(len(names))
    ev.residual(theta)
    return ev.jacobian(theta)


@pytest.mark.parametrize("extra", [
    {"params": {"c3": 300.0}},
    {"term": Term("bouc_wen", "k_h", 2.0e4, (0.75 / 0.0025**1.5, 0.25 / 0.0025**1.5, 1.5)),
     "fresh": True},
], ids=["eq10_and_a_cubic_damper", "bouc_wen_each_run_fresh"])
def test_the_tangent_jacobian_gives_the_converged_slopes_with_the_sensor_map(average_model,
                                                                            extra):
    """Every column of d residual / d θ: the model's constants and the dead band through
    the tangent, the sensor's gain (which also moves each run's start, read from the
    data) and delay (a fraction of a sample, so the interpolation's slope) by the chain
    rule, against forward differences of step 1e-6 of each scaled constant. A Bouc–Wen
    loop whose runs each start from unloaded seals has no state handed between runs,
    so it takes the tangent too, its shape constants included.

    Measured: within 1.3e-3 of each column's own size (the sensor's columns within
    1e-6), the breakaway force's, 1e-6 of the largest column, within 2.2e-2 of its own;
    the finite differences the refit took before, of step 3e-3, are 1e-3 to 7.5e-3 off."""
    model = average_model.with_parameters(**extra.get("params", {}))
    if "term" in extra:
        model = model.with_terms(extra["term"])
    runs = _runs(model)
    h = R.Hypothesis(model, sensor_gain=0.02, sensor_delay=0.0013,
                     fresh_states=extra.get("fresh", False))
    assert not R.carries_states(h)
    p = model.parameters()
    names = [n for n in p if n != "m" and p[n] != 0.0] + ["sensor_gain", "sensor_delay"]
    Jt = _jacobian(h, runs, names, True, R.FD_STEP)
    Jf = _jacobian(h, runs, names, False, 1e-6)
    size = np.linalg.norm(Jf, axis=0)
    error = np.linalg.norm(Jt - Jf, axis=0)
    for n, e, s in zip(names, error, size):
        assert e < 5e-3 * s + 1e-4 * size.max(), (n, e / s, s / size.max())


def test_a_hypothesis_that_carries_states_between_runs_keeps_finite_differences(
        average_model):
    """A thermal drift carries the fluid's temperature from run to run, which the tangent
    does not follow: its Jacobian stays the finite differences', bit for bit."""
    model = average_model.with_terms(Term("thermal_damper", "c_T", -2.0, (0.8, 600.0, 0.0)))
    runs = _runs(average_model)
    h = R.Hypothesis(model)
    assert R.carries_states(h) and not R.carries_states(R.Hypothesis(model, fresh_states=True))
    names = ["k1", "c1"]
    a = _jacobian(h, runs, names, True, R.FD_STEP)
    b = _jacobian(h, runs, names, False, R.FD_STEP)
    assert np.array_equal(a, b)
