"""The share of a candidate's force pattern the fitted terms cannot make follows the data."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.loop.conditioning import MIN_UNIQUE, collinearity
from analysis.model.isolator import Term
from analysis.model.report_constants import report_model

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

DT = 1e-3


def swings(amplitude: float) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """A decaying swing through the dead band and out to `amplitude` (m), and its rate."""
    t = np.arange(0.0, 3.0, DT)
    z = amplitude * np.exp(-0.8 * t) * np.sin(2 * np.pi * 1.5 * t)
    return [z], [np.gradient(z, DT)]


def with_preload(alpha: float):
    """Table 1's average model, which carries the report's preload γ at zero."""
    model = report_model("average").with_parameters(alpha=alpha)
    assert model.parameters()["gamma"] == 0.0
    return model


def test_a_preload_is_the_tanh_spring_when_tanh_saturates_at_the_dead_band_edge():
    model = with_preload(alpha=90.0)  # α δ ≈ 1.8: tanh(αz) ≈ sgn z over |z| > δ
    c = collinearity(model, "gamma", *swings(0.1), DT, "preload")
    assert c.unique_fraction < MIN_UNIQUE and c.indistinguishable
    assert c.like[0] == "k2"
    assert c.variance_inflation > 1 / MIN_UNIQUE


def test_a_preload_is_testable_where_the_tanh_spring_is_soft():
    model = with_preload(alpha=2.0)  # α δ ≈ 0.04: tanh(αz) is nearly linear in z
    c = collinearity(model, "gamma", *swings(0.1), DT, "preload")
    assert c.unique_fraction > 30 * MIN_UNIQUE and not c.indistinguishable  # measured 4.4 %


@pytest.mark.parametrize("amplitude", [0.05, 0.1])
def test_a_force_offset_is_nothing_the_odd_terms_can_make(amplitude):
    model = report_model("average").with_terms(Term("force_offset", "F0", 0.0))
    c = collinearity(model, "F0", *swings(amplitude), DT, "force_offset")
    # every term of Eq 10 is odd in (z, ż): a constant is almost all its own
    assert c.unique_fraction > 0.9
