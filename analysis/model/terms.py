"""The force terms an isolator model is built from: one registry, one formula each.

Each kind of term is `coef * basis(z, ż, ...; shape)`: a coefficient that enters
linearly (what appendix A's least squares solves for) times a basis function
whose shape constants (α, β, …) enter nonlinearly. `basis` below is the only
place a term's formula is written; the simulator kernel and the regressor
builder of the identification both call it, so the two can never disagree.

A kind may carry one internal state (hysteresis, fluid temperature): its rate
is `state_rate`, integrated by the simulator alongside z and ż.

To add a kind: give it a code and a branch in `basis` (and `state_rate` if it
has state), and a `TermKind` entry in `KINDS`. Then touch
analysis/simulate/kernel.py: numba's on-disk cache is keyed on the file that
holds each compiled function, so it does not see a change here alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from numba import njit

# codes used inside the compiled kernel
LINEAR_SPRING = 0
TANH_SPRING = 1
LINEAR_DAMPER = 2
TANH_DAMPER = 3
COULOMB = 4
PRELOAD = 5
CUBIC_SPRING = 6
QUADRATIC_DAMPER = 7
FORCE_OFFSET = 8
BOUC_WEN = 9
COMPRESSION_SPRING = 10
EXTENSION_DAMPER = 11
THERMAL_DAMPER = 12

MAX_SHAPE = 3  # shape constants per term in the kernel's parameter layout


# basis and state_rate are compiled into the cached code of simulate/kernel.py and
# identify/regressors.py, which numba checks against those files only: a change here
# bumps TERMS_REVISION in both
@njit(cache=True, inline="always")
def basis(kind: int, z: float, zd: float, sz: float, szd: float, s: float,
          a: float, b: float, c: float) -> float:
    """Basis function of a term kind, N per unit coefficient.

    z, zd: relative displacement (m) and velocity (m/s); sz, szd: the sign of
    each as the integrator holds it (±1, or 0 when at rest); s: the term's
    internal state; a, b, c: shape constants in SI.
    """
    if kind == LINEAR_SPRING:
        return z
    if kind == TANH_SPRING:
        return math.tanh(a * z)
    if kind == LINEAR_DAMPER:
        return zd
    if kind == TANH_DAMPER:
        return math.tanh(a * zd)
    if kind == COULOMB:
        # smoothed where the seals' friction builds up over a velocity a (a Stribeck or
        # bristle layer, an oil film): a = 0 is the report's step at ż = 0
        return math.tanh(zd / a) if a > 0.0 else szd
    if kind == PRELOAD:
        return sz
    if kind == CUBIC_SPRING:
        return z * z * z
    if kind == QUADRATIC_DAMPER:
        return zd * abs(zd)
    if kind == FORCE_OFFSET:
        return 1.0
    if kind == BOUC_WEN:
        return s
    if kind == COMPRESSION_SPRING:
        return max(0.0, z)
    if kind == EXTENSION_DAMPER:
        return max(0.0, zd)
    if kind == THERMAL_DAMPER:
        # the fluid thins to its hot viscosity and no further: past θ_max (c > 0) the
        # drift stops, so c1 + c_T θ never crosses zero into a damper that feeds energy in
        return (min(s, c) if c > 0.0 else s) * zd
    return math.nan


@njit(cache=True, inline="always")
def state_rate(kind: int, z: float, zd: float, s: float, coef: float,
               a: float, b: float, c: float) -> float:
    """Time derivative of a term's internal state (0 for stateless kinds)."""
    if kind == BOUC_WEN:
        # Bouc–Wen: r' = ż − a|ż| |r|^(n−1) r − b ż |r|^n  (r in m, a and b in 1/m^n, n ≥ 1);
        # r saturates at (a + b)^(−1/n), the yield displacement
        if c == 1.0:
            return zd - a * abs(zd) * s - b * zd * abs(s)
        rn = abs(s) ** c
        return zd - a * abs(zd) * (rn if s > 0.0 else -rn) - b * zd * rn
    if kind == THERMAL_DAMPER:
        # fluid temperature rise θ (K): heated by the viscous power a ż² (a = c/C_th, in
        # K s/m²), cooled through the casing with time constant b (s)
        return a * zd * zd - (s / b if b > 0.0 else 0.0)
    return 0.0


@dataclass(frozen=True)
class TermKind:
    """What a kind of term means, and the units of its numbers (SI)."""

    name: str
    code: int
    formula: str
    coef_unit: str
    shape_names: tuple[str, ...] = ()
    shape_units: tuple[str, ...] = ()
    gated_by_dead_band: bool = False  # inactive for |z| <= δ, as the report's spring terms
    switches_on: str = ""  # "z" or "zd": the basis jumps where that variable changes sign
    has_state: bool = False
    meaning: str = ""
    # shape constants a model written before they existed may lack, with the value that
    # reads it as it was meant (a Bouc–Wen loop written with a and b only had n = 1)
    optional_shapes: tuple[tuple[str, float], ...] = ()

    def completed_shape(self, given: dict[str, float]) -> dict[str, float]:
        """`given` shape constants by name, with the optional ones it lacks at theirs."""
        return {**{n: v for n, v in self.optional_shapes if n not in given}, **given}


KINDS: dict[str, TermKind] = {
    k.name: k
    for k in (
        TermKind("linear_spring", LINEAR_SPRING, "k z", "N/m", gated_by_dead_band=True,
                 meaning="linear stiffness of the compressed fluid"),
        TermKind("tanh_spring", TANH_SPRING, "k tanh(α z)", "N", ("alpha",), ("1/m",),
                 gated_by_dead_band=True, meaning="softening spring (Eq 8)"),
        TermKind("linear_damper", LINEAR_DAMPER, "c ż", "N/(m/s)",
                 meaning="viscous damping, active everywhere including the dead band"),
        TermKind("tanh_damper", TANH_DAMPER, "c tanh(β ż)", "N", ("beta",), ("s/m",),
                 gated_by_dead_band=True, meaning="softening damping, orifice flow (Eq 9)"),
        TermKind("coulomb", COULOMB, "c tanh(ż/v_s), c sgn(ż) at v_s = 0", "N", ("v_s",),
                 ("m/s",), switches_on="zd", optional_shapes=(("v_s", 0.0),),
                 meaning="dry friction of the seals, built up over v_s"),
        TermKind("preload", PRELOAD, "γ sgn(z)", "N", gated_by_dead_band=True, switches_on="z",
                 meaning="fluid preload: a force step at the edge of the dead band"),
        TermKind("cubic_spring", CUBIC_SPRING, "k z³", "N/m^3", gated_by_dead_band=True,
                 meaning="hardening spring"),
        TermKind("quadratic_damper", QUADRATIC_DAMPER, "c ż|ż|", "N/(m/s)^2",
                 meaning="turbulent orifice flow"),
        TermKind("force_offset", FORCE_OFFSET, "F₀", "N", meaning="constant force offset"),
        TermKind("bouc_wen", BOUC_WEN, "k r, r' = ż − a|ż||r|ⁿ⁻¹r − b ż|r|ⁿ", "N/m",
                 ("a", "b", "n"), ("1/m^n", "1/m^n", "1"), has_state=True,
                 meaning="rate-independent hysteresis", optional_shapes=(("n", 1.0),)),
        TermKind("compression_spring", COMPRESSION_SPRING, "k max(z, 0)", "N/m",
                 gated_by_dead_band=True,
                 meaning="extra stiffness in one direction: the rod displaces fluid only "
                         "when the isolator closes"),
        TermKind("extension_damper", EXTENSION_DAMPER, "c max(ż, 0)", "N/(m/s)",
                 meaning="extra damping in one direction: a check valve in the piston head"),
        TermKind("thermal_damper", THERMAL_DAMPER, "c min(θ, θ_max) ż, θ' = a ż² − θ/b",
                 "N/(m/s)/K", ("heating", "tau", "theta_max"), ("K s/m^2", "s", "K"),
                 has_state=True, optional_shapes=(("theta_max", 0.0),),
                 meaning="viscosity falls as the fluid heats from the energy the damper "
                         "dissipates (c < 0): damping that drifts within and between runs"),
    )
}


def kind(name: str) -> TermKind:
    """The TermKind called `name`; KeyError lists the known kinds."""
    try:
        return KINDS[name]
    except KeyError:
        raise KeyError(f"unknown term kind {name!r} (known: {', '.join(KINDS)})") from None
