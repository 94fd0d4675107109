"""The library of physical effects the loop may add to a fitted isolator model.

Each candidate is one effect with a physical reason, the parameter it adds (a
force term of `analysis.model.terms`, or a parameter of the mass sensor's
output map) and a *typical size*: the magnitude at which the effect would be
just worth naming for a 6000 lb mass on a liquid spring. The typical size
scales the search, sets the finite-difference step of the score test, and is
what keeps look-alikes apart: a candidate is sized by its physics, not free to
take whatever value soaks up the residual.

The names are the product's vocabulary for effects (JSON `effects_added`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from analysis.model.isolator import IsolatorModel, Term
from analysis.model.terms import kind

SENSOR_GAIN = "sensor_gain"
SENSOR_DELAY = "sensor_delay"
SENSOR_PARAMETERS = (SENSOR_GAIN, SENSOR_DELAY)
# The fluid heats by `a ż²` and cools with `tau`: a = c1/C_th with ~7.5 kJ/K of fluid and
# casing; tau, minutes for a warm casing. Only a's product with c_T is seen, so a is held;
# tau is chosen from THERMAL_SHAPES by equation error and refitted with c_T. A drift may
# stop at θ_max (0: it does not): the damping thins to the hot fluid's and no further;
# equation error places θ_max at fractions of the peak θ of the measured motion (`naming`).
THERMAL_SHAPE = (0.8, 600.0, 0.0)  # K s/m², s, K (no limit)
HYSTERESIS_SHAPE = (60.0, 20.0, 1.0)  # Bouc–Wen a, b in 1/m, n = 1: r saturates at 12.5 mm
# What equation error tries: a small damper's oil cools in seconds, not minutes (a cooling
# time of seconds drifts the damping within one run), and a seal's hysteresis yields within
# millimetres; a/(a+b) kept at the default's 0.75, a loop's corners sharp (n = 1) or round
# (n = 2: a seal that yields gradually); n is chosen, not refitted: with a → 0 and n = 2,
# r' = ż(1 − b r²) makes r = tanh(√b z)/√b, Eq 10's own k2 tanh(αz), and a refit with n
# free walked there (an unseen loop refused as a look-alike of α at 1.000, a dry friction
# named in its place). Not shorter: cooled within half a
# second, θ follows ż² and the drift is a cubic damping, whose column outscored a sensor
# delay's on an unseen campaign. The yields a factor of two apart down to 1.25 mm: with
# 2.5 mm the least, unseen loops that yield at 1.2–1.8 mm were named a dry friction
# (1.44 mm) or refitted above the noise (Bouc–Wen 804, 1.75 mm: 2.26 x; with 1.25 mm,
# 1.09 x). Below a millimetre a loop is a dry friction's twin
THERMAL_SHAPES = tuple((THERMAL_SHAPE[0], b, 0.0) for b in (1.5, 5.0, THERMAL_SHAPE[1]))
HYSTERESIS_SHAPES = tuple((0.75 / y**n, 0.25 / y**n, n) for n in (1.0, 2.0)
                          for y in (1.25e-3, 2.5e-3, 5e-3, 12.5e-3))
HYSTERETIC_FORCE = 100.0  # N at the yield: as large as the report's breakaway force
# A seal's friction builds up over a velocity v_s (a bristle layer, an oil film, Stribeck):
# the report's step (v_s = 0) is the library's shape, equation error also tries a few mm/s,
# and a v_s it chooses is refitted. Below FRICTION_BUILD_UP_MIN the runs, sampled at 1 kHz
# with ż known to mm/s, cannot tell it from the step, and the integrator's 1 ms step would
# chatter across a slope c/v_s that steep
FRICTION_SHAPES = ((0.0,), (2e-3,), (6e-3,))  # m/s
FRICTION_BUILD_UP_MIN = 1e-3  # m/s
# (term kind, shape): least value. Bouc–Wen's exponent: below 1, |r|^(n−1) makes the
# loop's slope at each reversal (r = 0) infinite
SHAPE_FLOORS = {("coulomb", "v_s"): FRICTION_BUILD_UP_MIN, ("bouc_wen", "n"): 1.0}


def yield_stiffness(shape: tuple[float, ...]) -> float:
    """1 / the yield displacement of a Bouc–Wen shape (a, b, n), 1/m: r saturates at
    (a + b)^(−1/n)."""
    a, b, n = shape
    return float((a + b) ** (1.0 / n))


@dataclass(frozen=True)
class Candidate:
    """An effect the model may lack."""

    name: str
    explanation: str
    parameter: str  # name of the parameter it adds
    unit: str
    signature: str  # the variable its residual shows against: z, zd, t, x, xd
    term_kind: str = ""  # "" for a sensor effect
    shape: tuple[float, ...] = ()
    sign: int = 0  # +1 / −1 where physics fixes the sign, 0 where either is possible
    # shape constants the runs can choose (named as the term kind names them): searched by
    # equation error over `shapes` and refitted with the effect; the rest only scale it
    free_shape: tuple[str, ...] = ()
    shapes: tuple[tuple[float, ...], ...] = ()  # the shapes equation error tries
    # the coefficient of Eq 10 (a force in N, like this effect's) whose term a base fit
    # bends into this effect's shape: k2 tanh(αz), saturated at the dead band's edge, is a
    # preload's step; c2 tanh(βż) with a large β, a dry friction's
    takes_over: str = ""

    @property
    def stateful(self) -> bool:
        """Whether its term carries a state from sample to sample (a drift's temperature,
        a hysteresis's z_h), which a run may start afresh or carry over."""
        return bool(self.term_kind) and kind(self.term_kind).has_state

    def typical(self, model: IsolatorModel) -> float:
        """The physics-sized magnitude of this effect for `model` (SI)."""
        p = model.parameters()
        k1, c1 = abs(p.get("k1", 7.0e4)), abs(p.get("c1", 6.0e3))
        if self.name == "hysteresis":
            # sized by its force at the yield displacement (a + b)^(-1/n), as the dry
            # friction is: a seal that yields at 1 mm is stiffer than one at 12 mm
            return HYSTERETIC_FORCE * yield_stiffness(self.shape)
        return {
            "coulomb_friction": 100.0,  # N, the report's breakaway force is 92 N
            "asymmetric_damping": 0.2 * c1,
            "quadratic_damping": 0.2 * c1,  # equals 0.2 c1 ż at 1 m/s
            "cubic_stiffness": 20.0 * k1,  # equals 0.2 k1 z at z = 0.1 m
            "asymmetric_stiffness": 0.2 * k1,
            "preload": 100.0,
            "force_offset": 100.0,
            "thermal_damping_drift": 0.05 * c1,  # per K
            SENSOR_DELAY: 1e-3,  # s, one sample at 1 kHz
            SENSOR_GAIN: 0.01,
        }[self.name]

    def bounds(self, model: IsolatorModel) -> tuple[float, float]:
        big = 50.0 * self.typical(model)  # an effect 50 times "worth naming" is another model
        # the limit the model's term has (a start may have placed it), else this shape's
        shape = next((t.shape for t in model.terms if t.name == self.parameter), self.shape)
        if self.term_kind == "thermal_damper" and shape[2] > 0.0:
            # a drift that stops at θ_max is bounded by the damping it can take away, c1
            # (twice, for a refit that lowers θ_max), however steep it is per K on the way
            big = max(big, 2.0 * abs(model.parameters().get("c1", 6.0e3)) / shape[2])
        return (0.0 if self.sign > 0 else -big, 0.0 if self.sign < 0 else big)

    def size_at(self, value: float, shape: tuple[float, ...]) -> float:
        """Its size `value` at this shape carried to `shape` with the same force: a
        hysteresis's stiffness scales with 1 / its yield displacement (`typical`); every
        other effect's size is a force, or a coefficient the shape does not scale."""
        if self.name == "hysteresis":
            return value * yield_stiffness(tuple(shape)) / yield_stiffness(self.shape)
        return value

    def shaped(self, shape: tuple[float, ...]) -> Candidate:
        """This effect with another shape (one of `shapes`, or a refitted one)."""
        return replace(self, shape=tuple(shape))

    def shape_parameters(self, model: IsolatorModel) -> list[str]:
        """The qualified names of the shape constants a refit frees, as `model` has them:
        none at the library's own shape. There the runs cannot tell the shape from the
        size (a cooling time of minutes over a 4 s run: θ integrates ż², and only c_T·τ
        shows; freed, c_T of a -400 N/(m/s)/K drift came out -465), and only a shape the
        runs chose over it (`naming`) is theirs to refit."""
        if not self.free_shape or self.shape == CANDIDATES[self.name].shape:
            return []
        term = model.term(self.parameter)
        # a limit at 0 is off (a thermal drift without a floor), and its basis jumps
        # there: it stays off rather than being stepped across
        return [q for q, n, v in zip(term.shape_names(), kind(term.kind).shape_names,
                                     term.shape) if n in self.free_shape and v != 0.0]

    def add_to(self, model: IsolatorModel) -> tuple[IsolatorModel, str]:
        """The model with this effect at zero, and the name of the parameter to fit.

        A term the model already carries (the report's c3 and γ at zero, or this effect
        at a refitted shape) is reused.
        """
        if not self.term_kind:
            return model, self.parameter
        for t in model.terms:
            if t.kind == self.term_kind and t.name == self.parameter and t.coef == 0.0 \
                    and t.shape != self.shape:
                # the report's c3 at zero, at this effect's shape (a friction built up over
                # v_s)
                return model.with_parameters(**dict(zip(t.shape_names(), self.shape))), t.name
            if t.kind == self.term_kind and (t.shape == self.shape or t.name == self.parameter):
                return model, t.name
        return model.with_terms(Term(self.term_kind, self.parameter, 0.0, self.shape)), \
            self.parameter


def shape_floor(model: IsolatorModel, name: str) -> float:
    """The least value a refit may give the shape constant `name` of `model` (−inf: none)."""
    for t in model.terms:
        for q, n in zip(t.shape_names(), kind(t.kind).shape_names):
            if q == name:
                return SHAPE_FLOORS.get((t.kind, n), -np.inf)
    return -np.inf


CANDIDATES: dict[str, Candidate] = {
    c.name: c
    for c in (
        Candidate("coulomb_friction", "dry friction of the rod seals: a constant force against "
                  "the motion, a step in the restoring force at ż = 0 (or built up over v_s)",
                  "c3", "N", "zd", "coulomb", FRICTION_SHAPES[0], sign=+1, takes_over="c2",
                  free_shape=("v_s",), shapes=FRICTION_SHAPES),
        Candidate("asymmetric_damping", "a check valve in the piston head: more damping in "
                  "extension than in compression", "c_ext", "N/(m/s)", "zd",
                  "extension_damper"),
        Candidate("quadratic_damping", "turbulent flow through the orifice: force ∝ ż|ż|",
                  "c_q", "N/(m/s)^2", "zd", "quadratic_damper", sign=+1),
        Candidate("cubic_stiffness", "hardening of the compressed fluid at large stroke: z³",
                  "k3", "N/m^3", "z", "cubic_spring"),
        Candidate("asymmetric_stiffness", "the rod displaces fluid in compression only: "
                  "stiffer one way than the other", "k_comp", "N/m", "z", "compression_spring"),
        Candidate("preload", "fluid preload: a force step γ sgn(z) at the edge of the dead "
                  "band", "gamma", "N", "z", "preload", sign=+1, takes_over="k2"),
        Candidate("force_offset", "a constant force: a tilted track, a cable, a zero error",
                  "F0", "N", "t", "force_offset"),
        Candidate("thermal_damping_drift", "viscosity falls as the fluid heats from the energy "
                  "the damper dissipates: damping drifts down within and across runs",
                  "c_T", "N/(m/s)/K", "t", "thermal_damper", THERMAL_SHAPE, sign=-1,
                  free_shape=("tau", "theta_max"), shapes=THERMAL_SHAPES),
        Candidate("hysteresis", "rate-independent hysteresis (Bouc–Wen) of seals and "
                  "mountings: two forces at one (z, ż)", "k_h", "N/m", "z", "bouc_wen",
                  HYSTERESIS_SHAPE, sign=+1, free_shape=("a", "b"), shapes=HYSTERESIS_SHAPES),
        Candidate(SENSOR_DELAY, "one sensor lags the other: the residual follows the mass "
                  "velocity", SENSOR_DELAY, "s", "xd"),
        Candidate(SENSOR_GAIN, "a scale error of the mass sensor: the residual follows x",
                  SENSOR_GAIN, "1", "x"),
    )
}


def signature_variable(name: str, z: np.ndarray, zd: np.ndarray, x: np.ndarray,
                       t: np.ndarray) -> np.ndarray:
    """The variable a candidate's residual is plotted and binned against."""
    sig = CANDIDATES[name].signature
    if sig == "xd":
        return np.gradient(x, t)
    return {"z": z, "zd": zd, "x": x, "t": t}[sig]
