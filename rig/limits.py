"""The limit check run before anything moves: every actuator, every setpoint, four limits.

A pure function over the whole plan (design.md §4.5–6): the profile is sampled at
the setpoint rate into the six actuators' extension, velocity, acceleration and
force (rig.geometry), and each peak is held against its limit:

    stroke        |extension|     ≤ stroke (± from mid-stroke)
    velocity      |velocity|      ≤ servovalve flow / piston area
    acceleration  |acceleration|  ≤ rated acceleration
    force         |force|         ≤ min(rated capacity, supply pressure × piston area)

`check_all` returns the Margins or raises one LimitError that lists every violation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.config import Actuator, RigConfig
from rig.errors import LimitError
from rig.geometry import ActuatorPlan, actuator_plan
from rig.profile import Profile
from rig.units import from_si, us_unit

QUANTITIES = ("stroke", "velocity", "acceleration", "force")
SI_UNITS = {"stroke": "m", "velocity": "m/s", "acceleration": "m/s^2", "force": "N"}
#: printf formats by unit name: about 0.1 % of a typical limit
FORMATS = {"m": ".4f", "m/s": ".2f", "m/s^2": ".1f", "N": ",.0f",
           "in": ".2f", "in/s": ".1f", "in/s^2": ".0f", "lb": ",.0f"}


@dataclass(frozen=True)
class Margin:
    """One actuator's peak of one quantity against its limit, SI (`unit`), at time `t` (s)."""

    actuator: int
    name: str
    quantity: str
    peak: float
    limit: float
    rule: str  # what sets the limit, e.g. "servovalve limit"
    t: float

    @property
    def unit(self) -> str:
        return SI_UNITS[self.quantity]

    @property
    def fraction(self) -> float:
        """1 − peak/limit: 0.2 is 20 % to spare, negative is over the limit."""
        return 1.0 - self.peak / self.limit

    @property
    def ok(self) -> bool:
        return self.peak <= self.limit

    def describe(self, profile: str, units: str = "si") -> str:
        """`actuator 3 velocity 2.41 m/s exceeds servovalve limit 1.29 m/s (profile C, …)`,
        in SI or the report's US units (`units='us'`)."""
        verb = "within" if self.ok else "exceeds"
        unit = self.unit if units == "si" else us_unit(self.unit)
        peak, limit = (from_si(v, unit) for v in (self.peak, self.limit))
        return (f"actuator {self.actuator} {self.quantity} {_fmt(peak, unit)} {verb} "
                f"{self.rule} {_fmt(limit, unit)} (profile {profile}, t = {self.t:.3f} s)")


@dataclass(frozen=True)
class Margins:
    """Every actuator × quantity margin of one profile, in actuator then QUANTITIES order."""

    profile: str
    rate: float  # Hz, the setpoint rate the plan was sampled at
    samples: int
    items: tuple[Margin, ...]

    def get(self, actuator: int, quantity: str) -> Margin:
        """The margin of `actuator` (1–6) for `quantity`; KeyError if there is none."""
        for m in self.items:
            if m.actuator == actuator and m.quantity == quantity:
                return m
        raise KeyError(f"no margin for actuator {actuator} {quantity}")

    @property
    def violations(self) -> tuple[Margin, ...]:
        return tuple(m for m in self.items if not m.ok)

    @property
    def worst(self) -> Margin:
        return min(self.items, key=lambda m: m.fraction)

    def format(self, units: str = "si") -> str:
        """A table for a test engineer, in SI or the report's US units (`units='us'`)."""
        if units not in ("si", "us"):
            raise ValueError(f"units must be 'si' or 'us', got {units!r}")
        lines = [f"Limit margins, profile {self.profile}: {self.samples} setpoints at "
                 f"{self.rate:g} Hz; margin = 1 - peak/limit",
                 f"{'act':>3} {'name':<6} {'quantity':<12} {'peak':>16} {'limit':>16} "
                 f"{'margin':>7}  {'at t':>7}  set by"]
        for m in self.items:
            unit = m.unit if units == "si" else us_unit(m.unit)
            peak, limit = (from_si(v, unit) for v in (m.peak, m.limit))
            flag = "" if m.ok else "  << OVER"
            lines.append(f"{m.actuator:>3} {m.name:<6} {m.quantity:<12} {_fmt(peak, unit):>16} "
                         f"{_fmt(limit, unit):>16} {m.fraction:>7.1%}  {m.t:>5.3f} s  "
                         f"{m.rule}{flag}")
        w = self.worst
        lines.append(f"smallest margin: actuator {w.actuator} {w.quantity} {w.fraction:.1%}")
        return "\n".join(lines)


def force_limit(config: RigConfig, actuator: Actuator) -> tuple[float, str]:
    """(N, rule): the smaller of the rated force and supply pressure × piston area."""
    hydraulic = config.table.supply_pressure * actuator.piston_area
    if hydraulic < actuator.force_capacity:
        return hydraulic, "pressure x area limit"
    return actuator.force_capacity, "force capacity"


def plan_margins(config: RigConfig, plan: ActuatorPlan) -> Margins:
    """Margins of every actuator and quantity over `plan`; raises nothing."""
    arrays = {"stroke": plan.extension, "velocity": plan.velocity,
              "acceleration": plan.acceleration, "force": plan.force}
    items = []
    for i, act in enumerate(config.table.actuators):
        limits = {"stroke": (act.stroke, "stroke limit"),
                  "velocity": (act.max_velocity, "servovalve limit"),
                  "acceleration": (act.max_acceleration, "acceleration limit"),
                  "force": force_limit(config, act)}
        for q in QUANTITIES:
            column = np.abs(arrays[q][:, i])
            k = int(np.argmax(column))
            limit, rule = limits[q]
            items.append(Margin(act.index, act.name, q, float(column[k]), limit, rule,
                                float(plan.t[k])))
    return Margins(plan.profile, plan.rate, len(plan.t), tuple(items))


def check_plan(config: RigConfig, plan: ActuatorPlan) -> Margins:
    """`plan_margins`, or LimitError listing every violation (first line summarises)."""
    margins = plan_margins(config, plan)
    if margins.violations:
        raise limit_error(margins, plan.profile)
    return margins


def limit_error(margins: Margins, profile: str, units: str = "si") -> LimitError:
    """The LimitError for `margins`' violations: one line each, after a summary line
    where there are several; `profile` names it as the user gave it (a file, or A)."""
    bad = margins.violations
    lines = [m.describe(profile, units) for m in bad]
    if len(bad) > 1:
        actuators = sorted({m.actuator for m in bad})
        lines.insert(0, f"profile {profile}: {len(bad)} limit violations on actuators "
                     f"{', '.join(map(str, actuators))}; nothing has moved")
    error = LimitError("\n".join(lines))
    error.margins = margins  # the whole table, for a display of what went wrong
    return error


def check_all(config: RigConfig, profile: Profile) -> Margins:
    """Check `profile` on every actuator against every limit before anything moves."""
    return check_plan(config, actuator_plan(config, profile))


def _fmt(value: float, unit: str) -> str:
    return f"{format(value, FORMATS.get(unit, '.4g'))} {unit}"
