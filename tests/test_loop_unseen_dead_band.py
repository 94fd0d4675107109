"""The dead band found where the fit had lost it, on unseen campaigns through the
command a user runs.

A base fit can close the dead band and let c2 tanh(βż), steep in β, carry a dry friction
of the seals; the friction's refit from there goes to nothing. Where the fit's dead band
is closed, the candidate is also started from the prior's α, β, δ and ε with appendix
A's coefficients at them (`candidate_fit._reopened`). A mass a force offset holds on the
dead band's edge rests there: the final fit is also restarted with the edge at the
runs' common rest position (`polish._dead_band_at_rest`). The campaigns and the CLI
call are `test_loop_unseen`'s (`bench/unseen/generator.py`, which shares nothing with
the analysis; only A.csv, B.csv and C.csv reach `analysis fit`).
"""

from __future__ import annotations

import pytest

from tests.test_loop_unseen import _fit
from tests.test_unseen_generator import gen

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)


def test_a_friction_behind_a_closed_dead_band_is_named_with_the_band_reopened(tmp_path):
    """Seed 5541: a one-sided damping (3.74 kN s/m in extension) and a Coulomb friction
    (4.62 kN built up over 5 mm/s), each 29 % of the peak force. The base fit closed the
    dead band (0.1 mm against 22.3) and ended at 97 x noise; with the damping named, the
    friction refitted from the fit's constants went to nothing and the loop stopped at
    11.5 x, "unexplained". From the prior's α, β, δ and ε it reaches 1.00 x."""
    effects = ("asym_damping", "coulomb")
    doc = _fit(5541, effects, tmp_path)
    assert doc["effects_added"] == ["asymmetric_damping", "coulomb_friction"]
    assert doc["residual_after"]["residual_over_noise"] < 1.3  # measured 1.00
    assert doc["unexplained"]["value"] is False
    campaign = gen.make_campaign(5541, effects)
    truth = {e["name"]: e for e in campaign.effects}
    p = doc["parameters"]
    # both effects are the library's shapes and only noise stands between them and the
    # generator's: measured 4623 N against 4620, 3745 N s/m against 3745, a build-up of
    # 4.99 mm/s against 4.99 and the dead band 22.33 mm against 22.31
    assert p["c3"]["value"] == pytest.approx(truth["coulomb"]["F_c"], rel=0.05)
    assert p["c_ext"]["value"] == pytest.approx(truth["asym_damping"]["c_a"], rel=0.05)
    assert p["c3.v_s"]["value"] == pytest.approx(truth["coulomb"]["v_s"], rel=0.2)
    assert p["delta"]["value"] == pytest.approx(campaign.constants["delta"], rel=0.05)


def test_a_force_offset_holding_the_mass_on_the_edge_gives_the_dead_band(tmp_path):
    """Seed 1128: a force offset of −737 N (4.8 % of the peak force) against a 75 N
    breakaway pushes the mass out against the dead band's edge, where the springs' jump
    holds it: every run starts at rest 21.556–21.570 mm off centre, the generator's
    dead band 21.557 mm. The offset was named, and the final fit and its restarts
    stopped at 3.55 x noise with the dead band at 21.29 mm: the cost over δ steps at
    every rest position the mode changes at, and no start crossed them. From the rest
    position, 1.01 x."""
    effects = ("force_offset",)
    doc = _fit(1128, effects, tmp_path)
    assert doc["effects_added"] == ["force_offset"]
    assert doc["residual_after"]["residual_over_noise"] < 1.3  # measured 1.01
    assert doc["unexplained"]["value"] is False
    campaign = gen.make_campaign(1128, effects)
    p = doc["parameters"]
    # the edge is read from 50 samples at rest per run (7 µm each at this noise):
    # measured 21.555 mm against 21.557, the offset −736.6 N against −736.6
    assert p["delta"]["value"] == pytest.approx(campaign.constants["delta"], abs=30e-6)
    assert p["F0"]["value"] == pytest.approx(campaign.effects[0]["F0"], rel=0.02)
