"""sim.plant serves the solution of its own physics: x converged in the step, whatever the chunk.

The servo lag's acceleration jumps wherever the interpolated target's slope
changes, and the integrator's last RK4 stage reads ü at the step's end. With a
cubic Hermite table motion (ü jumping at every grid point) and chunk ends held
(ü = 0), each stage was wrong by a jump of the same sign along a ramp: run A's
served x was 1.6 mm off the converged solution at the end of its first ramp and
tens of mm after the return, and changed with the chunk length.
"""

from __future__ import annotations

import numpy as np
import pytest

from analysis.model.report_constants import report_model
from analysis.simulate import simulate
from analysis.simulate.motion import quintic_hermite
from rig.config import load_config
from rig.geometry import x_components
from rig.profile import load_profile
from sim.devices import interpolate_setpoints
from sim.plant import Plant

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

RATE = 400.0  # Hz, the setpoints (data/rig.toml)
START = 0.3037  # s: START arrives between grid points, as it does on the rig
CONFIG = load_config()
MODEL = report_model("average")


def played(profile: str, exact: bool = False):
    """An actuator controller's target: its interpolation of the 400 Hz setpoints
    (sim.devices); `exact`: the profile's own ramps instead, at any instant."""
    prof = load_profile(profile)
    sp = prof.sample(np.arange(0.0, prof.duration + 1e-9, 1.0 / RATE))[0]
    samples = dict(enumerate(sp.tolist()))
    nx = x_components(CONFIG)

    def targets(t: float) -> np.ndarray:
        if exact:
            return nx * float(prof.sample(np.array([min(max(t - START, 0.0),
                                                        prof.duration)]))[0][0])
        i = min(max((t - START) * RATE, 0.0), sp.size - 1.0)
        return nx * interpolate_setpoints(samples, min(i, sp.size - 1.0 - 1e-12), 1.0 / RATE)

    return prof.duration + START + 0.4, targets


def run_plant(profile: str, dt: float = 1e-3, chunk: int = 20, exact: bool = False):
    duration, targets = played(profile, exact)
    plant = Plant(MODEL, targets, x_components(CONFIG),
                  np.array([a.max_velocity for a in CONFIG.table.actuators]), 0.0,
                  dt=dt, chunk=chunk)
    plant.advance_to(duration)
    grid = 1e-3 * np.arange(int(duration / 1e-3))
    return plant, grid, np.array([plant.at(t)[1] for t in grid])


@pytest.fixture(scope="module")
def plant_a():
    return run_plant("A")


def test_the_served_x_is_converged_and_independent_of_the_chunk(plant_a):
    _, _, x = plant_a
    _, _, fine = run_plant("A", dt=1e-4, chunk=200)  # the reference: 10× finer steps
    _, _, long_chunks = run_plant("A", chunk=1000)
    rms = np.sqrt(np.mean((x - fine) ** 2))
    assert rms < 1e-6  # m (measured 0.39 µm; was 12 mm), a 25th of the sensor noise
    assert np.abs(x - long_chunks).max() < 1e-9  # was 23 mm RMS apart


def test_the_analysis_simulator_driven_by_the_plants_table_reproduces_its_x(plant_a):
    """The sim and the analysis agree about the model when given the same table motion."""
    plant, grid, x = plant_a
    h = plant.history()
    n = h["t"].size
    motion = quintic_hermite(h["t"], h["u"], np.array(plant._ud[:n]), np.array(plant._udd[:n]))
    r = simulate(MODEL, motion, duration=grid[-1], dt=1e-3, t0=0.0)
    assert np.sqrt(np.mean((r.x[:grid.size] - x) ** 2)) < 1e-5  # m (measured ~6 µm)


def test_the_rig_serves_its_constants_response_to_the_profile_within_half_a_micron(plant_a):
    """Setpoints at 400 Hz, interpolated by the controller, through the servo lag: the
    mass's x is the response to the profile's own ramps (10× finer steps) to < 0.5 µm.

    Static friction makes this strict: the mass breaks away where m·ü crosses the
    breakaway force (0.03 m/s² here), so an acceleration ripple that no displacement
    record shows moved x by 5 µm RMS with straight lines between setpoints.
    """
    _, _, x = plant_a
    _, _, exact = run_plant("A", dt=1e-4, chunk=200, exact=True)
    assert np.sqrt(np.mean((x - exact) ** 2)) < 0.5e-6  # m (measured 0.29 µm; linear 5 µm)


def test_the_setpoint_interpolation_is_exact_for_a_quartic_and_c2_across_samples():
    h = 1.0 / RATE
    poly = np.polynomial.Polynomial([0.01, -0.2, 3.0, 40.0, -500.0])  # m, t in s
    samples = {j: float(poly(j * h)) for j in range(12)}
    for i in (4.0, 4.3, 5.5, 6.99):
        assert interpolate_setpoints(samples, i, h) == pytest.approx(poly(i * h), abs=1e-12)
    # across the knot at sample 6: the second difference of the target at steps of ε
    eps = 1e-4
    acc = [(interpolate_setpoints(samples, i + eps, h) - 2 * interpolate_setpoints(samples, i, h)
            + interpolate_setpoints(samples, i - eps, h)) / (eps * h) ** 2
           for i in (6.0 - 2 * eps, 6.0 + 2 * eps)]
    assert acc[0] == pytest.approx(acc[1], rel=1e-3)
    # the stream's first sample is a knot at rest, as the table is before the profile
    ramp = {j: 0.001 * j for j in range(6)}
    assert interpolate_setpoints(ramp, 0.5, h) < 0.0005
    assert interpolate_setpoints(ramp, 2.5, h) == pytest.approx(0.0025, abs=1e-15)
