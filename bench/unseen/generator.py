"""An independent generator of identification campaigns (after CERL TR M-226, Eq 10).

Nothing here comes from the project's packages (``analysis``, ``sim``, ``rig``): the
model, the base motions, the extra effects, the integrator and the sensor model are
written again from the report, so the project's identification can be tested on
data it did not make.

Model, in relative coordinates z = x - u (u table, x mass, both absolute)::

    m z'' = -m u'' - F(z, z')
    F = c1 z'                                                    (|z| <= delta)
    F = k1 z + k2 tanh(alpha z) + c1 z' + c2 tanh(beta z')       (|z| >  delta)

plus static friction: while stuck (z' = 0) the mass moves with the table until
|m u'' + F(z, 0)| exceeds the breakaway force F_b; sliding stops when |z'| < eps and
the force is within breakaway. At a dead-band edge the spring force jumps; a mass
resting against the edge is held there (the force is set-valued at the edge) the same
way as by friction, which keeps the integration free of chattering.

Every dead-band entry/exit and every stick/slip transition is an event of
``scipy.integrate.solve_ivp``; the integration restarts at each one in the new mode.

    python bench/unseen/generator.py --seed 3 --effect coulomb --out /tmp/c3
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

LB = 4.44822  # N
IN = 0.0254  # m

MASS = 2721.55  # kg (6000 lb)
STEP = 5.5 * IN  # 0.1397 m
FS = 1000.0  # Hz

# Table 1 averages in SI: the centre of each campaign's draw.
CENTRE = {
    "k1": 70926.0,
    "k2": 1115.0,
    "c1": 6063.0,
    "c2": 2315.0,
    "alpha": 78.74,
    "beta": 78.74,
    "delta": 0.019558,
    "eps": 0.01524,
    "F_b": 91.63,
}

RAMPS = {"A": 0.20, "B": 0.16, "C": 0.12}
REST = 0.1
HOLD = 1.3

EFFECTS = (
    "coulomb",
    "orifice",
    "hardening",
    "asym_stiffness",
    "asym_damping",
    "preload",
    "thermal",
    "bouc_wen",
    "sensor_delay",
    "sensor_gain",
    "force_offset",
    "servo_lag",
)


# --------------------------------------------------------------------------- ramps
def _cycloidal(tau: float) -> tuple[float, float, float]:
    w = 2.0 * math.pi
    return (tau - math.sin(w * tau) / w, 1.0 - math.cos(w * tau), w * math.sin(w * tau))


def _half_cosine(tau: float) -> tuple[float, float, float]:
    p = math.pi
    return ((1.0 - math.cos(p * tau)) / 2.0, p * math.sin(p * tau) / 2.0,
            p * p * math.cos(p * tau) / 2.0)


def _min_jerk(tau: float) -> tuple[float, float, float]:
    t2, t3 = tau * tau, tau * tau * tau
    return (
        10 * t3 - 15 * t3 * tau + 6 * t3 * t2,
        30 * t2 - 60 * t3 + 30 * t2 * t2,
        60 * tau - 180 * t2 + 120 * t3,
    )


SHAPES: dict[str, Callable[[float], tuple[float, float, float]]] = {
    "cycloidal": _cycloidal,
    "half_cosine": _half_cosine,
    "min_jerk": _min_jerk,
}


def shape(name: str, tau: np.ndarray | float) -> np.ndarray:
    """The ramp shape s(tau), tau in [0, 1] -> [0, 1] (clipped outside)."""
    f = SHAPES[name]
    return np.array([f(min(1.0, max(0.0, float(v))))[0] for v in np.atleast_1d(tau)])


class Profile:
    """Commanded table motion: rest, ramp up STEP, hold, ramp back, rest."""

    def __init__(self, shape_name: str, ramp: float, rest: float = REST, hold: float = HOLD):
        self.f = SHAPES[shape_name]
        self.ramp = ramp
        self.t1 = rest
        self.t2 = rest + ramp
        self.t3 = rest + ramp + hold
        self.t4 = rest + 2 * ramp + hold
        self.breaks = (self.t1, self.t2, self.t3, self.t4)

    def piece_at(self, t: float) -> int:
        """Which piece (rest, up, hold, down, rest) holds t; right-continuous at breaks."""
        return sum(t >= b for b in self.breaks)

    def __call__(self, t: float, piece: int | None = None) -> tuple[float, float, float]:
        """(u, u', u'') of the command at t, on the given piece (u'' jumps at the breaks
        of a half-cosine ramp: an integration segment keeps its own piece to its end)."""
        r = self.ramp
        if piece is None:
            piece = self.piece_at(t)
        if piece == 1:
            s, sd, sdd = self.f(min(1.0, max(0.0, (t - self.t1) / r)))
            return STEP * s, STEP * sd / r, STEP * sdd / (r * r)
        if piece == 2:
            return STEP, 0.0, 0.0
        if piece == 3:
            s, sd, sdd = self.f(min(1.0, max(0.0, (t - self.t3) / r)))
            return STEP * (1.0 - s), -STEP * sd / r, -STEP * sdd / (r * r)
        return 0.0, 0.0, 0.0


# --------------------------------------------------------------------------- plant
class Plant:
    """Eq 10 with a dead band, static friction and the drawn effects.

    State y = [z, z', u_lag, T, w]: relative displacement and velocity, the lagged
    table (servo lag only), the thermal state (thermal only), Bouc-Wen w (bouc_wen only).
    """

    def __init__(self, k: dict, effects: dict[str, dict], profile: Profile):
        self.k = k
        self.e = effects
        self.p = profile
        self.m = MASS
        lag = effects.get("servo_lag")
        self.tau_lag = lag["tau"] if lag else 0.0
        self.piece = 0  # the profile piece of the current integration segment

    # table motion -------------------------------------------------------------
    def table(self, t: float, y) -> tuple[float, float, float]:
        """(u, u', u'') of the table itself (the command, or its first-order lag)."""
        if self.tau_lag:
            uc, ucd, _ = self.p(t, self.piece)
            ul = y[2]
            uld = (uc - ul) / self.tau_lag
            return ul, uld, (ucd - uld) / self.tau_lag
        return self.p(t, self.piece)

    # forces -------------------------------------------------------------------
    def spring(self, z: float) -> float:
        """Spring terms acting outside the dead band."""
        k, e = self.k, self.e
        s = k["k1"] * z + k["k2"] * math.tanh(k["alpha"] * z)
        if "hardening" in e:
            s += e["hardening"]["k3"] * z * z * z
        if "asym_stiffness" in e and z > 0.0:
            s += e["asym_stiffness"]["k_a"] * z
        if "preload" in e:
            p = e["preload"]
            s += p["gamma"] * math.tanh(z / p["w"])
        return s

    def force(self, z: float, zd: float, inside: bool, T: float, w: float) -> float:
        k, e = self.k, self.e
        c1 = k["c1"]
        if "thermal" in e:
            c1 *= max(0.05, 1.0 - e["thermal"]["kappa"] * T)
        f = c1 * zd
        if not inside:
            f += self.spring(z) + k["c2"] * math.tanh(k["beta"] * zd)
        if "coulomb" in e:
            f += e["coulomb"]["F_c"] * math.tanh(zd / e["coulomb"]["v_s"])
        if "orifice" in e:
            f += e["orifice"]["c_q"] * zd * abs(zd)
        if "asym_damping" in e and zd > 0.0:
            f += e["asym_damping"]["c_a"] * zd
        if "bouc_wen" in e:
            f += e["bouc_wen"]["k_h"] * w
        if "force_offset" in e:
            f += e["force_offset"]["F0"]
        return f

    # right-hand sides ----------------------------------------------------------
    def rhs_slip(self, inside: bool):
        e, m, k = self.e, self.m, self.k
        th = e.get("thermal")
        bw = e.get("bouc_wen")

        def f(t, y):
            z, zd, _, T, w = y
            _, uld, udd = self.table(t, y)
            F = self.force(z, zd, inside, T, w)
            Td = (k["c1"] * zd * zd / th["C"] - T) / th["tau_T"] if th else 0.0
            if bw:
                aw = abs(w)
                wn1 = aw ** (bw["n"] - 1.0) if aw > 0.0 else (1.0 if bw["n"] == 1.0 else 0.0)
                wd = zd - bw["beta_h"] * abs(zd) * wn1 * w - bw["gamma_h"] * zd * wn1 * aw
            else:
                wd = 0.0
            return [zd, -udd - F / m, uld, Td, wd]

        return f

    def rhs_stuck(self):
        th = self.e.get("thermal")

        def f(t, y):
            _, uld, _ = self.table(t, y)
            Td = -y[3] / th["tau_T"] if th else 0.0
            return [0.0, 0.0, uld, Td, 0.0]

        return f

    def hold_interval(self, t: float, y, edge: int, inside: bool) -> tuple[float, float]:
        """The range of the force the table must supply to hold the mass (z' = 0)."""
        z, _, _, T, w = y
        _, _, udd = self.table(t, y)
        mu = self.m * udd
        if edge:
            a = mu + self.force(z, 0.0, True, T, w)
            b = mu + self.force(z, 0.0, False, T, w)
            return (a, b) if a <= b else (b, a)
        a = mu + self.force(z, 0.0, inside, T, w)
        return a, a

    # events ------------------------------------------------------------------
    def ev_deadband(self, inside: bool):
        d = self.k["delta"]

        def g(t, y):
            return abs(y[0]) - d

        g.terminal = True
        g.direction = 1.0 if inside else -1.0
        return g

    def ev_stick(self, inside: bool):
        k, m = self.k, self.m

        def g(t, y):
            z, zd, _, T, w = y
            _, _, udd = self.table(t, y)
            return max(abs(zd) - k["eps"],
                       abs(m * udd + self.force(z, 0.0, inside, T, w)) - k["F_b"])

        g.terminal = True
        g.direction = -1.0
        return g

    def ev_breakaway(self, edge: int, inside: bool):
        fb = self.k["F_b"]

        def g(t, y):
            a, b = self.hold_interval(t, y, edge, inside)
            return max(a - fb, -b - fb)

        g.terminal = True
        g.direction = 1.0
        return g

    # initial state -------------------------------------------------------------
    def initial(self) -> tuple[list[float], int, bool]:
        """Rest: z = 0 unless a force offset pushes the mass to an edge or beyond."""
        d, fb = self.k["delta"], self.k["F_b"]
        F0 = self.e.get("force_offset", {}).get("F0", 0.0)
        if abs(F0) <= fb:
            return [0.0, 0.0, 0.0, 0.0, 0.0], 0, True
        sgn = -1.0 if F0 > 0 else 1.0
        z_edge = sgn * d
        if abs(self.spring(z_edge)) >= abs(F0):
            return [z_edge, 0.0, 0.0, 0.0, 0.0], int(sgn), True
        hi = z_edge
        while abs(self.spring(hi)) < abs(F0):
            hi *= 2.0
        z = brentq(lambda v: self.spring(v) + F0, z_edge, hi, xtol=1e-14)
        return [z, 0.0, 0.0, 0.0, 0.0], 0, False


@dataclass
class Trajectory:
    """Dense solution over the whole record: piecewise solve_ivp segments."""

    starts: list[float]
    sols: list

    def __call__(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        out = np.empty((5, t.size))
        idx = np.clip(np.searchsorted(self.starts, t, side="right") - 1, 0, len(self.sols) - 1)
        for i in np.unique(idx):
            sel = idx == i
            out[:, sel] = self.sols[i](t[sel])
        return out


def simulate(plant: Plant, t_end: float, max_events: int = 20000,
             dwell: float = 5e-4) -> Trajectory:
    """Integrate the hybrid model from rest to t_end, restarting at every event.

    After a breakaway the mass slides for at least ``dwell`` seconds before it may stick
    again: with a stiff element in the load path (Bouc-Wen) the force otherwise sits on
    the breakaway threshold and stick/slip would alternate without time advancing.
    """
    opts = {"method": "RK45", "rtol": 1e-8, "atol": 1e-10, "max_step": 5e-4, "dense_output": True}
    k = plant.k
    y, edge, inside = plant.initial()
    y = np.asarray(y, dtype=float)
    stuck = True
    breaks = [b for b in plant.p.breaks if 0.0 < b < t_end] + [t_end]
    t = 0.0
    starts: list[float] = []
    sols: list = []
    stalled = 0
    no_stick_until = -1.0
    for _ in range(max_events):
        if t >= t_end:
            break
        t_stop = next(b for b in breaks if b > t + 1e-12)
        plant.piece = plant.p.piece_at(t + 1e-12)
        if stuck:
            # at the start of a stuck segment: does the mass break away at once? (with a
            # small margin: a stick event leaves the force at the threshold to rounding)
            a, b = plant.hold_interval(t, y, edge, inside)
            fb = k["F_b"] * (1.0 + 1e-7)
            if a > fb or b < -fb:
                stuck, inside = False, _region_after_breakaway(y[0], edge, inside, a > fb)
                edge, no_stick_until = 0, t + dwell
                continue
            fun, events = plant.rhs_stuck(), [plant.ev_breakaway(edge, inside)]
        elif t < no_stick_until:
            t_stop = min(t_stop, no_stick_until)
            fun, events = plant.rhs_slip(inside), [plant.ev_deadband(inside)]
        else:
            fun = plant.rhs_slip(inside)
            events = [plant.ev_deadband(inside), plant.ev_stick(inside)]
        sol = solve_ivp(fun, (t, t_stop), y, events=events, **opts)
        if sol.status == -1:
            raise RuntimeError(f"integration failed at t={t:.6f}: {sol.message}")
        starts.append(t)
        sols.append(sol.sol)
        t_new, y = float(sol.t[-1]), sol.y[:, -1].copy()
        stalled = stalled + 1 if t_new - t < 1e-10 else 0
        if stalled > 50:
            raise RuntimeError(f"no progress at t={t:.6f} (mode stuck={stuck}, inside={inside})")
        t = t_new
        if sol.status != 1:
            continue  # reached a breakpoint: same mode
        if stuck:  # breakaway
            a, b = plant.hold_interval(t, y, edge, inside)
            push_neg = (a - k["F_b"]) >= (-b - k["F_b"])
            inside = _region_after_breakaway(y[0], edge, inside, push_neg)
            stuck, edge, no_stick_until = False, 0, t + dwell
        elif sol.t_events[0].size:  # dead-band edge
            y[0] = math.copysign(k["delta"], y[0])
            sgn = 1 if y[0] > 0 else -1
            a, b = plant.hold_interval(t, y, sgn, inside)
            if abs(y[1]) < k["eps"] and a <= k["F_b"] and b >= -k["F_b"]:
                stuck, edge, y[1] = True, sgn, 0.0
            else:
                inside = not inside
        else:  # stick
            stuck, edge, y[1] = True, 0, 0.0
    else:
        raise RuntimeError(f"more than {max_events} events before t={t:.6f}")
    return Trajectory(starts, sols)


def _region_after_breakaway(z: float, edge: int, inside: bool, push_neg: bool) -> bool:
    """Which side of the dead band the mass moves into when it breaks away."""
    if not edge:
        return inside
    moving = -1 if push_neg else 1
    return moving * edge < 0  # towards the centre: inside


# --------------------------------------------------------------------------- campaign
@dataclass
class Campaign:
    seed: int
    constants: dict
    effects: list[dict]
    noise: float
    runs: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]
    meta: dict = field(default_factory=dict)


def _run(k: dict, effects: dict[str, dict], shape_name: str, run: str, length: float):
    """Noise-free (t, u, x, z, z') of one run on the 1 kHz grid."""
    prof = Profile(shape_name, RAMPS[run])
    plant = Plant(k, effects, prof)
    traj = simulate(plant, length)
    n = round(length * FS)
    t = np.arange(n) / FS
    d = effects.get("sensor_delay", {}).get("d", 0.0)
    Y = traj(t)
    if plant.tau_lag:
        u = Y[2]
    else:
        u = np.array([prof(v)[0] for v in t])
    x = Y[0] + u
    if d:
        td = t - d
        Yd = traj(np.maximum(td, 0.0))
        ud = Yd[2] if plant.tau_lag else np.array([prof(v)[0] for v in td])
        x = np.where(td >= 0.0, Yd[0] + ud, x[0])
    g = effects.get("sensor_gain", {}).get("g", 0.0)
    return t, u, (1.0 + g) * x, Y[0], Y[1]


def _reference(k: dict, shape_name: str, length: float) -> dict:
    """Peaks of the clean run A: the scale of each effect's magnitude."""
    prof = Profile(shape_name, RAMPS["A"])
    plant = Plant(k, {}, prof)
    traj = simulate(plant, length)
    t = np.arange(round(length * FS)) / FS
    Y = traj(t)
    F = np.array(
        [plant.force(z, zd, abs(z) <= k["delta"], 0.0, 0.0) for z, zd in zip(Y[0], Y[1])]
    )
    return {
        "F_ref": float(np.max(np.abs(F))),
        "z_peak": float(np.max(np.abs(Y[0]))),
        "v_peak": float(np.max(np.abs(Y[1]))),
    }


def _draw_effect(name: str, rng: np.random.Generator, mag: float, ref: dict, k: dict) -> dict:
    F = mag * ref["F_ref"]
    zp, vp = max(ref["z_peak"], k["delta"]), max(ref["v_peak"], 1e-3)
    if name == "coulomb":
        return {"F_c": F, "v_s": float(rng.uniform(1e-3, 10e-3))}
    if name == "orifice":
        return {"c_q": F / vp**2}
    if name == "hardening":
        return {"k3": F / zp**3}
    if name == "asym_stiffness":
        return {"k_a": F / zp}
    if name == "asym_damping":
        return {"c_a": F / vp}
    if name == "preload":
        return {"gamma": F, "w": float(rng.uniform(0.5e-3, 3e-3))}
    if name == "thermal":
        tau_T = float(rng.uniform(0.5, 5.0))
        p_ref = k["c1"] * vp**2
        # heating scale: one ramp's dissipation lifts T by about 1/heat
        heat = float(rng.uniform(0.5, 2.0))
        return {
            "kappa": min(0.9, F / (k["c1"] * vp)),
            "tau_T": tau_T,
            "C": p_ref * RAMPS["A"] / 2.0 / tau_T * heat,
        }
    if name == "bouc_wen":
        n = float(rng.uniform(1.0, 2.0))
        y = float(rng.uniform(1e-3, 5e-3))
        r = float(rng.uniform(0.5, 0.9))
        return {"k_h": F / y, "n": n, "y": y, "beta_h": r / y**n, "gamma_h": (1 - r) / y**n}
    if name == "sensor_delay":
        return {"d": float(rng.uniform(1e-3, 5e-3))}
    if name == "sensor_gain":
        return {"g": float(rng.uniform(0.02, 0.08))}
    if name == "force_offset":
        return {"F0": F * float(rng.choice([-1.0, 1.0]))}
    if name == "servo_lag":
        return {"tau": float(rng.uniform(3e-3, 8e-3))}
    raise ValueError(f"unknown effect {name!r}; known: {', '.join(EFFECTS)}")


def make_campaign(seed: int, effects: Sequence[str] = (),
                  magnitude: float | None = None) -> Campaign:
    """Draw one campaign (runs A, B, C) from numpy.random.default_rng(seed)."""
    rng = np.random.default_rng(seed)
    # base draws first, in a fixed order: a seed gives the same plant whatever the effects
    k = {name: float(v * rng.uniform(0.7, 1.3)) for name, v in CENTRE.items()}
    shape_name = str(rng.choice(sorted(SHAPES)))
    length = float(np.round(rng.uniform(3.5, 5.0), 3))
    noise = float(rng.uniform(0.5, 4.0) * 25.4e-6)
    quantise = bool(rng.random() < 0.5)
    noise_seed = int(rng.integers(2**63))
    mag = float(rng.uniform(0.03, 0.30)) if magnitude is None else float(magnitude)

    drawn: dict[str, dict] = {}
    effect_list: list[dict] = []
    if effects:
        ref = _reference(k, shape_name, length)
        for name in effects:
            if name in drawn:
                continue
            drawn[name] = _draw_effect(name, rng, mag, ref, k)
            effect_list.append({"name": name, "magnitude": mag, **drawn[name]})

    nrng = np.random.default_rng(noise_seed)
    runs = {}
    for run in ("A", "B", "C"):
        t, u, x, _, _ = _run(k, drawn, shape_name, run, length)
        u = u + nrng.normal(0.0, noise, t.size)
        x = x + nrng.normal(0.0, noise, t.size)
        if quantise:
            u, x = np.round(u * 1e6) / 1e6, np.round(x * 1e6) / 1e6
        runs[run] = (t, u, x)
    meta = {
        "shape": shape_name,
        "length": length,
        "rest": REST,
        "hold": HOLD,
        "ramps": dict(RAMPS),
        "step": STEP,
        "mass": MASS,
        "quantise": 1e-6 if quantise else None,
    }
    return Campaign(seed, k, effect_list, noise, runs, meta)


def write_campaign(c: Campaign, out: Path) -> None:
    """A.csv, B.csv, C.csv (t,u,x) and truth.json in out."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for run, (t, u, x) in c.runs.items():
        lines = ["t,u,x"]
        lines += [f"{a:.9g},{b:.9g},{d:.9g}" for a, b, d in zip(t, u, x)]
        (out / f"{run}.csv").write_text("\n".join(lines) + "\n")
    truth = {
        "seed": c.seed,
        "constants": c.constants,
        "effects": c.effects,
        "noise": c.noise,
        "profile": c.meta,
    }
    (out / "truth.json").write_text(json.dumps(truth, indent=2, sort_keys=True) + "\n")


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--effect", action="append", default=[], choices=EFFECTS)
    ap.add_argument("--magnitude", type=float, default=None, help="fraction, e.g. 0.1")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    write_campaign(make_campaign(a.seed, a.effect, a.magnitude), a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
