"""The design space: which constants are free, and the box of sensible values for each.

The default box is scaled by the problem, not by the current isolator (whose k2
may be 0, or whose constants may be far from any good design) nor by the
fragility limit (the least acceleration within the stroke does not depend on
it): the force F = m a₀ that Figure 1's ideal isolator needs to keep the threats
within the stroke limit S (the least a design can pass; `design.scales`), S, and
the threats' peak table velocity V. Measured optima pass 1 to 2.2 times a₀; a
term whose force alone, at the stroke or at the threat's velocity, is several
times F cannot be part of one, so the coefficients run from 0 (the term absent)
to a few F:

    k1 (linear spring) m (2π f0)² … 4 F/S     c1 (linear damper)     0 … 4 F/V
    k2 (tanh spring)        0 … 2 F            c2 (tanh damper)       0 … 2 F
    α                  0.1/S … 100/S (log)     β                 0.1/V … 300/V (log)

f0 = 0.25 Hz: an isolator must bring the equipment back to the centre, and one
softer than a 4 s natural period drifts for longer than a shock record lasts
(with no spring at all, a stroke limit beyond the table's travel is met by
passing no force, which is no design). α S and β V say where the softening sets
in: from beyond the stroke or the velocity (0.1: the term is linear over it) to
1 % of it (100: a constant force). Beyond β V = 300 the tanh damper is dry
friction in all but name (0.995 of its force at 1 % of V): free a coulomb term
for that. Dead band 0 … S/2, breakaway 0 … F, dry friction and preload 0 … F.
The mass is the equipment's and is never free. Constants of kinds without a
default, and any constant whose default does not suit, take a
`--bound NAME=LO:HI`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from analysis.model.isolator import IsolatorModel
from analysis.model.terms import kind
from rig.errors import DataError

# the report's Eq 10: what is free unless the user says otherwise
EQ10 = ("k1", "k2", "c1", "c2", "alpha", "beta")
CENTRING = 0.25  # Hz, the softest linear spring of the default box (see above)


@dataclass(frozen=True)
class Scales:
    """What the default box is scaled by (SI)."""

    mass: float  # kg
    accel: float  # m/s², a₀: the ideal isolator's acceleration within the stroke limit
    stroke: float  # m, the stroke limit
    velocity: float  # m/s, the threats' peak table velocity

    @property
    def force(self) -> float:
        return self.mass * self.accel


@dataclass(frozen=True)
class Bound:
    """A free constant's box, SI; `log`: searched on a log scale (low > 0)."""

    name: str
    low: float
    high: float
    log: bool = False

    def __post_init__(self) -> None:
        if not (np.isfinite(self.low) and np.isfinite(self.high) and self.low < self.high):
            raise DataError(f"bound of {self.name}: need finite low < high, got "
                            f"{self.low:g} .. {self.high:g}")
        if self.log and self.low <= 0:
            raise DataError(f"bound of {self.name}: a log-scaled box needs low > 0")


@dataclass(frozen=True)
class DesignSpace:
    """The model whose constants are designed, and the box of its free constants.

    `model` is the working model: the user's isolator with the held terms whose
    coefficient is 0 left out (they add nothing but work for the integrator).
    """

    model: IsolatorModel
    bounds: tuple[Bound, ...]

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(b.name for b in self.bounds)

    def values(self, U: np.ndarray) -> np.ndarray:
        """(N, d) SI values of the free constants at unit-box coordinates U (N, d)."""
        U = np.clip(np.atleast_2d(U), 0.0, 1.0)
        out = np.empty_like(U)
        for j, b in enumerate(self.bounds):
            out[:, j] = (b.low * (b.high / b.low) ** U[:, j] if b.log
                         else b.low + (b.high - b.low) * U[:, j])
        return out

    def coords(self, values: np.ndarray) -> np.ndarray:
        """Unit-box coordinates (N, d) of SI values (N, d), clipped to the box."""
        V = np.atleast_2d(np.asarray(values, float))
        out = np.empty_like(V)
        for j, b in enumerate(self.bounds):
            out[:, j] = (np.log(np.maximum(V[:, j], 1e-300) / b.low) / np.log(b.high / b.low)
                         if b.log else (V[:, j] - b.low) / (b.high - b.low))
        return np.clip(out, 0.0, 1.0)

    def rows(self, values: np.ndarray) -> np.ndarray:
        """Kernel rows (N, P), `model.vector()` layout, with the free constants set."""
        V = np.atleast_2d(np.asarray(values, float))
        rows = np.tile(self.model.vector(), (V.shape[0], 1))
        idx = self.model.vector_index()
        for j, name in enumerate(self.names):
            rows[:, idx[name]] = V[:, j]
        return rows

    def current(self) -> np.ndarray:
        """(d,) the working model's own values of the free constants."""
        p = self.model.parameters()
        return np.array([p[n] for n in self.names])

    def designed(self, model: IsolatorModel, values: np.ndarray) -> IsolatorModel:
        """`model` (the user's, every term) with the free constants set to `values` (d,)."""
        return model.with_parameters(**dict(zip(self.names, map(float, values))))


def design_space(model: IsolatorModel, free: Sequence[str], scales: Scales,
                 overrides: Mapping[str, tuple[float, float]] | None = None) -> DesignSpace:
    """The space of `free` constants of `model`; `overrides`: name → (low, high) SI."""
    overrides = overrides or {}
    check_free(model, free, overrides)
    defaults = default_bounds(model, scales)
    bounds = []
    for name in free:
        if name in overrides:
            low, high = overrides[name]
            log = name in defaults and defaults[name].log and low > 0
            bounds.append(Bound(name, low, high, log))
        elif name in defaults:
            bounds.append(defaults[name])
        else:
            raise DataError(f"no default box for {name!r}: give --bound {name}=LOW:HIGH")
    return DesignSpace(working_model(model, free), tuple(bounds))


def check_free(model: IsolatorModel, free: Sequence[str],
               overrides: Mapping[str, tuple[float, float]]) -> None:
    """DataError for a free or bounded name the model lacks, the mass, a bound of a held
    constant or a bound that is no interval: before any simulation."""
    known = model.parameters()
    for name in list(free) + list(overrides):
        if name not in known:
            raise DataError(f"{name!r} is not a constant of the model (constants: "
                            f"{', '.join(n for n in known if n != 'm')})")
    if "m" in free:
        raise DataError("the mass is the equipment's, not the isolator's: give it with "
                        "--mass-lb, it is never free")
    unused = set(overrides) - set(free)
    if unused:
        raise DataError(f"--bound for {', '.join(sorted(unused))}, which is held: free it "
                        "with --free")
    for name, (low, high) in overrides.items():
        Bound(name, low, high)


def working_model(model: IsolatorModel, free: Sequence[str]) -> IsolatorModel:
    """`model` without the terms that are held at a zero coefficient."""
    keep = tuple(t for t in model.terms
                 if t.coef != 0.0 or t.name in free or set(t.shape_names()) & set(free))
    return replace(model, terms=keep)


def default_bounds(model: IsolatorModel, s: Scales) -> dict[str, Bound]:
    """The default box of every constant of `model` that has one (see the module's doc)."""
    F, S, V = s.force, s.stroke, s.velocity
    coef = {"linear_spring": 4 * F / S, "tanh_spring": 2 * F, "linear_damper": 4 * F / V,
            "tanh_damper": 2 * F, "coulomb": F, "preload": F, "cubic_spring": 4 * F / S**3,
            "quadratic_damper": 4 * F / V**2, "compression_spring": 4 * F / S,
            "extension_damper": 4 * F / V}
    shape = {("tanh_spring", "alpha"): (0.1 / S, 100 / S),
             ("tanh_damper", "beta"): (0.1 / V, 300 / V)}
    low = {"linear_spring": s.mass * (2 * np.pi * CENTRING) ** 2}
    out = {"delta": Bound("delta", 0.0, S / 2), "F_break": Bound("F_break", 0.0, F)}
    for t in model.terms:
        if t.kind in coef:
            out[t.name] = Bound(t.name, min(low.get(t.kind, 0.0), coef[t.kind] / 2),
                                coef[t.kind])
        for short, name in zip(kind(t.kind).shape_names, t.shape_names()):
            if (t.kind, short) in shape:
                out[name] = Bound(name, *shape[(t.kind, short)], log=True)
    return out
