"""The loop's work budget: counted in the simulator's RK4 steps, per thread, and once
spent the loop names no further effect, restarts nothing, and says so."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from analysis.loop import close_loop
from analysis.loop.budget import Budget, spent
from analysis.loop.refit import Hypothesis, predict
from analysis.model.report_constants import report_model
from tests.test_loop import campaign

pytestmark = [pytest.mark.numeric]


def test_a_prediction_spends_the_rk4_steps_its_rows_took():
    runs = [r.data for r in campaign()]
    h = Hypothesis(report_model("average"))
    k1 = h.model.parameters()["k1"]
    before = Budget.starting_now(10)
    predict(h, runs, ["k1"], np.array([[k1], [1.1 * k1], [0.9 * k1]]))
    # a step per sample of each row, and the trial steps that locate its events (the dead
    # band's edges, where the stop velocity is crossed): a few per cent more
    samples = 3 * sum(r.t.size - 1 for r in runs)
    assert samples <= before.used() <= 1.5 * samples
    assert before.exhausted()
    # another thread counts its own: units of a lot fitted side by side in threads
    other = []
    worker = threading.Thread(target=lambda: other.append(spent()))
    worker.start()
    worker.join()
    assert other == [0]
    assert spent() >= before.used()


@pytest.mark.slow
def test_past_its_budget_the_loop_names_one_effect_and_says_why_it_stopped():
    """The campaign of `test_two_effects_at_once_are_both_named`: with both effects named
    the loop ends at the noise; with no budget left after the first, the second is not
    tried, the final fit is not restarted, the residual stays well above the noise, and
    the description says the budget stopped it (not that nothing was left to find). Inside
    the first step too, the named effect is judged without the refits from the starting
    constants its refit above the noise would otherwise get."""
    messages: list[str] = []
    result = close_loop(report_model("average"),
                        campaign("coulomb_friction=167", "asymmetric_damping=560"),
                        progress=messages.append, budget=1)
    assert len(result.effects_added) == 1
    assert result.effects_added[0] in ("asymmetric_damping", "coulomb_friction")
    assert result.diagnosis_after.residual_over_noise > 1.3
    assert "work budget" in result.description
    assert "no further effect tried" in result.description
    assert any(m.startswith("loop: work budget spent") for m in messages)
    assert not any("starts near it" in m or "finer finite differences" in m for m in messages)
    assert "refits from the starting constants skipped" in result.description
    assert not any(m.endswith("from the starting constants") for m in messages)
