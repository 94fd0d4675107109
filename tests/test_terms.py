"""Term kinds: the one formula per kind, stateful terms, batch = single."""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.identify.regressors import state_after
from analysis.model.isolator import IsolatorModel, Term
from analysis.model.model_json import model_from_json, model_json
from analysis.model.terms import BOUC_WEN, KINDS, basis, kind
from analysis.simulate import simulate, simulate_batch
from rig.profile import Profile, Segment

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

# the formulas as the report writes them, independent of the kernel
EXPECTED = {
    "linear_spring": lambda z, zd, a: z,
    "tanh_spring": lambda z, zd, a: math.tanh(a * z),
    "linear_damper": lambda z, zd, a: zd,
    "tanh_damper": lambda z, zd, a: math.tanh(a * zd),
    "coulomb": lambda z, zd, a: math.tanh(zd / a),  # built up over v_s = a
    "preload": lambda z, zd, a: math.copysign(1.0, z),
    "cubic_spring": lambda z, zd, a: z**3,
    "quadratic_damper": lambda z, zd, a: zd * abs(zd),
    "force_offset": lambda z, zd, a: 1.0,
    "compression_spring": lambda z, zd, a: max(z, 0.0),
    "extension_damper": lambda z, zd, a: max(zd, 0.0),
}


@pytest.mark.parametrize("name", sorted(EXPECTED))
@pytest.mark.parametrize("z,zd", [(0.03, -0.4), (-0.11, 1.7), (0.002, 0.01)])
def test_basis_matches_formula(name, z, zd):
    k = kind(name)
    a = 78.74
    got = basis(k.code, z, zd, math.copysign(1.0, z), math.copysign(1.0, zd), 0.0, a, 0.0, 0.0)
    assert got == pytest.approx(EXPECTED[name](z, zd, a), rel=1e-14)


def test_a_friction_built_up_over_no_velocity_is_the_reports_step():
    """c3 tanh(ż/v_s) at v_s = 0 is c3 sgn(ż), with the sign the integrator holds (0 at
    rest); a term written before v_s existed reads as that step."""
    code = kind("coulomb").code
    for zd in (-0.4, 2e-3, 1.7):
        s = math.copysign(1.0, zd)
        assert basis(code, 0.0, zd, 1.0, s, 0.0, 0.0, 0.0, 0.0) == s
        assert basis(code, 0.0, zd, 1.0, s, 0.0, 5e-3, 0.0, 0.0) == pytest.approx(
            math.tanh(zd / 5e-3), rel=1e-14)
    assert basis(code, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0) == 0.0  # held: no sign yet
    assert Term("coulomb", "c3", 150.0).shape == (0.0,)


def test_every_kind_has_a_formula_and_units():
    for k in KINDS.values():
        assert k.coef_unit and k.formula and k.meaning
        assert len(k.shape_names) == len(k.shape_units)
        assert not math.isnan(basis(k.code, 0.1, 0.1, 1.0, 1.0, 0.1, 1.0, 1.0, 1.0))


def test_unknown_kind_is_named():
    with pytest.raises(KeyError, match="unknown term kind 'spring9'"):
        Term("spring9", "k9", 1.0)
    with pytest.raises(ValueError, match="needs shape constants"):
        Term("tanh_spring", "k2", 1.0)


def test_stateful_hysteresis_term_runs_in_the_same_simulator():
    """A Bouc–Wen term added to a linear isolator: the force–displacement loop opens."""
    base = IsolatorModel(mass=2721.55, terms=(Term("linear_spring", "k1", 7.0e4),
                                              Term("linear_damper", "c1", 3.0e3)))
    hyst = base.with_terms(Term("bouc_wen", "kh", 2.0e4, (60.0, 20.0, 1.0)))
    motion = Profile("pulse", (Segment(0.1), Segment(0.12, 0.14), Segment(0.12, 0.0),
                               Segment(1.5))).motion()
    r = simulate(hyst, motion)
    s = r.states["kh"]
    # the hysteretic variable is bounded by 1/(a+b) and follows ż
    assert np.abs(s).max() <= 1 / (60.0 + 20.0) * (1 + 1e-6)
    assert np.abs(s).max() > 0.5 / 80.0
    np.testing.assert_allclose(r.forces["kh"], 2.0e4 * s)
    # energy dissipated by the hysteretic force over the run is positive (a loop, not a line)
    work = np.trapezoid(r.forces["kh"] * r.zd, r.t)
    assert work > 1.0
    assert np.abs(simulate(base, motion).z - r.z).max() > 1e-3  # it changes the response


def test_batch_equals_single(average_model, run_a):
    rng = np.random.default_rng(3)
    V = np.tile(average_model.vector(), (5, 1))
    V[:, 4::4] *= rng.uniform(0.7, 1.3, (5, V[:, 4::4].shape[1]))
    batch = simulate_batch(average_model, V, run_a.motion())
    names = list(average_model.vector_index())
    for i in range(5):
        values = {n: V[i, average_model.vector_index()[n]] for n in names}
        single = simulate(average_model.with_parameters(**values), run_a.motion())
        np.testing.assert_array_equal(batch.z[i], single.z)
        np.testing.assert_array_equal(batch.xdd[i], single.xdd)
    with pytest.raises(ValueError, match="parameter rows"):
        simulate_batch(average_model, V[:, :-1], run_a.motion())


def test_thermal_damper_heats_with_dissipation_and_cools_with_its_time_constant():
    """θ' = a ż² − θ/τ: θ rises while the damper works, then decays as exp(−t/τ) at rest."""
    base = IsolatorModel(mass=2721.55, terms=(Term("linear_spring", "k1", 7.0e4),
                                              Term("linear_damper", "c1", 6.0e3)))
    heating, tau = 0.8, 2.0
    warm = base.with_terms(Term("thermal_damper", "c_T", -400.0, (heating, tau)))
    motion = Profile("pulse", (Segment(0.1), Segment(0.12, 0.14), Segment(0.12, 0.0),
                               Segment(5.0))).motion()
    r = simulate(warm, motion)
    theta = r.states["c_T"]
    # heating: while moving, the rise matches ∫ a ż² dt less the small loss over the pulse
    i_peak = int(np.argmax(theta))
    gained = np.trapezoid(heating * r.zd[: i_peak + 1] ** 2, r.t[: i_peak + 1])
    assert theta[i_peak] == pytest.approx(gained, rel=0.15)
    assert theta[i_peak] > 0.1
    # cooling: once at rest, θ(t + 1 s) / θ(t) = exp(−1/τ)
    rest = np.flatnonzero((np.abs(r.zd) < 1e-6) & (r.t > 3.0))
    i = rest[0]
    j = i + 1000
    assert theta[j] / theta[i] == pytest.approx(np.exp(-1.0 / tau), rel=1e-4)
    np.testing.assert_allclose(r.forces["c_T"], -400.0 * theta * r.zd, atol=1e-9)


def test_a_thermal_drift_stops_at_theta_max_while_the_fluid_heats_on():
    """c_T min(θ, θ_max) ż: past θ_max the damping is the hot fluid's, and c1 + c_T θ
    cannot cross zero into a damper that feeds the motion (an unseen drift whose
    damping falls to a floor diverged in its third run without one)."""
    base = IsolatorModel(mass=2721.55, terms=(Term("linear_spring", "k1", 7.0e4),
                                              Term("linear_damper", "c1", 6.0e3)))
    theta_max = 0.05
    hot = base.with_terms(Term("thermal_damper", "c_T", -6.0e4, (0.8, 2.0, theta_max)))
    motion = Profile("pulse", (Segment(0.1), Segment(0.12, 0.14), Segment(0.12, 0.0),
                               Segment(2.0))).motion()
    r = simulate(hot, motion)
    theta = r.states["c_T"]
    assert theta.max() > 2 * theta_max  # heated well past the limit ...
    np.testing.assert_allclose(r.forces["c_T"], -6.0e4 * np.minimum(theta, theta_max) * r.zd,
                               atol=1e-9)  # ... and the drift stopped there
    assert np.all(np.isfinite(r.z)) and np.abs(r.z).max() < 0.5
    # the same drift unlimited takes more damping than c1 and the mass runs away
    free = base.with_terms(Term("thermal_damper", "c_T", -6.0e4, (0.8, 2.0)))
    assert free.term("c_T").shape == (0.8, 2.0, 0.0)  # left out: no limit
    runaway = simulate(free, motion)
    assert not (np.all(np.isfinite(runaway.z)) and np.abs(runaway.z).max() < 0.5)


def test_initial_state_carries_a_warm_fluid_into_the_run():
    """s0 sets θ at t0: a warm start damps less, and batch agrees with single."""
    base = IsolatorModel(mass=2721.55, terms=(Term("linear_spring", "k1", 7.0e4),
                                              Term("linear_damper", "c1", 6.0e3),
                                              Term("thermal_damper", "c_T", -400.0, (0.8, 2.0))))
    motion = Profile("pulse", (Segment(0.1), Segment(0.12, 0.14), Segment(0.12, 0.0),
                               Segment(1.0))).motion()
    cold = simulate(base, motion)
    warm = simulate(base, motion, s0=[0.0, 0.0, 5.0])
    assert warm.states["c_T"][0] == 5.0
    assert cold.states["c_T"][0] == 0.0
    # less damping when warm: the mass overshoots further
    assert np.abs(warm.z).max() > np.abs(cold.z).max() + 1e-3
    batch = simulate_batch(base, np.tile(base.vector(), (2, 1)), motion,
                           s0=[[0.0, 0.0, 0.0], [0.0, 0.0, 5.0]])
    np.testing.assert_array_equal(batch.z[0], cold.z)
    np.testing.assert_array_equal(batch.z[1], warm.z)
    with pytest.raises(ValueError, match="initial states have shape"):
        simulate(base, motion, s0=[1.0])


@pytest.mark.parametrize("n", [1.0, 2.0, 3.0])
def test_a_bouc_wen_loop_yields_at_its_exponents_root(n):
    """r' = ż − a|ż||r|ⁿ⁻¹r − b ż|r|ⁿ: driven one way, r rises with slope 1 and levels
    off at the yield (a + b)^(−1/n), sharper the larger n (a seal that yields at once)."""
    y = 2.0e-3
    a, b = 0.7 / y**n, 0.3 / y**n
    dt, zd = 1e-4, np.full(20000, 0.1)  # 0.2 m one way at 0.1 m/s
    assert state_after(BOUC_WEN, (a, b, n), zd, dt, 0.0) == pytest.approx(y, rel=1e-3)
    # at a tenth of the yield the seal is nearly elastic, dr/dz = 1 − (r/y)ⁿ: r/z ≈
    # 1 − 0.1ⁿ/(n + 1), the more so the larger n
    k = round(0.1 * y / (0.1 * dt))
    r_tenth = state_after(BOUC_WEN, (a, b, n), zd[:k], dt, 0.0)
    assert r_tenth / (0.1 * y) == pytest.approx(1 - 0.1**n / (n + 1), abs=0.005)


@pytest.mark.parametrize("n", [1.0, 2.0])
def test_a_loop_that_yields_in_a_millimetre_stays_within_its_yield_at_a_fast_runs_rate(n):
    """At 1 kHz a loop that yields in 1.25 mm turns over at up to 1600 |ż| 1/s (n = 2):
    one midpoint step per sample is unstable past 1.25 m/s, and an unseen run's column
    went to NaN. Driven back and forth at up to 3 m/s, the state stays within its yield
    and follows the same loop integrated at a hundred times the rate."""
    y, dt = 1.25e-3, 1e-3
    a, b = 0.75 / y**n, 0.25 / y**n
    t = np.arange(0.0, 1.0, dt)
    zd = 3.0 * np.sin(2 * np.pi * 2.0 * t)  # ±3 m/s, reversing every 0.25 s
    ends = [state_after(BOUC_WEN, (a, b, n), zd[:k], dt, 0.0) for k in (60, 130, 380, 1000)]
    assert all(np.isfinite(ends)) and max(abs(r) for r in ends) <= y * (1 + 1e-9)
    fine = np.repeat(zd, 100)  # the same ż held over each sample, at 100 kHz
    exact = [state_after(BOUC_WEN, (a, b, n), fine[:100 * k], dt / 100, 0.0)
             for k in (60, 130, 380, 1000)]
    np.testing.assert_allclose(ends, exact, atol=0.02 * y)


def test_a_model_written_before_the_exponent_reads_as_n_1():
    """A Bouc–Wen term saved with a and b only (the kind had no n) reads back with n = 1."""
    model = IsolatorModel(mass=2721.55, terms=(Term("linear_spring", "k1", 7.0e4),
                                               Term("bouc_wen", "k_h", 2.0e4,
                                                    (60.0, 20.0, 1.0))))
    block = model_json(model)
    del block["terms"][1]["shape"]["n"]
    assert model_from_json(block).model == model
