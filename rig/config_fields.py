"""One table of the rig's TOML configuration, read field by field (rig.config builds on it).

Every problem is a ConfigError naming the file and the dotted field; every quantity
is a `{ value, unit }` table converted to SI; a key nobody asked for is named as
unknown when the table is closed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NoReturn

from rig.errors import ConfigError
from rig.units import factor

#: unit names a quantity of each kind may be stated in; the first is SI
UNITS: dict[str, tuple[str, ...]] = {
    "length": ("m", "in", "ft"),
    "area": ("m^2", "in^2"),
    "mass": ("kg", "lbm"),
    "force": ("N", "lb", "lbf"),
    "flow": ("m^3/s", "gpm"),
    "acceleration": ("m/s^2", "in/s^2", "g"),
    "pressure": ("Pa", "psi"),
}

_MISSING = object()


class Section:
    """A TOML table being read: remembers the keys it used, so `close` can name leftovers."""

    def __init__(self, doc: object, source: str, path: str) -> None:
        if not isinstance(doc, Mapping):
            raise ConfigError(source, path, f"must be a table, got {show(doc)}")
        self.doc, self.source, self.path, self.used = doc, source, path, set()

    def where(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def fail(self, key: str, problem: str) -> NoReturn:
        raise ConfigError(self.source, self.where(key), problem)

    def get(self, key: str, default: Any = _MISSING) -> Any:
        self.used.add(key)
        if key in self.doc:
            return self.doc[key]
        if default is _MISSING:
            self.fail(key, "missing")
        return default

    def section(self, key: str) -> Section:
        return Section(self.get(key), self.source, self.where(key))

    def close(self) -> None:
        unknown = sorted(set(self.doc) - self.used)
        if unknown:
            self.fail(unknown[0], f"unknown key (known here: {', '.join(sorted(self.used))})")

    def string(self, key: str) -> str:
        v = self.get(key)
        if not isinstance(v, str) or not v.strip():
            self.fail(key, f"must be a non-empty string, got {show(v)}")
        return v

    def choice(self, key: str, choices: tuple[str, ...]) -> str:
        v = self.get(key)
        if v not in choices:
            self.fail(key, f"must be one of {', '.join(map(repr, choices))}, got {show(v)}")
        return v

    def integer(self, key: str, low: int, high: int | None = None) -> int:
        v = self.get(key)
        if isinstance(v, bool) or not isinstance(v, int):
            self.fail(key, f"must be an integer, got {show(v)}")
        if v < low or (high is not None and v > high):
            bounds = f"in {low}..{high}" if high is not None else f">= {low}"
            self.fail(key, f"must be {bounds}, got {v}")
        return v

    def number(self, key: str, low: float | None = None, high: float | None = None,
               unit: str = "", value: Any = _MISSING, strict: bool = True) -> float:
        """A finite number; `low` is exclusive unless not `strict`, `high` inclusive."""
        v = self.get(key) if value is _MISSING else value
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not _finite(v):
            self.fail(key, f"must be a finite number, got {show(v)}")
        u = f" {unit}" if unit else ""
        if low is not None and (v <= low if strict else v < low):
            self.fail(key, f"must be {'>' if strict else '>='} {low:g}{u}, got {v!r}")
        if high is not None and v > high:
            self.fail(key, f"must be <= {high:g}{u}, got {v!r}")
        return float(v)

    def _unit(self, key: str, raw: Any, kind: str | None) -> tuple[Any, float]:
        """(value, SI factor) of a `{ value, unit }` table; a bare value if `kind` is None."""
        if kind is None:
            return raw, 1.0
        allowed = UNITS[kind]
        if not isinstance(raw, Mapping) or set(raw) != {"value", "unit"}:
            self.fail(key, f'must be {{ value = …, unit = "{allowed[0]}" }} (a {kind} in '
                      f"{', '.join(allowed)}), got {show(raw)}")
        if raw["unit"] not in allowed:
            self.fail(f"{key}.unit", f"must be a {kind} unit ({', '.join(allowed)}), "
                      f"got {show(raw['unit'])}")
        return raw["value"], factor(raw["unit"])

    def quantity(self, key: str, kind: str, low: float | None = 0.0,
                 strict: bool = True) -> float:
        """A `{ value, unit }` scalar of `kind`, > `low` (>= if not strict), in SI."""
        raw = self.get(key)
        value, scale = self._unit(key, raw, kind)
        unit = raw["unit"]
        v = self.number(key, low=low, unit=unit, value=value, strict=strict) * scale
        if not math.isfinite(v):
            self.fail(key, f"{value!r} {unit} overflows")
        return v

    def vector(self, key: str, kind: str | None = None) -> tuple[float, float]:
        """An [x, y] pair of finite numbers, bare or `{ value = [x, y], unit }`, in SI."""
        value, scale = self._unit(key, self.get(key), kind)
        if not isinstance(value, list) or len(value) != 2:
            self.fail(key, f"must be a pair [x, y], got {show(value)}")
        x, y = (self.number(key, value=c) * scale for c in value)
        return (x, y)


def _finite(v: int | float) -> bool:
    try:
        return math.isfinite(v)
    except OverflowError:  # an integer beyond any float
        return False


def show(v: object) -> str:
    """`v` as an error message quotes it: a short repr, or the type of anything else."""
    if isinstance(v, (Mapping, list)):
        text = repr(dict(v) if isinstance(v, Mapping) else v)
        return text if len(text) <= 60 else text[:57] + "..."
    if isinstance(v, (bool, int, float, str)):
        return repr(v)
    return type(v).__name__
