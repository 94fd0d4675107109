"""The force-driven model and its library of effects, each a regressor linear in its parameter.

Sign convention: the measured force F drives the mass and every term resists it,

    F = m q̈ + Σ θ_k φ_k(q, q̇)        i.e.  m q̈ = F − Σ θ_k φ_k,

the convention of the EMPS benchmark (τ = M q̈ + Fv q̇ + Fc sgn(q̇) + offset), so
its published numbers compare directly. A positive θ is a force against the
motion (friction, damping) or towards q = 0 (stiffness); `force_offset` F₀ is
the constant force the drive must supply to hold the mass still, i.e. an
external force −F₀ (a tilted track, a cable, a zero error of the force sensor).

Base terms are the mass (identified unless given) and viscous friction, plus a
linear spring when the system has a restoring force. The candidates carry the
names the isolator loop uses (analysis/loop/candidates.py), so JSON
`effects_added` reads the same for both layouts. Direction-dependent effects are
written as one extra term for one direction, as the isolator's terms are:
`asymmetric_damping` = c_ext max(q̇, 0), so the viscous coefficient is c + c_ext
for q̇ > 0 and c for q̇ < 0. With `coulomb_friction` and `force_offset` in the
model this spans exactly EMPS's direction-dependent friction (Fv±, Fc±): a
Coulomb level that differs by direction, Fc± = Fc ± F₀, is a symmetric Coulomb
term plus an offset, because (1 ± sgn q̇)/2 are combinations of 1 and sgn q̇.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

MASS = "mass"
VISCOUS = "viscous"
STIFFNESS = "stiffness"


@dataclass(frozen=True)
class Term:
    """One term θ φ(q, q̇, q̈) of the force balance."""

    name: str  # the effect's name (JSON `effects_added`) or a base term's
    parameter: str  # the parameter's name in tables and JSON
    unit: str  # of the parameter, SI
    formula: str
    explanation: str
    regressor: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
    code: int  # the simulator's switch (analysis.force_driven.simulate)


def _sign(v: np.ndarray) -> np.ndarray:
    # unsmoothed, as the EMPS reference model: the filtered velocity is rarely exactly 0
    return np.sign(v)


BASE: dict[str, Term] = {
    t.name: t
    for t in (
        Term(MASS, "m", "kg", "m q̈", "inertia of the moving mass",
             lambda q, v, a: a, -1),
        Term(VISCOUS, "c", "N/(m/s)", "c q̇", "viscous friction (lubricant, back-EMF, air)",
             lambda q, v, a: v, 0),
        Term(STIFFNESS, "k", "N/m", "k q", "linear spring towards q = 0",
             lambda q, v, a: q, 1),
    )
}

CANDIDATES: dict[str, Term] = {
    t.name: t
    for t in (
        Term("coulomb_friction", "Fc", "N", "Fc sgn(q̇)",
             "dry friction: a constant force against the motion, a step at q̇ = 0",
             lambda q, v, a: _sign(v), 2),
        Term("force_offset", "F0", "N", "F₀",
             "a constant force: a tilted track, a cable, a zero error of the force sensor",
             lambda q, v, a: np.ones_like(q), 3),
        Term("asymmetric_damping", "c_ext", "N/(m/s)", "c_ext max(q̇, 0)",
             "direction-dependent friction: a different viscous slope for q̇ > 0 "
             "(worn screw, seal lip, check valve)",
             lambda q, v, a: np.maximum(v, 0.0), 4),
        Term("quadratic_damping", "c_q", "N/(m/s)^2", "c_q q̇|q̇|",
             "friction that grows (or saturates, c_q < 0) with speed: turbulent flow, "
             "a curved friction-velocity law",
             lambda q, v, a: v * np.abs(v), 5),
        Term("cubic_stiffness", "k3", "N/m^3", "k3 q³",
             "hardening (k3 > 0) or softening spring, symmetric about q = 0",
             lambda q, v, a: q**3, 6),
        Term("asymmetric_stiffness", "k_pos", "N/m", "k_pos max(q, 0)",
             "a spring stiffer on one side of q = 0 than the other",
             lambda q, v, a: np.maximum(q, 0.0), 7),
    )
}

TERMS: dict[str, Term] = {**BASE, **CANDIDATES}


def term(name: str) -> Term:
    """The base term or candidate called `name`; KeyError lists the known ones."""
    try:
        return TERMS[name]
    except KeyError:
        raise KeyError(f"unknown term {name!r} (known: {', '.join(TERMS)})") from None


def base_terms(mass_known: bool, stiffness: bool) -> list[str]:
    """The terms every force-driven fit starts from."""
    names = [] if mass_known else [MASS]
    names.append(VISCOUS)
    if stiffness:
        names.append(STIFFNESS)
    return names
