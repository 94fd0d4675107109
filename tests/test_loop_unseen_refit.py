"""The loop's refits on unseen campaigns, through the command a user runs: shape
constants the data choose (a drift's cooling time and floor, a friction's build-up
velocity), valleys the base fit leaves behind, and intervals that stay finite.

The campaigns and the CLI call are `test_loop_unseen`'s (`bench/unseen/generator.py`,
which shares nothing with the analysis; only A.csv, B.csv and C.csv reach
`analysis fit`): split from it so that pytest-xdist, which hands a file to one
worker, runs the two side by side.
"""

from __future__ import annotations

import pytest

from tests.test_loop_unseen import _fit
from tests.test_unseen_generator import gen

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)


@pytest.mark.parametrize("seed", [705, 704])
def test_a_thermal_drift_down_to_a_floor_is_named_with_its_cooling_time_and_limit(seed,
                                                                                   tmp_path):
    """Seed 705: the generator's damping falls as c1 (1 − κT) down to a floor of 5 % of
    c1, its fluid heated by c1 ż²/C and cooled in 4.7 s: a dominant drift (29 % of the
    peak force) that reaches the floor within a run. Without a limit the library's
    drift runs the mass away where the damping would cross zero, and the loop ended at
    58 x noise. With θ_max placed by the data and refitted, the heat capacity the
    library cannot see (its heating is held) leaves the cooling time and the damping
    lost at the floor to compare with the generator's.

    Seed 704: a drift of the same size that cools in 2.7 s, each run starting cool.
    Identification bends Eq 10 around it (α 356 1/m against 75, c1 1.78 kN s/m against
    6.73), and the drift refitted from there and from the base refit's constants stayed
    in a valley with the stop velocity at 0.15 m/s: 23.5 x noise. Refitted also from
    the report's average constants, which never saw the runs (`close_identified`), with
    each run started cool, it reaches the noise: 1.02 x, 2.697 s against 2.696."""
    doc = _fit(seed, ("thermal",), tmp_path)
    assert doc["effects_added"] == ["thermal_damping_drift"]
    assert doc["residual_after"]["residual_over_noise"] < 1.3  # measured 1.01, 1.02
    assert doc["unexplained"]["value"] is False
    truth = gen.make_campaign(seed, ("thermal",))
    e, c1 = truth.effects[0], truth.constants["c1"]
    p = doc["parameters"]
    assert p["c_T.tau"]["value"] == pytest.approx(e["tau_T"], rel=0.05)  # 4.699 s vs 4.702
    # at the floor the damping has lost 95 % of c1: c_T θ_max = −0.95 c1 (705: −6291 N s/m
    # both; 704: −6394 both)
    lost = p["c_T"]["value"] * p["c_T.theta_max"]["value"]
    assert lost == pytest.approx(-0.95 * c1, rel=0.05)


# the longest campaign of the suite: 190-215 s alone on this 2-core machine, more beside
# another worker; the limit is against a hang, not a measure of speed (bench/)
@pytest.mark.timeout(600)
def test_a_drift_the_base_fit_absorbed_is_named_on_every_kernel(tmp_path):
    """Seed 702: a drift cooling in 4.1 s, 4.5 % of the peak force, whose runs never heat
    the fluid to the generator's floor. The base fit bends Eq 10 round it (α 356 1/m
    against 81; 330 x noise). Identified again by equation error with the drift's
    column, each run from a cool fluid, α, β and δ searched, the drift is named under
    every BLAS kernel; the output-error refit from there still ends in a valley the
    kernel chooses: 1.05 x noise under Haswell, 1.18 x under SkylakeX, 45 x under
    Sandybridge. Only the name and a residual cut to under half are kernel-proof, and
    only they are checked."""
    doc = _fit(702, ("thermal",), tmp_path)
    assert doc["effects_added"] == ["thermal_damping_drift"]
    before = doc["residual_before"]["residual_over_noise"]
    assert doc["residual_after"]["residual_over_noise"] < 0.5 * before  # 1.33 / 10.5 / 138 of 330


def test_a_lagged_servo_leaves_every_interval_finite(tmp_path):
    """Seed 1205's servo lag is fitted with a 0.7 ms ramp at a corner, shorter than a
    sample: no sample of u sees its duration, and propagating its undetermined variance
    would put ±2e6 lb/in on k1. Every constant the fit estimates now comes with an interval
    within ±20 % (the noise alone puts them within ±1 % on three runs)."""
    doc = _fit(1205, ("servo_lag",), tmp_path)
    assert doc["effects_added"] == []  # a table that lags is the input's, not the isolator's
    # the identification's intervals (the table `analysis fit` prints first)
    estimated = {n: p for n, p in doc["parameters_base_model"].items()
                 if p.get("std") is not None}
    assert {"k1", "k2", "c1", "c2"} <= set(estimated)
    for name, p in estimated.items():
        lo, hi = p["ci95"]
        assert hi - lo < 0.4 * abs(p["value"]), (name, p)


def test_a_slow_force_equation_error_barely_sees_is_tried_where_the_residual_is_high(
        tmp_path):
    """Seed 404: a one-sided stiffness of 3.3 % of the peak force (k_a = 4.21 kN/m for
    z > 0). Its force is slow (96 % of the residual power below 2 Hz), where equation
    error's twice-differentiated x hides it: a BIC fall of 4.5 on 339 rows, under the
    margin of 10, while output error leaves 11.0 x the noise. With the residual that far
    above the noise, equation error's best column is tried all the same, and the judge's
    checks (held-out runs included) keep it."""
    doc = _fit(404, ("asym_stiffness",), tmp_path)
    assert doc["effects_added"] == ["asymmetric_stiffness"]
    assert doc["residual_after"]["residual_over_noise"] < 1.5  # measured 1.34, from 11.0
    truth = gen.make_campaign(404, ("asym_stiffness",)).effects[0]
    # measured 4157 N/m against 4212: the rest of the model's valley (δ, α) moves it little
    assert doc["parameters"]["k_comp"]["value"] == pytest.approx(truth["k_a"], rel=0.1)


def test_a_friction_built_up_over_its_own_velocity_is_refitted_with_it(tmp_path):
    """Seed 101: a dry friction of 4.08 kN (27 % of the peak force) that the generator
    builds up as F tanh(ż/v_s) over v_s = 6.2 mm/s. Equation error names it at the
    library's step: beside the base fit's c2 tanh(βż), itself a friction built up over
    1/β outside the dead band, the step's column is the one that differs. Refitted as a
    step it stopped at 5.40 x noise; started at the library's other shapes with v_s
    free, it ends near the noise with the generator's size and build-up velocity (the
    generator's constants in the library's terms fit at 1.01 x; the rest is the base
    fit's valley of α and δ). Its held-out check is the one where a single fold's refit
    ended in a valley of its own (run C 9.85 -> 14.80 x noise, A and B at 1.2): judged
    run by run (`validation._verdict`), the friction is kept."""
    doc = _fit(101, ("coulomb",), tmp_path)
    assert doc["effects_added"] == ["coulomb_friction"]
    assert doc["residual_after"]["residual_over_noise"] < 2.0  # measured 1.02
    e = gen.make_campaign(101, ("coulomb",)).effects[0]
    p = doc["parameters"]
    assert p["c3"]["value"] == pytest.approx(e["F_c"], rel=0.1)  # 4001 N against 4080
    # v_s trades with β and ε along the valley: measured 6.71 mm/s against 6.2
    assert p["c3.v_s"]["value"] == pytest.approx(e["v_s"], rel=0.25)


def test_a_fit_stopped_short_in_a_narrow_valley_is_carried_on_to_the_noise(tmp_path):
    """Seed 1004: a sensor gain of 7.8 % (12 % of the peak force). It is named and sized
    right at once, but the refit with it stopped at 3.26 x noise with α at 70 against 84
    1/m and β at 111 against 95 s/m: there the valley is narrower than the refit's
    finite-difference step, the Jacobian points up its walls, and every trial step was
    refused. The final fit carried on with finer steps (`polish`) walks to the noise and
    brings back the generator's shape constants, not only the gain."""
    doc = _fit(1004, ("sensor_gain",), tmp_path)
    assert doc["effects_added"] == ["sensor_gain"]
    assert doc["residual_after"]["residual_over_noise"] < 1.2  # measured 1.06
    assert doc["unexplained"]["value"] is False
    truth = gen.make_campaign(1004, ("sensor_gain",))
    p = doc["parameters"]
    assert p["sensor_gain"]["value"] == pytest.approx(truth.effects[0]["g"], rel=0.005)
    # measured 84.41 against 84.44 1/m and 95.6 against 94.7 s/m (stopped: 70.5 and 111)
    assert p["alpha"]["value"] == pytest.approx(truth.constants["alpha"], rel=0.03)
    assert p["beta"]["value"] == pytest.approx(truth.constants["beta"], rel=0.05)


def test_a_friction_named_as_a_step_gets_its_build_up_back_in_the_final_fit(tmp_path):
    """Seed 102: a dry friction of 4.25 kN (28 % of the peak force) built up over
    v_s = 9.9 mm/s. Named and refitted at the library's step (v_s = 0, where the
    naming cannot tell a build-up from a size), the loop ended at 1.57 x noise and said
    "unexplained structure". The final fit started again with the build-up freed from
    the library's other shapes (`polish.restarted`) reaches the noise, with the
    generator's build-up velocity and size (the generator's constants in the library's
    terms, refitted, fit at 0.995 x)."""
    doc = _fit(102, ("coulomb",), tmp_path)
    assert doc["effects_added"] == ["coulomb_friction"]
    assert doc["residual_after"]["residual_over_noise"] < 1.2  # measured 0.995
    assert doc["unexplained"]["value"] is False
    e = gen.make_campaign(102, ("coulomb",)).effects[0]
    p = doc["parameters"]
    assert p["c3"]["value"] == pytest.approx(e["F_c"], rel=0.05)
    assert p["c3.v_s"]["value"] == pytest.approx(e["v_s"], rel=0.1)  # 9.6 against 9.9 mm/s


def test_a_friction_whose_fit_swapped_it_with_eq_10s_tanh_damper_is_exchanged_back(tmp_path):
    """Seed 105: a dry friction of 1.75 kN (12 % of the peak force) built up over
    v_s = 5.6 mm/s, acting inside the dead band too. Under Haswell, named first and
    refitted, every start of the loop ended in the valley where the two velocity terms
    have swapped roles: Eq 10's c2 tanh(βż) sharp (1/β 0.05 mm/s, outside the dead
    band only) and the friction smooth (v_s 35 mm/s), ε at 0.22 m/s (the generator's
    0.016), at 3.84 x noise ("unexplained structure"). Started with the two exchanged
    and δ, ε from the prior (`polish._roles_exchanged`), the final fit reaches the
    noise with the generator's friction and c2 tanh(βż): 1.01 x, 1747 N against 1748,
    β 64.6 against 64.9 s/m. With numpy's baseline kernels (`rig/__init__.py`) the
    loop ended beside that valley at 1.07 x, each size in its own term but the two
    build-ups exchanged (1/β 7.8 mm/s, v_s 16 against 15.4 and 5.6): below the level
    of "unexplained structure", and restarted there too (`close_loop`), it is
    exchanged back, 1.02 x, β 68.1."""
    doc = _fit(105, ("coulomb",), tmp_path)
    assert doc["effects_added"] == ["coulomb_friction"]
    assert doc["residual_after"]["residual_over_noise"] < 1.3  # measured 1.01-1.12
    assert doc["unexplained"]["value"] is False
    truth = gen.make_campaign(105, ("coulomb",))
    p = doc["parameters"]
    # the swapped valley had the friction at 1.29 kN (-26 %) and β at 21 000 s/m
    assert p["c3"]["value"] == pytest.approx(truth.effects[0]["F_c"], rel=0.05)  # -0.05, -1.5 %
    assert p["beta"]["value"] == pytest.approx(truth.constants["beta"], rel=0.1)  # -0.4, -3.3 %


@pytest.mark.parametrize("seed", [505, 513])
def test_a_one_sided_damping_is_named_alone_once_the_final_fit_is_started_again(
        seed, tmp_path):
    """Seed 505: 1.45 kN s/m more damping in extension (11 % of the peak force). Named
    first and refitted, it stopped at 1.67 x noise with α at 70 1/m and β at 205 s/m
    (the generator's 92 and 79): the valley of the base fit's softening spring. Started
    again from a quarter and four times that α (`polish.restarted`), the final fit
    reaches the noise with the generator's one-sided damping (the generator's constants
    in the library's terms, refitted, fit at 1.009 x).

    Seed 513: 3.63 kN s/m (26 % of the peak force; a draw the loop was not tuned on).
    The base fit is 476 x noise and the one-sided damping's refit 170 x: a force offset
    and a cubic spring are named after it (50 and 43 x), and the final fit's restarts
    reach 1.06 x with the offset at 0.24 N and k3 at 3.0 kN/m³, each explaining 0.07
    sensor-noise RMS of the motion. Judged again after the restarts
    (`prune.drop_redundant`) both are dropped: 1.07 x, the damping 0.14 % from the
    generator's.

    5 %: the fit's 95 % intervals are 0.01-0.1 %, and a damping that shares its force with
    another term moves by more."""
    doc = _fit(seed, ("asym_damping",), tmp_path)
    assert doc["effects_added"] == ["asymmetric_damping"]
    assert doc["residual_after"]["residual_over_noise"] < 1.2  # measured 1.01 and 1.07
    assert doc["unexplained"]["value"] is False
    e = gen.make_campaign(seed, ("asym_damping",)).effects[0]
    assert doc["parameters"]["c_ext"]["value"] == pytest.approx(e["c_a"], rel=0.05)


def test_an_offset_refitted_in_the_identified_models_valley_is_started_from_the_prior(
        tmp_path):
    """Seed 1105: a force offset of −507 N (3.4 % of the peak force). Named first, its
    refit from the identified model, which had bent Eq 10 round the offset, and every
    restart near the final fit stopped at 2.04 x noise ("unexplained structure"). The
    final fit started again with Eq 10's constants from the report's average
    (`polish._from_prior`: the prior `analysis fit` gives the loop, which never saw the
    runs) and the offset at its fitted size reaches the noise: 1.07 x (−508.1 N against
    the generator's −507.3 N) under SkylakeX, 1.07 x (−508.0 N) under Haswell, 1.09 x
    (−507.7 N) under Sandybridge."""
    doc = _fit(1105, ("force_offset",), tmp_path)
    assert doc["effects_added"] == ["force_offset"]
    assert doc["residual_after"]["residual_over_noise"] < 1.3  # measured 1.07-1.09
    assert doc["unexplained"]["value"] is False
    e = gen.make_campaign(1105, ("force_offset",)).effects[0]
    # within 0.16 % on the three kernels (its standard error 0.07 N); 2 % leaves room for
    # another valley near the noise
    assert doc["parameters"]["F0"]["value"] == pytest.approx(e["F0"], rel=0.02)
