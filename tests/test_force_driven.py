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
from analysis.force_driven.loading import ForceRecord
from analysis.force_driven.model import base_terms
from analysis.force_driven.simulate import simulate_position

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
