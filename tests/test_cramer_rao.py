"""Cramér–Rao bounds: the errors-in-variables bound against the x-only bound."""

import numpy as np
import pytest

from analysis.identify.cramer_rao import cramer_rao, profile_parameters, with_parameters
from analysis.model.report_constants import report_model
from rig.profile import load_profile

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

NAMES = ("k1", "k2", "c1", "c2", "alpha", "beta")


def test_profile_parameters_round_trip():
    prof = load_profile("B")
    p = profile_parameters(prof)
    assert with_parameters(prof, p) == prof
    moved = with_parameters(prof, p + 1e-3)
    assert profile_parameters(moved) == pytest.approx(p + 1e-3)


@pytest.fixture(scope="module")
def bounds():
    model = report_model("A")
    return (cramer_rao(model, NAMES, profiles=("A",)),
            cramer_rao(model, NAMES, profiles=("A",), sigma_u=2.54e-9))


def test_unknown_input_costs_information(bounds):
    noisy, _ = bounds
    # the Schur complement removes information: never a tighter bound
    assert np.all(noisy.errors_in_variables >= noisy.x_only * (1 - 1e-9))
    # and on run A the table's timing matters for the stiffnesses: visibly looser
    assert noisy.errors_in_variables[0] > 1.1 * noisy.x_only[0]


def test_exact_table_sensor_recovers_x_only_bound(bounds):
    _, exact = bounds
    # σ_u 10⁴× smaller: the input is as good as known, the bounds meet
    assert exact.errors_in_variables == pytest.approx(exact.x_only, rel=1e-3)
