"""A mass pushed against the dead band's edge: the springs act only outside the band.

A constant force beyond breakaway drives the mass to the edge of the dead band,
where the gated springs switch on with a jump (k1 δ + k2 tanh(αδ) ≈ 2.3 kN) that
pushes it back in. Entering the band leaves z exactly on the edge, where the exit
event is not armed; the integrator must still notice the mass is inside again.
Before the fix it kept the springs on for the rest of the run, and a run
restarted from the same (z, ż) went elsewhere (105 × the sensor noise).
"""

import numpy as np
import pytest

from analysis.model.report_constants import report_model
from analysis.simulate import simulate
from rig.profile import load_profile
from sim.effects import parse_effect, with_effects
from sim.generate import PAUSE, campaign_profile

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

GATED = ("k1", "k2", "c2")


def _campaign():
    model = with_effects(report_model("average"), (parse_effect("force_offset=181"),))
    whole, spans = campaign_profile([load_profile(r) for r in "ABC"], PAUSE)
    return model, whole.motion(), spans, simulate(model, whole.motion(), dt=1e-3)


def test_gated_terms_are_off_inside_the_band():
    model, _, _, r = _campaign()
    # sliding along the edge chatters across it by far less than 1 µm: not "inside"
    inside = np.abs(r.z) < model.dead_band - 1e-6
    assert inside.sum() > 1000  # the campaign spends seconds in the band
    for name in GATED:
        assert np.all(r.forces[name][inside] == 0.0), name


def test_restart_from_the_state_continues_the_same_motion():
    model, motion, spans, r = _campaign()
    i0 = round(spans[1][0] / 1e-3)  # run B's start, after the mass sat at the edge
    restart = simulate(model, motion, dt=1e-3, t0=r.t[i0], duration=3.0, z0=r.z[i0],
                       zd0=r.zd[i0])
    n = restart.z.size
    # 25.4 µm is the sensor noise: the continuation must agree far below it
    assert np.max(np.abs(restart.z - r.z[i0:i0 + n])) < 2.5e-6
