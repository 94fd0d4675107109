"""The final fit's restarts free a named hysteresis's exponent (`polish._exponent_freed`).

The library names a Bouc–Wen loop at n = 1 or 2 and holds n while naming; a seal's
loop may lie between. The restarts free n with a and b, from the fit's n and from 1.5,
at the same yield displacement, so the loop's force at the yield does not jump.
"""

from __future__ import annotations

import pytest

from analysis.loop.candidates import CANDIDATES, shape_floor
from analysis.loop.polish import _exponent_freed
from analysis.loop.refit import Hypothesis
from analysis.model.isolator import Term
from analysis.model.report_constants import report_model


def _with_hysteresis(shape):
    c = CANDIDATES["hysteresis"]
    model = report_model("average").with_terms(Term(c.term_kind, c.parameter, 4e5, shape))
    return Hypothesis(model), {c.parameter: c.shaped(shape)}


def _yield(shape):
    a, b, n = shape
    return (a + b) ** (-1.0 / n)


def test_a_named_loops_exponent_is_freed_from_its_own_and_from_between_at_the_same_yield():
    shape = (0.75 / 2e-3**2, 0.25 / 2e-3**2, 2.0)  # a 2 mm yield, round corners
    h, cands = _with_hysteresis(shape)
    starts = list(_exponent_freed(h, cands))
    assert [s.model.term("k_h").shape[2] for s, _, _ in starts] == [2.0, 1.5]
    for start, names, cand in starts:
        assert names == ["k_h.a", "k_h.b", "k_h.n"]
        got = start.model.term("k_h").shape
        assert got == cand["k_h"].shape
        assert _yield(got) == pytest.approx(2e-3, rel=1e-12)
        assert got[0] / (got[0] + got[1]) == pytest.approx(0.75, rel=1e-12)  # loop's tilt kept
        assert start.model.term("k_h").coef == 4e5  # force at the yield: k times the yield


def test_no_start_repeats_the_fit_and_no_exponent_goes_below_one():
    h, cands = _with_hysteresis((300.0, 100.0, 1.5))
    assert [s.model.term("k_h").shape[2] for s, _, _ in _exponent_freed(h, cands)] == [1.5]
    assert shape_floor(h.model, "k_h.n") == 1.0
    # a model without hysteresis, or only a friction, gets none
    c = CANDIDATES["coulomb_friction"]
    assert list(_exponent_freed(Hypothesis(report_model("average")), {c.parameter: c})) == []
