"""The simulator against the exact response of a linear isolator to a ramp-step.

For k2 = c2 = 0, no dead band and no friction, Eq 10 is the damped oscillator
m z̈ + c ż + k z = −m ü. The table motion is piecewise polynomial, so the
system augmented with the polynomial's generator (1, τ, τ², τ³) is linear and
time-invariant on each piece and its matrix exponential is the exact solution.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import PPoly
from scipy.linalg import expm

from analysis.model.isolator import IsolatorModel, Term
from analysis.simulate import simulate
from rig.profile import Profile, Segment

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)


def exact_linear_response(m: float, k: float, c: float, motion: PPoly, t: np.ndarray):
    """z(t), ż(t) of m z̈ + c ż + k z = −m ü, starting at rest; exact on each piece."""
    acc = motion.derivative(2)  # ü as a piecewise cubic: coefficients acc.c (4, K)
    times = np.union1d(t, motion.x)
    state = np.zeros(2)
    out = {}
    for t_a, t_b in zip(times[:-1], times[1:]):
        i = min(np.searchsorted(motion.x, t_a, side="right") - 1, len(motion.x) - 2)
        tau0 = t_a - motion.x[i]
        a_poly = acc.c[::-1, i]  # ü(τ) = Σ a_j τ^j, j = 0..3
        A = np.zeros((6, 6))
        A[0, 1] = 1.0
        A[1, 0], A[1, 1] = -k / m, -c / m
        A[1, 2:6] = -a_poly
        for j in range(1, 4):  # d/dτ τ^j = j τ^(j−1)
            A[2 + j, 2 + j - 1] = j
        w = np.concatenate([state, [1.0, tau0, tau0**2, tau0**3]])
        state = (expm(A * (t_b - t_a)) @ w)[:2]
        out[t_b] = state
    out[times[0]] = np.zeros(2)
    zz = np.array([out[ti] for ti in t])
    return zz[:, 0], zz[:, 1]


@pytest.mark.parametrize("rise", [0.20, 0.12])
def test_linear_case_matches_exact_solution(rise):
    m, k, c = 2721.55, 70926.0, 6024.0  # the report's mass, k1 and c1 (ζ ≈ 0.22)
    model = IsolatorModel(mass=m, terms=(Term("linear_spring", "k1", k),
                                         Term("linear_damper", "c1", c)))
    profile = Profile("ramp-step", (Segment(0.1), Segment(rise, 0.1397), Segment(2.0),
                                    Segment(0.12, 0.0), Segment(0.6)))
    r = simulate(model, profile.motion(), dt=1e-3, substeps=4)
    z_ref, zd_ref = exact_linear_response(m, k, c, profile.motion(), r.t)
    peak = np.abs(z_ref).max()
    assert peak > 0.05  # a real response, not a trivially small one
    assert np.abs(r.z - z_ref).max() < 1e-6 * peak
    assert np.abs(r.zd - zd_ref).max() < 1e-6 * np.abs(zd_ref).max()
    # m ẍ = −(k z + c ż) holds sample by sample
    np.testing.assert_allclose(m * r.xdd, -(k * r.z + c * r.zd), atol=1e-9 * m * 9.81)
