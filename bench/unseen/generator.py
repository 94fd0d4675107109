"""An independent generator of identification campaigns (after CERL TR M-226, Eq 10).

Nothing here comes from the project's packages (``analysis``, ``sim``, ``rig``): the
model, the base motions, the extra effects, the integrator and the sensor model are
written again from the report, so the project's identification can be tested on
data it did not make. The generator's modules in ``bench.unseen``:

- ``motion``: the ramp shapes and the table's commanded motion (rest, ramp, hold,
  ramp back, rest; RAMPS, REST, HOLD, STEP);
- ``effects``: the force F(z, z') with each extra effect's terms, EFFECTS, and the
  draw of an effect's parameters;
- ``plant``: the hybrid model (dead band, static friction) with its right-hand sides,
  events and initial state, and MASS;
- ``integrate``: its integration on ``scipy.integrate.solve_ivp``, restarted at every
  event;
- this module: a campaign's draw (constants ±30 % around Table 1, ramp shape, record
  length, noise, quantisation, effects), its three runs with the sensor effects and
  the noise on the 1 kHz grid, and its files.

    python -m bench.unseen.generator --seed 3 --effect coulomb --out /tmp/c3
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.unseen.effects import EFFECTS, draw_effect
from bench.unseen.integrate import simulate
from bench.unseen.motion import HOLD, RAMPS, REST, SHAPES, STEP, Profile
from bench.unseen.plant import MASS, Plant

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
            drawn[name] = draw_effect(name, rng, mag, ref, k)
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
