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
from analysis.table_motion import quintic_hermite
from rig.config import load_config
from rig.geometry import x_components
from rig.profile import load_profile
from sim.plant import Plant

RATE = 400.0  # Hz, the setpoints (data/rig.toml)
START = 0.3037  # s: START arrives between grid points, as it does on the rig
CONFIG = load_config()
MODEL = report_model("average")


def played(profile: str):
    """An actuator controller's target: the setpoints interpolated linearly (sim.devices)."""
    prof = load_profile(profile)
    sp = prof.sample(np.arange(0.0, prof.duration + 1e-9, 1.0 / RATE))[0]
    nx = x_components(CONFIG)

    def targets(t: float) -> np.ndarray:
        i = min(max((t - START) * RATE, 0.0), sp.size - 1.0)
        k = min(int(i), sp.size - 2)
        return nx * (sp[k] + (i - k) * (sp[k + 1] - sp[k]))

    return prof.duration + START + 0.4, targets


def run_plant(profile: str, dt: float = 1e-3, chunk: int = 20):
    duration, targets = played(profile)
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
    assert rms < 5e-6  # m (measured 2.5 µm; was 12 mm), a fifth of the sensor noise
    assert np.abs(x - long_chunks).max() < 1e-9  # was 23 mm RMS apart


def test_the_analysis_simulator_driven_by_the_plants_table_reproduces_its_x(plant_a):
    """The sim and the analysis agree about the model when given the same table motion."""
    plant, grid, x = plant_a
    h = plant.history()
    n = h["t"].size
    motion = quintic_hermite(h["t"], h["u"], np.array(plant._ud[:n]), np.array(plant._udd[:n]))
    r = simulate(MODEL, motion, duration=grid[-1], dt=1e-3, t0=0.0)
    assert np.sqrt(np.mean((r.x[:grid.size] - x) ** 2)) < 1e-5  # m (measured ~6 µm)
