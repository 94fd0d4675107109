"""Forward sensitivities of the simulated motion (`simulate.tangent`) against the
finite-difference slopes they converge to (tests/test_simulate_nonsmooth.py)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from analysis.simulate import simulate, tangent
from analysis.simulate.tangent import motion_sensitivity
from rig.profile import load_profile
from tests.test_simulate_nonsmooth import motion_slopes

# numeric; and the first test compiles the tangent integrator (~1 min alone, longer beside
# another worker) where the cache is cold
pytestmark = [pytest.mark.numeric, pytest.mark.timeout(900)]


@pytest.mark.parametrize("run", ["A", "C"])
@pytest.mark.parametrize("extra", [{}, {"c3": 300.0, "gamma": 200.0}],
                         ids=["eq10", "step_friction_and_preload"])
def test_the_tangent_gives_the_converged_slopes_of_every_constant(average_model, run, extra):
    """Every constant's slope d z / d ln p from one integration with the tangent, against
    forward differences of relative step 1e-6 (converged: 1e-5 gives the same within
    7e-4, test_the_motion_is_a_smooth_function_of_every_constant).

    Measured: within 2.8e-3 of each column's own size for every constant whose column
    is at least 1e-4 of the largest (k1's); the breakaway force's and, on these runs, the
    stop velocity's columns are ~1e-6 and ~2e-5 of k1's, and there the finite differences
    see RK4's split steps (module docstring), so those are held to 1e-4 of k1's column,
    which no fit resolves. The motion itself is the kernel's, bit for bit."""
    model = average_model.with_parameters(**extra)
    p = model.parameters()
    names = [n for n in p if n != "m" and p[n] != 0.0]
    motion = load_profile(run).motion()
    z, dz = motion_sensitivity(model, motion, names)
    assert np.array_equal(z, simulate(model, motion).z)
    fine = motion_slopes(model, motion, names, 1e-6)
    slopes = dz * np.array([p[n] for n in names])[:, None]
    size = np.linalg.norm(fine, axis=1)
    error = np.linalg.norm(slopes - fine, axis=1)
    for n, e, s in zip(names, error, size):
        assert e < 5e-3 * s + 1e-4 * size.max(), (n, e / s, s / size.max())


def test_the_tangents_cache_follows_the_kernel():
    """numba caches tangent.py's code against that file alone, and the kernel's and the
    terms' functions are compiled into it: their sources' hash is written in tangent.py,
    so an edit there must change tangent.py too (update KERNEL_SOURCES)."""
    root = Path(tangent.__file__).parents[1]
    src = b"".join((root / f).read_bytes() for f in ("simulate/kernel.py", "model/terms.py"))
    assert tangent.KERNEL_SOURCES == hashlib.sha1(src).hexdigest()[:16]
