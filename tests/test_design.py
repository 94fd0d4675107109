"""`analysis design`: the optimum is the one an exhaustive search finds.

A linear isolator (k1, c1 free) under a velocity step has a closed-form response,
so its optimum is found here by exhaustive search without the simulator; under a
displacement step (a profile file, through the CLI) it is found by simulating a
grid. The search must land on both. Then: limits no design meets are reported
with the closest design, Figure 1's ideal isolator gives ΔV²/(2a) for a velocity
step, and bad input is one line, exit 2.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest
from scipy.interpolate import PPoly

from analysis.design.cli import add_design_parser, run_design
from analysis.design.design import design
from analysis.design.ideal import ideal_curve
from analysis.design.objective import Evaluator
from analysis.design.pareto import pareto_front
from analysis.design.problem import Limits
from analysis.design.quantity import parse_quantity
from analysis.design.space import Bound, DesignSpace
from analysis.design.threat import Threat, read_threat
from analysis.model.isolator import IsolatorModel, Term
from analysis.model.model_json import SCHEMA_VERSION, model_from_json, model_json
from analysis.predict import BaseMotion
from rig.cli_support import guarded
from rig.errors import DataError
from rig.units import STANDARD_GRAVITY, to_si

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

INCH = 0.0254
MASS = float(to_si(6000, "lbm"))
# the velocity step: the table's acceleration a triangle pulse of RAMP seconds from T0
# (so that ü is continuous: the simulator is fourth order only for motions whose ü is),
# after which it moves on at V
V, RAMP, T0, SPAN = 1.0, 0.02, 0.05, 1.2  # m/s, s, s, s
JERK = 4 * V / RAMP**2  # m/s³, the pulse's slope
PULSE = ((T0, 1.0), (T0 + RAMP / 2, -2.0), (T0 + RAMP, 1.0))  # ü = JERK Σ w (t − tᵢ)⁺
TAIL = 0.5  # s, as analysis.design.objective simulates past the record


def velocity_step() -> Threat:
    udd = PPoly(np.array([[0.0, JERK, -JERK, 0.0], [0.0, 0.0, JERK * RAMP / 2, 0.0]]),
                np.array([0.0, T0, T0 + RAMP / 2, T0 + RAMP, SPAN]))
    return Threat("velocity step", BaseMotion(udd.antiderivative(2), 0.0, SPAN, 1e-3,
                                              "velocity step"))


def linear_model(k1: float = 1e5, c1: float = 1e4) -> IsolatorModel:
    return IsolatorModel(MASS, (Term("linear_spring", "k1", k1), Term("linear_damper", "c1", c1)))


def closed_form_peaks(k: np.ndarray, c: np.ndarray, dt: float = 5e-4
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Peak |ẍ| and |z| (N,) of m z̈ + c ż + k z = −m ü for the velocity step: the sum of
    a linear oscillator's responses to ramps of forcing (complex ω_d covers the
    overdamped ones)."""
    k, c = np.asarray(k, float)[:, None], np.asarray(c, float)[:, None]
    t = np.arange(0.0, SPAN + TAIL, dt)[None, :]
    w = np.sqrt(k / MASS)
    zeta = c / (2 * np.sqrt(k * MASS))
    wd = w * np.sqrt((1 - zeta**2).astype(complex))
    wd = np.where(np.abs(wd) < 1e-9, 1e-9, wd)  # critical damping, as a limit
    A, B = 2 * zeta / w**3, (2 * zeta**2 - 1) / (w**2 * wd)  # from z(0) = ż(0) = 0

    def ramp(start: float) -> tuple[np.ndarray, np.ndarray]:
        # z̈ + 2ζω ż + ω² z = τ from rest at τ = 0
        tau = np.maximum(t - start, 0.0)
        e = np.exp(-zeta * w * tau)
        cos, sin = np.cos(wd * tau), np.sin(wd * tau)
        z = tau / w**2 - 2 * zeta / w**3 + e * (A * cos + B * sin)
        zd = 1 / w**2 + e * ((wd * B - zeta * w * A) * cos - (zeta * w * B + wd * A) * sin)
        return z.real, zd.real

    z, zd = 0.0, 0.0
    for start, weight in PULSE:
        zr, zdr = ramp(start)
        z, zd = z - JERK * weight * zr, zd - JERK * weight * zdr
    xdd = -(c * zd + k * z) / MASS
    return np.abs(xdd).max(axis=1), np.abs(z).max(axis=1)


def closed_form_optimum(stroke: float, k: np.ndarray) -> tuple[float, float, float]:
    """(k1, c1, peak accel) of the least acceleration with the stroke within `stroke`:
    for each k on the grid, the least c that keeps the stroke (bisection), then the best k."""
    lo, hi = np.zeros_like(k), np.full_like(k, 1e5)
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        ok = closed_form_peaks(k, mid)[1] <= stroke
        hi, lo = np.where(ok, mid, hi), np.where(ok, lo, mid)
    a = closed_form_peaks(k, hi)[0]
    i = int(np.argmin(a))
    return float(k[i]), float(hi[i]), float(a[i])


def ideal_stroke(a: np.ndarray, motion: PPoly) -> np.ndarray:
    """Figure 1's isolator on the velocity step, by hand: the mass rides with the table
    until ü reaches a, then slides against a constant force until ẋ = V."""
    ts = T0 + a / JERK
    vs = motion(ts, 1)
    t_end = ts + (V - vs) / a  # after the pulse for every a used below
    x_end = motion(ts) + vs * (t_end - ts) + 0.5 * a * (t_end - ts) ** 2
    return motion(t_end) - x_end


def test_linear_isolator_on_a_velocity_step_matches_the_closed_form_exhaustive_search():
    stroke = 4 * INCH
    k, _, _ = closed_form_optimum(stroke, np.geomspace(5e3, 4e5, 25))
    k_opt, c_opt, a_opt = closed_form_optimum(stroke, np.linspace(0.85 * k, 1.15 * k, 31))
    # the textbook figure: the best linear isolator needs ~0.52 V²/S, the ideal 0.5 V²/S
    assert a_opt * stroke / V**2 == pytest.approx(0.52, abs=0.01)
    threat = velocity_step()
    # the simulator agrees with the closed form at that optimum
    sim = Evaluator(linear_model(), [threat])(linear_model(k_opt, c_opt).vector())
    assert sim.worst_accel[0] == pytest.approx(a_opt, rel=1e-3)
    assert sim.worst_stroke[0] == pytest.approx(stroke, rel=1e-3)

    space = DesignSpace(linear_model(), (Bound("k1", 5e3, 4e5), Bound("c1", 0.0, 4e4)))
    r = design(linear_model(), space, [threat], Limits(STANDARD_GRAVITY, stroke))
    a, z = r.archive.worst_accel[r.optimum], r.archive.worst_stroke[r.optimum]
    k1, c1 = r.archive.values[r.optimum]
    assert r.feasible and z <= stroke
    assert a == pytest.approx(a_opt, rel=3e-3)
    assert k1 == pytest.approx(k_opt, rel=0.05) and c1 == pytest.approx(c_opt, rel=0.03)
    # the tolerances: stiffer or more damped only costs acceleration, softer crosses the
    # stroke at once (it binds)
    tol = {t.name: t for t in r.tolerances}
    assert tol["c1"].limits[0] < 0.01 and tol["c1"].crossed[0] == "stroke"
    assert tol["c1"].within[1] > 0.01


def test_ideal_isolator_needs_delta_v_squared_over_twice_the_stroke():
    threat = velocity_step()
    curve = ideal_curve([threat], MASS)
    # sliding before the pulse peaks, caught up within the simulated time
    slides = (curve.accel < JERK * RAMP / 4) & (curve.accel > 2 * V / (SPAN + TAIL))
    assert slides.sum() > 10
    assert np.allclose(curve.stroke[slides], ideal_stroke(curve.accel[slides],
                                                          threat.drive.motion), rtol=2e-3)
    assert np.allclose(curve.accel[slides], curve.force[slides] / MASS, rtol=1e-9)
    stroke = 4 * INCH
    a = curve.accel_at(stroke)
    assert ideal_stroke(np.array([a]), threat.drive.motion)[0] == pytest.approx(stroke,
                                                                               rel=0.01)
    # ΔV²/(2S), less what the table's own pulse takes up: about V²/(2 (S + V RAMP / 2))
    assert 1 / (1 + V * RAMP / stroke) <= a / (V**2 / (2 * stroke)) <= 1.0


# --- through the CLI: a displacement step, checked against a grid of simulations ---------

STEP = """name = "step"
units = "in"
[[segment]]
hold = 0.05
[[segment]]
ramp_to = 3.0
duration = 0.1
[[segment]]
hold = 1.2
"""
K1_MAX, C1_MAX = 2000.0, 300.0  # lb/in, lb/(in/s): the box of the grid and of the design


def analysis(argv: list[str]) -> int:
    """`analysis design …` as analysis.cli will run it, with its one-line errors."""
    def main(args: list[str]) -> int:
        parser = argparse.ArgumentParser(prog="analysis")
        add_design_parser(parser.add_subparsers(dest="command", required=True))
        return run_design(parser.parse_args(args))

    return guarded(main, argv, "analysis")


class Exhaustive:
    """The step profile, a fit JSON of a linear isolator, and exhaustive search of the
    box. The optimum of a limit lies on a boundary (the stroke at its limit; both limits
    relaxed by the same factor), along which a grid's points miss it by up to a cell
    of c1: so for each k1 of a 33-point grid, c1 is put on the boundary by bisection,
    and the best k1 is then searched again on a 33-point grid over ±2 cells around it."""

    N = 33

    def __init__(self, tmp: Path) -> None:
        self.dir = tmp
        (tmp / "step.toml").write_text(STEP, encoding="utf-8")
        model = linear_model(to_si(400, "lb/in"), to_si(30, "lb/(in/s)"))
        (tmp / "fit.json").write_text(json.dumps({"identified_model": model_json(model)}))
        self.space = DesignSpace(model, (Bound("k1", 0.0, to_si(K1_MAX, "lb/in")),
                                         Bound("c1", 0.0, to_si(C1_MAX, "lb/(in/s)"))))
        self.evaluate = Evaluator(model, [read_threat(str(tmp / "step.toml"))])

    def peaks(self, k: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = self.evaluate(self.space.rows(self.space.values(np.column_stack([k, c]))))
        return p.worst_accel, p.worst_stroke

    def on_boundary(self, k: np.ndarray, beyond) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For each k (unit box), the least c with beyond(a, z) ≤ 0 (it falls with c)."""
        lo, hi = np.zeros_like(k), np.ones_like(k)
        for _ in range(30):
            mid = 0.5 * (lo + hi)
            ok = beyond(*self.peaks(k, mid)) <= 0
            hi, lo = np.where(ok, mid, hi), np.where(ok, lo, mid)
        return (hi, *self.peaks(k, hi))

    def best(self, beyond, value) -> tuple[float, np.ndarray]:
        """(value, constants SI) of the point of least value(a, z) on the boundary."""
        cell = 1.0 / (self.N - 1)
        k = np.linspace(0, 1, self.N)
        for _ in range(2):
            c, a, z = self.on_boundary(k, beyond)
            i = int(np.argmin(value(a, z)))
            best = (float(value(a, z)[i]), self.space.values([k[i], c[i]])[0])
            k = np.linspace(max(k[i] - 2 * cell, 0), min(k[i] + 2 * cell, 1), self.N)
        return best


@pytest.fixture(scope="module")
def step_case(tmp_path_factory) -> Exhaustive:
    return Exhaustive(tmp_path_factory.mktemp("design"))


def run_step(case: Exhaustive, tmp: Path, *limits: str) -> tuple[int, dict]:
    out = tmp / "d.json"
    code = analysis(["design", "--threat", str(case.dir / "step.toml"), *limits,
                     "--from", str(case.dir / "fit.json"), "--free", "k1,c1",
                     "--bound", f"k1=0:{K1_MAX}", "--bound", f"c1=0:{C1_MAX}",
                     "--samples", "64", "--json", str(out), "--report", str(tmp / "rep")])
    return code, json.loads(out.read_text()) if out.exists() else {}


def test_displacement_step_optimum_matches_the_exhaustive_search(step_case, tmp_path, capsys):
    stroke = 2.5 * INCH
    code, doc = run_step(step_case, tmp_path, "--max-accel", "1g", "--max-stroke", "2.5in")
    assert code == 0
    d = doc["design"]
    best, constants = step_case.best(lambda a, z: z - stroke, lambda a, z: a)
    a, z = d["optimum"]["peak_accel"], d["optimum"]["peak_stroke"]
    assert d["feasible"] and z <= stroke
    assert a == pytest.approx(best, rel=1e-3)
    found = [d["optimum"]["constants"][n] for n in ("k1", "c1")]
    assert np.allclose(step_case.space.coords(found), step_case.space.coords(constants),
                       atol=0.01)
    # the design JSON is a model `sim response --model` reads
    designed = model_from_json(doc).model.parameters()
    assert designed["k1"] == pytest.approx(d["optimum"]["constants"]["k1"])
    assert (tmp_path / "rep" / "pareto.png").stat().st_size > 10_000
    text = capsys.readouterr().out
    assert "verdict: meets both limits" in text and "tolerances" in text


def test_limits_no_design_meets_are_reported_with_the_closest(step_case, tmp_path, capsys):
    a_max, stroke = to_si(0.3, "g"), 2.5 * INCH
    code, doc = run_step(step_case, tmp_path, "--max-accel", "0.3g", "--max-stroke", "2.5in")
    assert code == 0  # an answer, not an error
    d = doc["design"]
    assert not d["feasible"] and d["stroke_met"]
    assert d["optimum"]["peak_accel"] > a_max
    # the closest design: the least common factor both limits must grow by, where the
    # two ratios meet
    factor, _ = step_case.best(lambda a, z: z / stroke - a / a_max, lambda a, z: a / a_max)
    c = d["closest"]
    mine = max(c["peak_accel"] / a_max, c["peak_stroke"] / stroke)
    assert mine == pytest.approx(factor, rel=2e-3)
    text = capsys.readouterr().out
    assert "no isolator of this form" in text and "closest to both" in text
    assert "over the limit" in text


def test_a_stroke_no_design_in_the_box_reaches_is_reported(step_case, tmp_path, capsys):
    code, doc = run_step(step_case, tmp_path, "--max-accel", "1g", "--max-stroke", "1.4in")
    assert code == 0
    d = doc["design"]
    assert not d["stroke_met"] and d["closest"] is not None
    least = step_case.peaks(np.ones(1), np.ones(1))[1][0]  # the stiffest corner of the box
    assert d["optimum"]["peak_stroke"] == pytest.approx(least, rel=1e-3)
    assert d["at_edge"] == {"k1": "high", "c1": "high"}
    assert "the least stroke any design in the box reaches" in capsys.readouterr().out


# --- bad input: one line, exit 2 --------------------------------------------------------


def one_line_error(capsys, argv: list[str]) -> str:
    assert analysis(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("analysis: error:"), err
    return err


def design_args(threat: str = "A", accel: str = "0.5g", stroke: str = "4in") -> list[str]:
    return ["design", "--threat", threat, "--max-accel", accel, "--max-stroke", stroke]


@pytest.mark.parametrize("accel, stroke, words", [
    ("6in", "4in", "not a unit of acceleration"),
    ("0.5g", "0.5g", "not a unit of length"),
    ("0.5", "4in", "give its unit"),
    ("0.5g", "0in", "positive"),
    ("fast", "4in", "not a number and a unit"),
])
def test_limits_of_the_wrong_unit_are_refused(capsys, accel, stroke, words):
    assert words in one_line_error(capsys, design_args(accel=accel, stroke=stroke))


@pytest.mark.parametrize("rows, words", [
    ([(0.000, 0.0), (0.001, 0.1), (0.002, 0.2), (0.010, 0.3), (0.011, 0.4)], "gap in time"),
    ([(0.000, 0.0), (0.001, 0.1), (0.003, 0.2), (0.002, 0.3), (0.004, 0.4)], "not increasing"),
])
def test_a_threat_record_with_gaps_or_time_going_back_is_refused(tmp_path, capsys, rows, words):
    f = tmp_path / "threat.csv"
    f.write_text("t [s],u [in]\n" + "".join(f"{t},{u}\n" for t, u in rows))
    assert words in one_line_error(capsys, design_args(threat=str(f)))


def test_a_threat_record_without_units_is_refused(tmp_path, capsys):
    f = tmp_path / "threat.csv"
    f.write_text("t,u\n" + "".join(f"{i * 1e-3},{i * 0.01}\n" for i in range(10)))
    assert "needs its unit" in one_line_error(capsys, design_args(threat=str(f)))


def test_a_fit_json_of_another_version_is_refused(tmp_path, capsys):
    block = model_json(linear_model()) | {"schema_version": SCHEMA_VERSION + 1}
    f = tmp_path / "fit.json"
    f.write_text(json.dumps({"identified_model": block}))
    err = one_line_error(capsys, design_args() + ["--from", str(f)])
    assert "schema version" in err and str(f) in err


@pytest.mark.parametrize("extra, words", [
    (["--free", "m"], "never free"),
    (["--free", "k9"], "not a constant of the model"),
    (["--free", "k1", "--bound", "c1=0:10"], "which is held"),
    (["--free", "k1", "--bound", "k1=5:1"], "low < high"),
    (["--threat", "nowhere.toml"], "no such profile file"),
])
def test_other_bad_options_are_refused(capsys, extra, words):
    assert words in one_line_error(capsys, design_args() + extra)


# --- the pieces ---------------------------------------------------------------------------


def test_pareto_front_keeps_the_non_dominated_points():
    accel = np.array([5.0, 3.0, 4.0, 1.0, 2.0, np.inf, 3.0])
    stroke = np.array([1.0, 2.0, 3.0, 5.0, 4.0, 0.1, 2.0])
    assert pareto_front(accel, stroke).tolist() == [0, 1, 4, 3]


def test_quantities_read_with_their_units():
    assert parse_quantity("0.5g", "acceleration", "--max-accel") == pytest.approx(4.903325)
    assert parse_quantity(" 6 in ", "length", "--max-stroke") == pytest.approx(0.1524)
    assert parse_quantity("150mm", "length", "--max-stroke") == pytest.approx(0.15)
    with pytest.raises(DataError, match="--max-stroke"):
        parse_quantity("6 furlongs", "length", "--max-stroke")
