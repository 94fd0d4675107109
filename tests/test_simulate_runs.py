"""Several runs in one parallel call give each run's own simulation, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.model.report_constants import report_model
from analysis.simulate import RunSetup, motion_from_samples, simulate, simulate_runs
from rig.profile import load_profile

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)


def test_runs_of_different_motions_lengths_and_starts_match_one_by_one():
    model = report_model("A")
    ramp = load_profile("A").motion()  # quintic step-pulse, few breaks
    t = np.arange(0.0, 1.5, 1e-3)
    sampled = motion_from_samples(t, 0.02 * np.sin(2 * np.pi * 1.5 * t) ** 3)  # cubic, many
    setups = [RunSetup(ramp, 2.0, 1e-3, 0.0, 0.004, 0.0),
              RunSetup(sampled, 1.2, 2e-3, 0.1, -0.002, 0.01),
              RunSetup(load_profile("C").motion(), 3.0)]
    stiff = model.vector().copy()
    stiff[model.vector_index()["k1"]] *= 1.3
    vectors = [np.vstack([model.vector(), stiff]), model.vector()[None, :],
               np.vstack([stiff, model.vector(), stiff])]
    batches = simulate_runs(model, setups, vectors)
    assert [b.z.shape for b in batches] == [(2, 2001), (1, 601), (3, 3001)]
    for s, rows, b in zip(setups, vectors, batches):
        for row, z, xdd in zip(rows, b.z, b.xdd):
            one = simulate(_with_row(model, row), s.motion, duration=s.duration, dt=s.dt,
                           t0=s.t0, z0=s.z0, zd0=s.zd0)
            np.testing.assert_array_equal(z, one.z)
            np.testing.assert_array_equal(xdd, one.xdd)
            np.testing.assert_array_equal(b.u, one.u)


def _with_row(model, row):
    """The model whose kernel vector is `row` (only k1 differs here)."""
    moved = model.with_parameters(k1=float(row[model.vector_index()["k1"]]))
    assert np.array_equal(moved.vector(), row)
    return moved


def test_the_table_motion_on_a_grid_is_shared_read_only_and_its_own_per_grid():
    """Every batch of a run shares one u (a fit simulates a run thousands of times):
    read-only, so no caller can change another's, and another grid of the same motion
    gets its own."""
    model = report_model("A")
    motion = load_profile("A").motion()
    first, again, finer = (simulate_runs(model, [RunSetup(motion, 1.0, dt, 0.0)],
                                         [model.vector()[None, :]])[0]
                           for dt in (1e-3, 1e-3, 5e-4))
    assert again.u is first.u and not first.u.flags.writeable
    with pytest.raises(ValueError):
        first.u[0] = 1.0
    assert finer.u.size == 2001 and first.u.size == 1001
    np.testing.assert_array_equal(finer.u[::2], first.u)
    np.testing.assert_array_equal(first.u, motion(first.t))
