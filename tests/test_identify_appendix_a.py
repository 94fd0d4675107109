"""Appendix A's least squares (Eq A8–A15) on a case small enough to check by hand."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.identify.equation_error import fit_coefficients, solve
from analysis.model.report_constants import report_model

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)


def test_small_case_by_hand() -> None:
    # Z = [[1,0],[0,1],[1,1]], y = [1,2,4]: A = ZᵀZ = [[2,1],[1,2]], b = Zᵀy = [5,6],
    # A k = −b → k = −(1/3)[[2,−1],[−1,2]]·[5,6] = [−4/3, −7/3];
    # ε = y + Z k = [−1/3, −1/3, 1/3], σ² = εᵀε/(I − J) = (1/3)/1,
    # V = σ² A⁻¹ = [[2/9, −1/9], [−1/9, 2/9]], correlation −1/2, cond(A) = 3/1.
    Z = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    fit = solve(Z, np.array([1.0, 2.0, 4.0]), ("k1", "k2"))
    np.testing.assert_allclose(fit.A, [[2, 1], [1, 2]], atol=1e-15)
    np.testing.assert_allclose(fit.b, [5, 6], atol=1e-15)
    np.testing.assert_allclose(fit.values, [-4 / 3, -7 / 3], rtol=1e-14)
    np.testing.assert_allclose(fit.residual, [-1 / 3, -1 / 3, 1 / 3], atol=1e-14)
    assert fit.sigma2 == pytest.approx(1 / 3, rel=1e-14)
    np.testing.assert_allclose(fit.covariance, [[2 / 9, -1 / 9], [-1 / 9, 2 / 9]], rtol=1e-13)
    assert fit.correlation[0, 1] == pytest.approx(-0.5, rel=1e-13)
    assert fit.condition == pytest.approx(3.0, rel=1e-13)
    assert fit.as_dict() == {"k1": fit.values[0], "k2": fit.values[1]}


def test_too_few_samples_is_refused() -> None:
    with pytest.raises(ValueError, match="2 samples cannot determine 2"):
        solve(np.eye(2), np.ones(2), ("a", "b"))


def test_noise_free_eq10_is_recovered_exactly() -> None:
    """With exact z, ż, ẍ the four coefficients come back to rounding, σ² ≈ 0."""
    model = report_model("A")
    rng = np.random.default_rng(0)
    z, zd = rng.uniform(-0.15, 0.15, 500), rng.uniform(-1.5, 1.5, 500)
    from analysis.identify.regressors import regressor_matrix

    force = regressor_matrix(model, z, zd) @ np.array([t.coef for t in model.terms])
    fit = fit_coefficients(model, z, zd, -force / model.mass, free=("k1", "k2", "c1", "c2"))
    for n, v in fit.as_dict().items():
        assert v == pytest.approx(model.parameters()[n], rel=1e-9)
    assert fit.sigma2 < 1e-12 * np.mean(force**2)


def test_fixed_terms_move_to_the_known_side() -> None:
    model = report_model("A")
    rng = np.random.default_rng(1)
    z, zd = rng.uniform(-0.15, 0.15, 300), rng.uniform(-1.5, 1.5, 300)
    from analysis.identify.regressors import regressor_matrix

    force = regressor_matrix(model, z, zd) @ np.array([t.coef for t in model.terms])
    fit = fit_coefficients(model, z, zd, -force / model.mass, free=("c2", "k1"))
    assert fit.names == ("c2", "k1")
    np.testing.assert_allclose(fit.values, [model.parameters()["c2"], model.parameters()["k1"]],
                               rtol=1e-9)
