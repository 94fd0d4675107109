"""A limit as the user writes it, `0.5g` or `6 in`: a number and its unit, read into SI.

A bare number is refused: `--max-stroke 6` could be inches or metres, and the two
designs differ by a factor of 39. So is a unit of the wrong kind (`--max-accel 6in`).
"""

from __future__ import annotations

import math
import re

from rig.errors import DataError
from rig.units import factor

# the units a limit of each kind may be written in; the first is the report's
UNITS: dict[str, tuple[str, ...]] = {
    "acceleration": ("g", "m/s^2", "in/s^2"),
    "length": ("in", "m", "mm", "ft"),
}
NUMBER_AND_UNIT = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(\S*)\s*$")


def parse_quantity(text: str, kind: str, option: str) -> float:
    """`text` (e.g. '0.5g', '6 in') as a positive SI value of `kind`; DataError names `option`."""
    allowed = UNITS[kind]
    m = NUMBER_AND_UNIT.match(text)
    if m is None:
        raise DataError(f"{option} {text!r}: not a number and a unit "
                        f"(e.g. '{_example(kind)}')")
    value, unit = float(m.group(1)), m.group(2)
    if not unit:
        raise DataError(f"{option} {text!r}: give its unit, one of {', '.join(allowed)} "
                        f"(e.g. '{_example(kind)}')")
    if unit not in allowed:
        raise DataError(f"{option} {text!r}: {unit!r} is not a unit of {kind} "
                        f"({', '.join(allowed)})")
    si = value * factor(unit)
    if not (si > 0 and math.isfinite(si)):
        raise DataError(f"{option} {text!r}: must be a positive finite {kind}")
    return si


def _example(kind: str) -> str:
    return {"acceleration": "0.5g", "length": "6in"}[kind]
