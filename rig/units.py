"""Unit conversion at the edges: SI inside, the report's US customary units outside.

Every quantity in the code is SI. A unit name maps to the factor that turns a
value in that unit into SI, so `to_si(405, "lb/in")` is 70 926 N/m and
`from_si(70926, "lb/in")` is 405.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

INCH = 0.0254  # m, exact by definition
POUND_FORCE = 4.4482216152605  # N, exact by definition
POUND_MASS = 0.45359237  # kg, exact by definition
STANDARD_GRAVITY = 9.80665  # m/s^2

#: factor from the named unit to SI
FACTORS: dict[str, float] = {
    # SI names map to 1 so a file may state SI units explicitly
    "m": 1.0,
    "m/s": 1.0,
    "m/s^2": 1.0,
    "s": 1.0,
    "N": 1.0,
    "N/m": 1.0,
    "N/(m/s)": 1.0,
    "N.s/m": 1.0,
    "kg": 1.0,
    "1/m": 1.0,
    "s/m": 1.0,
    "1": 1.0,
    "Pa": 1.0,
    "m^2": 1.0,
    "m^3/s": 1.0,
    "mm": 1e-3,  # as measurement files (MDF, TDMS) often give lengths
    # US customary, as the report writes them
    "in": INCH,
    "in.": INCH,
    "ft": 12 * INCH,
    "in/s": INCH,
    "in./sec": INCH,
    "in/s^2": INCH,
    "g": STANDARD_GRAVITY,
    "lb": POUND_FORCE,
    "lbf": POUND_FORCE,
    "lbm": POUND_MASS,
    "lb/in": POUND_FORCE / INCH,
    "lb/in.": POUND_FORCE / INCH,
    "lb/(in/s)": POUND_FORCE / INCH,
    "lb/in./sec": POUND_FORCE / INCH,
    "1/in": 1 / INCH,
    "s/in": 1 / INCH,
    "in^2": INCH**2,
    "psi": POUND_FORCE / INCH**2,
    "gpm": 3.785411784e-3 / 60.0,
}

#: the US unit the report uses for each SI unit, for printing back
US_FOR_SI: dict[str, str] = {
    "m": "in",
    "m/s": "in/s",
    "m/s^2": "in/s^2",
    "N": "lb",
    "N/m": "lb/in",
    "N/(m/s)": "lb/(in/s)",
    "kg": "lbm",
    "1/m": "1/in",
    "s/m": "s/in",
    "s": "s",
    "1": "1",
    "Pa": "psi",
    "m^2": "in^2",
    "m^3/s": "gpm",
}


class UnitError(ValueError):
    """A unit name that this module does not know."""


def factor(unit: str) -> float:
    """SI factor of `unit`; raises UnitError naming the unit and the known ones."""
    try:
        return FACTORS[unit]
    except KeyError:
        known = ", ".join(sorted(FACTORS))
        raise UnitError(f"unknown unit {unit!r} (known: {known})") from None


def to_si(value: ArrayLike, unit: str) -> np.ndarray | float:
    """Convert `value` given in `unit` to SI."""
    result = np.asarray(value, dtype=float) * factor(unit)
    return float(result) if result.ndim == 0 else result


def from_si(value: ArrayLike, unit: str) -> np.ndarray | float:
    """Convert an SI `value` to `unit`."""
    result = np.asarray(value, dtype=float) / factor(unit)
    return float(result) if result.ndim == 0 else result


def us_unit(si_unit: str) -> str:
    """The report's unit for an SI unit name (identity where the report has none)."""
    return US_FOR_SI.get(si_unit, si_unit)
