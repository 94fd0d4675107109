"""A second effect the loop names after the first, on unseen campaigns, through the
command a user runs.

Past the first effect, equation error often names nothing: the second effect is small,
slow, or the noise differentiated twice hides it. Where the residual is still well
above the noise, equation error's two best columns are refitted all the same, and kept
only where the refit takes the residual to where nothing is left to call unexplained
(`close._one_step`). The campaigns and the CLI call are `test_loop_unseen`'s
(`bench/unseen/generator.py`, which shares nothing with the analysis; only A.csv, B.csv
and C.csv reach `analysis fit`).
"""

from __future__ import annotations

import pytest

from tests.test_loop_unseen import _fit
from tests.test_unseen_generator import gen

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)


def test_a_slow_drift_left_after_a_one_sided_stiffness_is_named_second(tmp_path):
    """Seed 5341: a one-sided stiffness (5.23 kN/m in compression) with a thermal drift of
    the damping (cooling in 0.81 s), each 4.4 % of the peak force, at 2.7 x the rig's
    noise. Equation error names the stiffness; with it kept, 6.85 x noise is left and the
    drift's column lowers BIC by 1.6, under the margin of 10: the loop stopped there.
    Refitted as equation error's best, the drift takes it to 1.06 x."""
    effects = ("asym_stiffness", "thermal")
    doc = _fit(5341, effects, tmp_path)
    assert doc["effects_added"] == ["asymmetric_stiffness", "thermal_damping_drift"]
    assert doc["residual_after"]["residual_over_noise"] < 1.3  # measured 1.06
    assert doc["unexplained"]["value"] is False
    truth = {e["name"]: e for e in gen.make_campaign(5341, effects).effects}
    p = doc["parameters"]
    # measured 5254 N/m against 5233, and a cooling time of 0.830 s against 0.813: both
    # effects are the generator's shapes, and only noise stands between them
    assert p["k_comp"]["value"] == pytest.approx(truth["asym_stiffness"]["k_a"], rel=0.05)
    assert p["c_T.tau"]["value"] == pytest.approx(truth["thermal"]["tau_T"], rel=0.1)


def test_a_cubic_equation_error_ranks_best_below_every_margin_is_named_second(tmp_path):
    """Seed 5042: a Coulomb friction (557 N, built up over 8 mm/s) with a hardening spring,
    each 3.5 % of the peak force, at 2.3 x the rig's noise. The friction is named and
    leaves 2.09 x noise; no column then lowers BIC at all (the cubic's rises by 3.6, the
    least of all). Refitted in that order, the cubic reaches 1.04 x; a one-sided damping,
    which output error's score ranks first, stops at 1.45 x and is not the effect."""
    effects = ("coulomb", "hardening")
    doc = _fit(5042, effects, tmp_path)
    assert doc["effects_added"] == ["coulomb_friction", "cubic_stiffness"]
    assert doc["residual_after"]["residual_over_noise"] < 1.3  # measured 1.04
    truth = {e["name"]: e for e in gen.make_campaign(5042, effects).effects}
    p = doc["parameters"]
    assert p["c3"]["value"] == pytest.approx(truth["coulomb"]["F_c"], rel=0.15)  # 576 vs 557 N
    # 3.50e5 N/m³ against 4.20e5: at 3.5 % of the peak, the cubic shares the stiffening
    # with k2 tanh(αz), which the refit makes a step at the dead band's edge
    assert p["k3"]["value"] == pytest.approx(truth["hardening"]["k3"], rel=0.3)
