"""Force-driven CSV layout (`analysis fit --force … --position …`) on simulated data.

The data are generated backwards from a known motion, as a position-controlled
rig like EMPS produces them: a multisine position q(t) (0.3–8 Hz, ±10 mm) and the
force the true model needs to follow it, F = m q̈ + c q̇ + k q + Fc sgn(q̇) + F₀,
both measured with noise (force 0.3 N rms ≈ 1 % of its rms, position 1 µm rms,
about an encoder step). The truth is then exact, with no integrator error.

Tolerance: least squares on the filtered, decimated rows gives θ̂ and its std.
A Monte Carlo over 40 seeds (same generator) measured the spread of θ̂ at 0.95–1.23
times the reported std (the decimated residual is mildly coloured), and one
deterministic bias: the mass is 0.06 % high (≈ 1 std), the central differences'
(ωΔt)²/3 ≤ 0.08 % on q̈ at the top 8 Hz line. So the check is
|θ̂ − θ| < 4 × 1.3 std (+ 0.1 % of m for the mass), and every std must be small
(< 3 % of the value; measured 0.03–0.2 %) so that the check has teeth. The worst
of the 40 seeds used 5.2 reported std on the mass, 3.2 on the others.
"""

from __future__ import annotations

import gzip
import json

import numpy as np
import pytest
from scipy import signal

from analysis.cli import main
from analysis.force_driven import close_force_loop, fit_terms, prepare
from analysis.force_driven.identify import FOLD_GAP, FOLDS, HELDOUT_GAIN, blocked_folds, predict
from analysis.force_driven.loading import ForceRecord
from analysis.force_driven.model import base_terms
from analysis.force_driven.simulate import simulate_position

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

FS = 1000.0
DURATION = 30.0
TRUE = {"mass": 2.0, "viscous": 30.0, "stiffness": 2000.0, "coulomb_friction": 3.0,
        "force_offset": -1.0}
FORCE_NOISE = 0.3  # N rms
POSITION_NOISE = 1e-6  # m rms
SPREAD = 1.3  # Monte Carlo spread / reported std, rounded up (module doc)
CUTOFF, FACTOR = 50.0, 10  # decimated band 40 Hz: 5 × the 8 Hz content


def motion(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """t, q, q̇, q̈ of a random-phase multisine, exact derivatives."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(DURATION * FS)) / FS
    freqs = np.linspace(0.3, 8.0, 12)
    amps = 4e-3 / (1 + freqs / 2)  # less motion at high frequency, as a real drive
    phases = rng.uniform(0, 2 * np.pi, freqs.size)
    w = 2 * np.pi * freqs[:, None]
    arg = w * t + phases[:, None]
    q = (amps[:, None] * np.sin(arg)).sum(0)
    qd = (amps[:, None] * w * np.cos(arg)).sum(0)
    qdd = -(amps[:, None] * w**2 * np.sin(arg)).sum(0)
    return t, q, qd, qdd


def force_record(seed: int, truth: dict[str, float]) -> ForceRecord:
    t, q, qd, qdd = motion(seed)
    force = (truth["mass"] * qdd + truth.get("viscous", 0) * qd + truth.get("stiffness", 0) * q
             + truth.get("coulomb_friction", 0) * np.sign(qd) + truth.get("force_offset", 0))
    rng = np.random.default_rng(seed + 1000)
    force = force + FORCE_NOISE * rng.standard_normal(t.size)
    q = q + POSITION_NOISE * rng.standard_normal(t.size)
    return ForceRecord(f"sim{seed}", None, t, force, q, "force_N", "q_m")  # type: ignore[arg-type]


def write_csv(path, rec: ForceRecord, q_scale: float = 1.0) -> None:
    opener = gzip.open if str(path).endswith(".gz") else open
    with opener(path, "wt", encoding="utf-8") as f:
        f.write("t,force_N,q_m\n")
        for row in zip(rec.t, rec.force, rec.position * q_scale):
            f.write(",".join(repr(float(x)) for x in row) + "\n")


def test_recovers_known_parameters():
    rec = force_record(1, TRUE)
    p = prepare(rec, CUTOFF, FACTOR, "central")
    fit = fit_terms([p], list(TRUE))
    for name, true in TRUE.items():
        est, std = fit.value(name), float(fit.std[fit.names.index(name)])
        assert std < 0.03 * abs(true), (name, est, std)
        bias = 1e-3 * abs(true) if name == "mass" else 0.0
        assert abs(est - true) < 4 * SPREAD * std + bias, (name, est, std, true)


def test_loop_finds_coulomb_first_and_the_offset():
    rec = force_record(2, TRUE)
    p = prepare(rec, CUTOFF, FACTOR, "central")
    loop = close_force_loop([p], base_terms(False, True))
    assert loop.effects_added[0] == "coulomb_friction"
    assert set(loop.effects_added) == {"coulomb_friction", "force_offset"}
    assert loop.final.relative_error < 0.5 * loop.base.relative_error
    assert abs(loop.final.value("coulomb_friction") - 3.0) < 0.3


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_clean_linear_data_adds_nothing(seed):
    linear = {k: TRUE[k] for k in ("mass", "viscous", "stiffness")}
    p = prepare(force_record(seed, linear), CUTOFF, FACTOR, "central")
    loop = close_force_loop([p], base_terms(False, True))
    assert loop.effects_added == [], loop.refused


def test_known_mass_is_held():
    p = prepare(force_record(6, TRUE), CUTOFF, FACTOR, "central")
    loop = close_force_loop([p], base_terms(True, True), mass=TRUE["mass"])
    assert "mass" not in loop.final.names
    assert loop.effects_added[0] == "coulomb_friction"
    assert abs(loop.final.value("viscous") - TRUE["viscous"]) < 2.0


def test_forward_simulation_matches_the_generator():
    # a linear mass-spring-damper (5 Hz) simulated forwards by RK4, then identified back.
    # The force is band-limited to 10 Hz, where central differences are biased by
    # (ωΔt)²/3 < 0.2 % on q̈: 1 % on m and k is a generous margin, nothing else is noisy.
    t = np.arange(20000) / FS
    rng = np.random.default_rng(7)
    b, a = signal.butter(4, 10.0 / (FS / 2))
    force = 50.0 * signal.filtfilt(b, a, rng.standard_normal(t.size))
    truth = {"viscous": 30.0, "stiffness": 2000.0}
    q = simulate_position({"mass": 2.0, **truth}, force, 1 / FS, 0.0, 0.0)
    rec = ForceRecord("fwd", None, t, force, q, "f", "q")  # type: ignore[arg-type]
    fit = fit_terms([prepare(rec, 100.0, 5, "central")], ["mass", "viscous", "stiffness"])
    assert abs(fit.value("mass") - 2.0) < 0.02
    assert abs(fit.value("viscous") - 30.0) < 0.3
    assert abs(fit.value("stiffness") - 2000.0) < 20.0


def test_cli_force_layout_json(tmp_path, capsys):
    path = tmp_path / "msd.csv.gz"
    write_csv(path, force_record(8, TRUE), q_scale=1 / 0.0254)  # position in inches
    out = tmp_path / "fit.json"
    rc = main(["fit", str(path), "--force", "force_N", "--position", "q_m", "--units", "us",
               "--stiffness", "--cutoff", str(CUTOFF), "--decimate", str(FACTOR),
               "--json", str(out)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "coulomb_friction" in text and "± " in text
    doc = json.loads(out.read_text())
    for key in ("parameters", "error_before", "error_after", "effects_added", "loop",
                "unexplained", "model"):
        assert key in doc
    assert doc["effects_added"][0] == "coulomb_friction"
    for step in doc["loop"]:
        assert {"added", "evidence", "error_before", "error_after"} <= set(step)
    assert doc["error_after"] < doc["error_before"]
    k = doc["parameters"]["k"]
    assert abs(k["value"] - 2000.0) < 4 * k["std"] + 1e-9
    assert doc["parameters"]["m"]["unit"] == "kg"


def _bad(tmp_path, capsys, args, rows=None, header="t,force_N,q_m"):
    path = tmp_path / "bad.csv"
    if rows is not None:
        path.write_text(header + "\n" + "\n".join(rows) + "\n")
    rc = main(["fit", str(path), *args])
    err = capsys.readouterr().err
    assert rc == 2
    assert "Traceback" not in err
    assert len(err.strip().splitlines()) == 1, err
    return err


def _rows(n=400, dt=1e-3):
    return [f"{i * dt!r},{np.sin(i / 10):.6f},{np.cos(i / 10) * 1e-3:.9f}" for i in range(n)]


def test_missing_column_is_named_with_the_available_ones(tmp_path, capsys):
    err = _bad(tmp_path, capsys, ["--force", "force_N", "--position", "qg_m"], _rows())
    assert "qg_m" in err and "t, force_N, q_m" in err


def test_duplicate_time(tmp_path, capsys):
    rows = _rows()
    rows[100] = rows[99]
    err = _bad(tmp_path, capsys, ["--force", "force_N", "--position", "q_m"], rows)
    assert "duplicate time" in err


def test_nan(tmp_path, capsys):
    rows = _rows()
    rows[50] = rows[50].split(",")[0] + ",nan,0.0"
    err = _bad(tmp_path, capsys, ["--force", "force_N", "--position", "q_m"], rows)
    assert "non-finite" in err


def test_too_short(tmp_path, capsys):
    err = _bad(tmp_path, capsys, ["--force", "force_N", "--position", "q_m"], _rows(50))
    assert "50 samples" in err


def test_force_without_position(tmp_path, capsys):
    err = _bad(tmp_path, capsys, ["--force", "force_N"], _rows())
    assert "--position" in err


def test_base_excited_without_mass(tmp_path, capsys):
    err = _bad(tmp_path, capsys, [], _rows(), header="t,u,x")
    assert "--mass" in err


# ------------------------------------------------------------- the held-out check
# Known truth: mass, viscous and Coulomb friction, plus a force κ max(q, 0) that is not a
# spring of the system: it acts only in part of the record or only one way. κ = 400 N/m
# gives 1.2 N rms (4.6 N at the +11.5 mm peak), a third of the Coulomb level, enough for
# the term to pass the in-sample tests (p < 0.001, 2 % cut) in most seeds, so that only
# the held-out check stands between it and the model.
# Measured over seeds 11–18: a single 75/25 split accepts it in every seed (held-out sum of
# squares ×0.41–0.57); the folds refuse it in every seed, and accept it in every seed
# when the spring acts throughout (×0.007–0.09 on the split, 4 of 4 folds).
CABLE = 400.0  # N/m
HELD_TRUTH = {"mass": 2.0, "viscous": 30.0, "coulomb_friction": 3.0}
POSITION_TERM = "asymmetric_stiffness"  # κ max(q, 0)


def cable_record(seed: int, acts) -> ForceRecord:
    """HELD_TRUTH plus CABLE max(q, 0) where acts(t, q̇) is 1, measured with noise."""
    t, q, qd, qdd = motion(seed)
    force = (HELD_TRUTH["mass"] * qdd + HELD_TRUTH["viscous"] * qd
             + HELD_TRUTH["coulomb_friction"] * np.sign(qd)
             + CABLE * np.maximum(q, 0.0) * acts(t, qd))
    rng = np.random.default_rng(seed + 1000)
    force = force + FORCE_NOISE * rng.standard_normal(t.size)
    q = q + POSITION_NOISE * rng.standard_normal(t.size)
    return ForceRecord(f"cable{seed}", None, t, force, q, "force_N", "q_m")  # type: ignore[arg-type]


def single_split_ratio(p, base: list[str], candidate: str) -> float:
    """Held-out sum of squares with / without `candidate`: fit on the first 75 % of the
    record, predict the last 25 % (one split, the check the folds replace)."""
    cut = int(0.75 * p.rows)
    ss = []
    for names in (base, base + [candidate]):
        resid, _ = predict(fit_terms([p], names, rows=[slice(0, cut)]), [p], [slice(cut, None)])
        ss.append(float(resid @ resid))
    return ss[1] / ss[0]


def _cable_loop(acts, seed: int = 11):
    p = prepare(cable_record(seed, acts), CUTOFF, FACTOR, "central")
    loop = close_force_loop([p], base_terms(False, False),
                            candidates=["coulomb_friction", POSITION_TERM])
    split = single_split_ratio(p, base_terms(False, False) + ["coulomb_friction"],
                               POSITION_TERM)
    reasons = [r["reason"] for r in loop.refused if r["candidate"] == POSITION_TERM]
    return loop, split, reasons


def test_folds_refuse_a_term_that_one_stretch_carries():
    # the force acts in the first and last quarters only: the tail split sees it in the fit
    # and in the test, the folds see it help two stretches and hurt the other two
    def ends(t, qd):
        return ((t < DURATION / 4) | (t >= 3 * DURATION / 4)).astype(float)

    loop, split, reasons = _cable_loop(ends)
    assert split < 1 - HELDOUT_GAIN  # the single split would add it (measured ×0.44)
    assert loop.effects_added == ["coulomb_friction"]
    assert any("better in only 2 of 4 folds" in r for r in reasons), reasons
    coulomb = loop.steps[0].evidence["heldout_folds"]
    assert coulomb["better"] == coulomb["folds"] == FOLDS  # the real term: every fold


def test_folds_refuse_a_term_that_trades_one_direction_for_the_other():
    # the force acts only while moving backwards (a position-dependent drag one way): a
    # spring fits it on average, better backwards and worse forwards, in every stretch
    def backwards(t, qd):
        return (qd < 0).astype(float)

    loop, split, reasons = _cable_loop(backwards)
    assert split < 1 - HELDOUT_GAIN  # measured ×0.41
    assert loop.effects_added == ["coulomb_friction"]
    assert any("worse while moving forwards" in r for r in reasons), reasons


def test_folds_accept_the_term_when_it_is_in_the_system():
    loop, split, _ = _cable_loop(lambda t, qd: np.ones_like(t))
    assert loop.effects_added == ["coulomb_friction", POSITION_TERM]
    step = loop.steps[1]
    assert step.evidence["heldout_folds"]["better"] == FOLDS
    assert abs(step.value - CABLE) < 4 * SPREAD * step.std


def test_blocked_folds_cover_each_row_once_and_keep_a_gap():
    p = prepare(force_record(9, TRUE), CUTOFF, FACTOR, "central")
    folds = blocked_folds([p], FOLDS)
    tested = np.concatenate([np.arange(p.rows)[f.test[0][1]] for f in folds])
    assert np.array_equal(tested, np.arange(p.rows))
    for f in folds:
        s = f.test[0][1]
        fit = f.fit_rows[0]
        near = np.abs(fit[:, None] - np.array([s.start, s.stop - 1])[None, :]).min()
        assert near > FOLD_GAP and not np.isin(np.arange(s.start, s.stop), fit).any()
