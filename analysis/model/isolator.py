"""An isolator model: mass, force terms, dead band and static friction, in SI.

The equation of motion is the report's Eq 4 with Eq 10's force:

    m ẍ = −F(z, ż, s),    F = Σ_j coef_j · basis_j(z, ż; shape_j)

with the displacement dead band δ (terms gated by it act only for |z| > δ) and
static friction (relative motion starts when the force the isolator must
transmit to keep the mass on the table exceeds the breakaway force; it stops
again when |ż| falls below ε and that force is within breakaway).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from analysis.model.terms import MAX_SHAPE, kind

# the kernel's global parameter slots, then MAX_SHAPE + 1 slots per term
P_MASS, P_DEAD_BAND, P_BREAKAWAY, P_STOP_VELOCITY = range(4)
N_GLOBAL = 4
TERM_WIDTH = 1 + MAX_SHAPE

GLOBAL_NAMES = ("m", "delta", "F_break", "epsilon")
GLOBAL_UNITS = {"m": "kg", "delta": "m", "F_break": "N", "epsilon": "m/s"}


@dataclass(frozen=True)
class Term:
    """One force term: `name` is its coefficient's name (k1, c2, …)."""

    kind: str
    name: str
    coef: float
    shape: tuple[float, ...] = ()
    gated: bool | None = None  # None: the kind's default

    def __post_init__(self) -> None:
        k = kind(self.kind)
        if len(self.shape) < len(k.shape_names):
            # trailing shape constants a term may leave out (a Bouc–Wen n, a thermal θ_max)
            given = dict(zip(k.shape_names, self.shape))
            full = k.completed_shape(given)
            if set(full) == set(k.shape_names):
                object.__setattr__(self, "shape", tuple(float(full[n]) for n in k.shape_names))
        if len(self.shape) != len(k.shape_names):
            raise ValueError(
                f"term {self.name!r} of kind {self.kind!r} needs shape constants "
                f"{k.shape_names}, got {len(self.shape)} values"
            )

    @property
    def is_gated(self) -> bool:
        return kind(self.kind).gated_by_dead_band if self.gated is None else self.gated

    def shape_names(self) -> tuple[str, ...]:
        """Names of this term's shape constants, qualified when the kind has more than one."""
        return tuple(_shape_name(self, s) for s in kind(self.kind).shape_names)


def _shape_name(term: Term, shape: str) -> str:
    # the report's α and β belong to k2 and c2; other kinds' shapes carry the term's name
    if (term.kind, term.name) in {("tanh_spring", "k2"), ("tanh_damper", "c2")}:
        return shape
    return f"{term.name}.{shape}"


@dataclass(frozen=True)
class IsolatorModel:
    """Mass on an isolator: the terms of F and the two non-smooth effects."""

    mass: float  # kg
    terms: tuple[Term, ...]
    dead_band: float = 0.0  # δ, m; 0 disables
    breakaway: float = 0.0  # N; 0 disables static friction
    stop_velocity: float = 0.0  # ε, m/s
    description: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        names = [t.name for t in self.terms]
        if len(set(names)) != len(names):
            raise ValueError(f"term names must be unique, got {names}")
        if self.mass <= 0:
            raise ValueError(f"mass must be positive, got {self.mass} kg")
        for label, v in (("dead band", self.dead_band), ("breakaway force", self.breakaway),
                         ("stop velocity", self.stop_velocity)):
            if v < 0 or not np.isfinite(v):
                raise ValueError(f"{label} must be finite and >= 0, got {v}")

    # --- named parameters, the view identification works in -------------------------
    def parameters(self) -> dict[str, float]:
        """Every number of the model by name, SI."""
        p = {"m": self.mass, "delta": self.dead_band, "F_break": self.breakaway,
             "epsilon": self.stop_velocity}
        for t in self.terms:
            p[t.name] = t.coef
            p.update(zip(t.shape_names(), t.shape))
        return p

    def units(self) -> dict[str, str]:
        """SI unit of each named parameter."""
        u = dict(GLOBAL_UNITS)
        for t in self.terms:
            k = kind(t.kind)
            u[t.name] = k.coef_unit
            u.update(zip(t.shape_names(), k.shape_units))
        return u

    def with_parameters(self, **values: float) -> IsolatorModel:
        """A copy with some named parameters changed; unknown names raise KeyError."""
        known = self.parameters()
        unknown = set(values) - set(known)
        if unknown:
            raise KeyError(f"unknown parameters {sorted(unknown)} (known: {list(known)})")
        terms = []
        for t in self.terms:
            coef = values.get(t.name, t.coef)
            shape = tuple(values.get(n, v) for n, v in zip(t.shape_names(), t.shape))
            terms.append(replace(t, coef=coef, shape=shape))
        return replace(
            self,
            mass=values.get("m", self.mass),
            dead_band=values.get("delta", self.dead_band),
            breakaway=values.get("F_break", self.breakaway),
            stop_velocity=values.get("epsilon", self.stop_velocity),
            terms=tuple(terms),
        )

    def with_terms(self, *extra: Term) -> IsolatorModel:
        """A copy with more terms (the loop adds effects this way)."""
        return replace(self, terms=self.terms + tuple(extra))

    def term(self, name: str) -> Term:
        for t in self.terms:
            if t.name == name:
                return t
        raise KeyError(f"no term named {name!r} (terms: {[t.name for t in self.terms]})")

    # --- the kernel's packed layout ---------------------------------------------------
    def structure(self) -> tuple[np.ndarray, np.ndarray]:
        """(kind codes, gated flags), one entry per term, for the compiled kernel."""
        codes = np.array([kind(t.kind).code for t in self.terms], dtype=np.int64)
        gated = np.array([t.is_gated for t in self.terms], dtype=np.bool_)
        return codes, gated

    def vector(self) -> np.ndarray:
        """Parameters packed as the kernel reads them: globals, then [coef, shape…] per term."""
        p = np.zeros(N_GLOBAL + TERM_WIDTH * len(self.terms))
        p[:N_GLOBAL] = (self.mass, self.dead_band, self.breakaway, self.stop_velocity)
        for j, t in enumerate(self.terms):
            o = N_GLOBAL + TERM_WIDTH * j
            p[o] = t.coef
            p[o + 1:o + 1 + len(t.shape)] = t.shape
        return p

    def vector_index(self) -> dict[str, int]:
        """Slot of each named parameter in `vector()`."""
        idx = {name: i for i, name in enumerate(GLOBAL_NAMES)}
        for j, t in enumerate(self.terms):
            o = N_GLOBAL + TERM_WIDTH * j
            idx[t.name] = o
            for i, n in enumerate(t.shape_names()):
                idx[n] = o + 1 + i
        return idx
