"""The forces of Eq 10 with each extra effect's terms, and the effects' drawn parameters.

``spring`` is the restoring force outside the dead band, ``force`` the whole force
F(z, z') on the mass; both add the terms of the effects present in ``e`` (a dict from
effect name to its parameters; the thermal state T and the Bouc-Wen w they read
evolve in ``Plant.rhs_slip``). ``draw_effect`` draws one effect's parameters: its
size is ``mag`` times the clean run A's peak force, turned into a coefficient with the
run's peak displacement or velocity, and its shape parameters (a friction's smoothing
velocity, a preload's transition width, a thermal time constant, a Bouc-Wen yield, a
delay, a gain, a lag) come from ``rng``. The three sensor and servo effects
(sensor_delay, sensor_gain, servo_lag) add no force: the plant and the campaign apply
them.
"""

from __future__ import annotations

import math

import numpy as np

from bench.unseen.motion import RAMPS

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


def spring(k: dict, e: dict[str, dict], z: float) -> float:
    """Spring terms acting outside the dead band."""
    s = k["k1"] * z + k["k2"] * math.tanh(k["alpha"] * z)
    if "hardening" in e:
        s += e["hardening"]["k3"] * z * z * z
    if "asym_stiffness" in e and z > 0.0:
        s += e["asym_stiffness"]["k_a"] * z
    if "preload" in e:
        p = e["preload"]
        s += p["gamma"] * math.tanh(z / p["w"])
    return s


def force(k: dict, e: dict[str, dict], z: float, zd: float, inside: bool, T: float,
          w: float) -> float:
    """F(z, z') inside or outside the dead band, at thermal state T and Bouc-Wen w."""
    c1 = k["c1"]
    if "thermal" in e:
        c1 *= max(0.05, 1.0 - e["thermal"]["kappa"] * T)
    f = c1 * zd
    if not inside:
        f += spring(k, e, z) + k["c2"] * math.tanh(k["beta"] * zd)
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


def draw_effect(name: str, rng: np.random.Generator, mag: float, ref: dict, k: dict) -> dict:
    """One effect's parameters, sized by ``ref`` (peaks of the clean run A)."""
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
