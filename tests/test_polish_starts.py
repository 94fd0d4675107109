"""Three of the final fit's restarts (`polish.restarted`): a named dry friction exchanged
with Eq 10's c2 tanh(βż), every constant of Eq 10 from the prior where the fit holds
some of them, and the fit as it is with a held dead band or stop velocity freed. Each is
a start only: the refit from it is kept where it ends lower."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.loop.polish import _from_prior, _roles_exchanged, _stop_freed
from analysis.loop.refit import Fit, Hypothesis
from analysis.model.report_constants import report_model

EQ10 = ("k1", "k2", "c1", "c2", "alpha", "beta", "delta", "epsilon")


def _fit(h: Hypothesis, names: tuple[str, ...]) -> Fit:
    """A final fit of `h` freeing `names` (its statistics play no part in the starts)."""
    n = len(names)
    values = np.array([h.value(k) for k in names])
    return Fit(h, names, values, np.zeros(n), np.eye(n), (np.zeros(3),), np.zeros((3, n)),
               np.ones(n), 40)


def _swapped() -> Hypothesis:
    """Unseen Coulomb 105's valley: c2 sharp, the friction smooth, ε and δ moved."""
    return Hypothesis(report_model("average")).with_values(
        {"c2": 2799.0, "beta": 21143.0, "c3": 1285.0, "c3.v_s": 0.0347,
         "epsilon": 0.221, "delta": 0.0197})


def test_a_friction_and_c2_are_exchanged_size_for_size_and_build_up_for_build_up():
    prior = Hypothesis(report_model("average"))
    fit = _fit(_swapped(), (*EQ10, "c3", "c3.v_s"))
    (start, names, cands), = list(_roles_exchanged(fit, prior))
    p = start.model.parameters()
    assert (p["c2"], p["c3"]) == (1285.0, 2799.0)
    assert p["beta"] == pytest.approx(1.0 / 0.0347)
    # c2's 0.047 mm/s handed to the friction no sharper than a step the runs can tell
    assert p["c3.v_s"] == pytest.approx(1e-3)
    assert (p["delta"], p["epsilon"]) == (prior.value("delta"), prior.value("epsilon"))
    assert p["k1"] == fit.hypothesis.value("k1")  # the rest as the fit has them
    assert names == [] and cands == {}


def test_no_exchange_without_a_build_up_on_both_sides():
    prior = Hypothesis(report_model("average"))
    # the friction at the library's step: no build-up to hand c2
    step = _fit(_swapped().with_values({"c3.v_s": 0.0}), (*EQ10, "c3", "c3.v_s"))
    assert list(_roles_exchanged(step, prior)) == []
    # the build-up held: the exchange could not be refitted
    assert list(_roles_exchanged(_fit(_swapped(), (*EQ10, "c3")), prior)) == []
    # β held
    held = tuple(n for n in EQ10 if n != "beta") + ("c3", "c3.v_s")
    assert list(_roles_exchanged(_fit(_swapped(), held), prior)) == []


def test_constants_the_fit_holds_are_taken_from_the_prior_in_a_start_of_their_own():
    prior = Hypothesis(report_model("average"))
    absorbed = _swapped().with_values({"k2": 8423.0, "alpha": 9.6, "c3.v_s": 0.0057})
    held = tuple(n for n in EQ10 if n not in ("k2", "alpha")) + ("c3", "c3.v_s")
    starts = [s for s, _, _ in _from_prior(_fit(absorbed, held), prior)]
    last = starts[-1].model.parameters()
    for n in EQ10:
        assert last[n] == prior.value(n)
    assert (last["c3"], last["c3.v_s"]) == (1285.0, 0.0057)  # the effect as fitted
    # the other starts leave what the fit holds where it is
    assert all(s.model.parameters()["k2"] == 8423.0 for s in starts[:-1])
    # every constant free: no start of its own
    free = list(_from_prior(_fit(absorbed, (*EQ10, "c3", "c3.v_s")), prior))
    assert all(s.model.parameters()["k2"] == prior.value("k2") for s, _, _ in free)
    assert len(free) == len(starts) - 1


def test_a_held_dead_band_and_stop_velocity_are_freed_from_where_the_fit_stopped():
    # unseen 5542's final fit: both held at the prior's, the effects fitted beside them
    stopped = Hypothesis(report_model("average")).with_values({"c3": 2230.0})
    held = tuple(n for n in EQ10 if n not in ("delta", "epsilon")) + ("c3",)
    (start, names, cands), = list(_stop_freed(_fit(stopped, held)))
    assert start is stopped  # from where it stopped, nothing moved
    assert sorted(names) == ["delta", "epsilon"] and cands == {}
    # with both free there is no start
    assert list(_stop_freed(_fit(stopped, (*EQ10, "c3")))) == []
