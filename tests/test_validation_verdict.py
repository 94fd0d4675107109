"""The held-out check's verdict (`analysis.loop.validation._verdict`): each run left out
one vote, so that one fold's refit ending in a valley of its own does not outweigh the
others, and a candidate that only fits noise is still refused."""

from __future__ import annotations

from analysis.loop.validation import _verdict

N = 4500  # samples of a run: the sums of squares are in noise units


def _ss(rms_over_noise: list[float]) -> list[float]:
    return [N * r * r for r in rms_over_noise]


def test_one_fold_in_a_valley_of_its_own_does_not_outweigh_the_others():
    # unseen Coulomb 101 with numpy's baseline kernels: A and B left out predicted at
    # the noise with the friction, C's fold refit in another valley
    base, cand = _ss([7.50, 4.82, 9.85]), _ss([1.22, 1.21, 14.80])
    assert sum(cand) > sum(base)  # the plain sum would refuse it
    accepted, better = _verdict(base, cand)
    assert accepted and better == 2


def test_a_candidate_that_fits_the_noise_is_refused():
    # every run 0.4 % better held out: under the 1 % the verdict asks
    base = _ss([1.01, 1.02, 0.99])
    cand = [s * 0.996 for s in base]
    assert _verdict(base, cand) == (False, 3)


def test_one_run_much_better_is_not_enough():
    base, cand = _ss([5.0, 1.0, 1.0]), _ss([1.0, 1.05, 1.05])
    accepted, better = _verdict(base, cand)
    assert not accepted and better == 1


def test_a_run_predicted_exactly_stays_comparable():
    # a run both models predict to the last bit (a zero sum) votes neither way
    assert _verdict([0.0, 4.0 * N, 9.0 * N], [0.0, N, N]) == (True, 2)
    assert _verdict([0.0, N, N], [0.0, 4.0 * N, 9.0 * N]) == (False, 0)
