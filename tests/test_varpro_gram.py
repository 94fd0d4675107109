"""The variable-projection search's cached σ² is the appendix-A σ², to rounding."""

import numpy as np
import pytest

from analysis.identify.pipeline import LINEAR, _stack, start_model
from analysis.identify.prepare import prepare
from analysis.identify.synthetic import synthetic_runs
from analysis.identify.varpro import Gram, _cost
from analysis.model.report_constants import report_model

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)


@pytest.fixture(scope="module")
def data():
    runs = synthetic_runs(report_model("A"), profiles=("A", "C"), seed=3)
    return start_model(runs[0].mass), _stack([prepare(r) for r in runs])


@pytest.mark.parametrize("free", [LINEAR, ("k1", "c1", "c2")])
def test_cached_sigma2_equals_full_solve(data, free):
    model, d = data
    gram = Gram(model, d)
    p = model.parameters()
    rng = np.random.default_rng(0)
    compared = 0
    for _ in range(12):
        values = {"alpha": p["alpha"] * 10 ** rng.uniform(-0.3, 0.3),
                  "beta": p["beta"] * 10 ** rng.uniform(-0.3, 0.3),
                  "delta": p["delta"] * rng.uniform(0.5, 1.5)}
        full = _cost(model, d, free, values)[0]
        cached = gram.sigma2(free, values)
        if np.isfinite(full):
            compared += 1
            # the normal equations on unit columns lose ~κ² ε; 1e-9 leaves room for it
            assert cached == pytest.approx(full, rel=1e-9)
        else:  # a negative coefficient: refused by both
            assert cached == np.inf
    assert compared >= 6  # most points near the report's shapes are admissible


@pytest.mark.parametrize("free", [LINEAR, ("k1", "c1", "c2")])
def test_grid_sigma2_equals_one_by_one(data, free):
    """The grid's stacked solve gives each point's σ², and ∞ where one point gives ∞."""
    model, d = data
    p = model.parameters()
    points = [{"alpha": p["alpha"] * fa, "beta": p["beta"] * fb, "delta": p["delta"] * fd}
              for fa in (0.1, 0.5, 1.0, 4.0) for fb in (0.2, 1.0, 5.0) for fd in (0.0, 1.0, 3.0)]
    points.append({"alpha": p["alpha"], "beta": p["beta"], "delta": 1.0})  # springs never act
    many = Gram(model, d).sigma2_many(free, points)
    one = Gram(model, d)
    single = np.array([one.sigma2(free, v) for v in points])
    assert np.array_equal(np.isinf(many), np.isinf(single))
    assert np.isfinite(single).sum() >= 5 and np.isinf(single).sum() >= 1
    np.testing.assert_allclose(many[np.isfinite(single)], single[np.isfinite(single)],
                               rtol=1e-9)
