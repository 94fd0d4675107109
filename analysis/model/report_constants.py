"""The report's constants (Table 1) and test configuration, loaded from data/ in SI."""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from functools import lru_cache

from analysis.model.isolator import IsolatorModel, Term
from rig.paths import data_file
from rig.units import from_si, to_si, us_unit

RUNS = ("A", "B", "C", "average")
NAMES = ("k1", "k2", "c1", "c2", "c3", "alpha", "beta", "gamma", "delta", "epsilon", "F_break")


@dataclass(frozen=True)
class Table1:
    """Table 1 in SI: run → constant name → value; `us_units`: the report's unit names."""

    runs: dict[str, dict[str, float]]
    us_units: dict[str, str]
    mass: float  # kg, the test configuration's isolated mass
    stroke: float  # m
    source: str


@lru_cache(maxsize=1)
def load_table1() -> Table1:
    """Read data/table1.toml and convert every number to SI."""
    doc = tomllib.loads(data_file("table1.toml").read_text(encoding="utf-8"))
    units = doc["units"]
    runs = {run: {n: to_si(doc["runs"][run][n], units[n]) for n in NAMES} for run in RUNS}
    cfg = doc["test_configuration"]
    return Table1(
        runs=runs,
        us_units=dict(units),
        mass=to_si(cfg["mass"]["value"], cfg["mass"]["unit"]),
        stroke=to_si(cfg["stroke"]["value"], cfg["stroke"]["unit"]),
        source=doc["source"],
    )


def si_unit(name: str) -> str:
    """SI unit name of a Table 1 constant."""
    return {"k1": "N/m", "k2": "N", "c1": "N/(m/s)", "c2": "N", "c3": "N", "alpha": "1/m",
            "beta": "s/m", "gamma": "N", "delta": "m", "epsilon": "m/s", "F_break": "N"}[name]


def report_model(run: str = "average") -> IsolatorModel:
    """Eq 10 with the dead band and static friction of appendix B, constants of `run`."""
    table = load_table1()
    if run not in table.runs:
        raise KeyError(f"unknown run {run!r} (Table 1 has {', '.join(RUNS)})")
    c = table.runs[run]
    return IsolatorModel(
        mass=table.mass,
        terms=(
            Term("linear_spring", "k1", c["k1"]),
            Term("tanh_spring", "k2", c["k2"], (c["alpha"],)),
            Term("linear_damper", "c1", c["c1"]),
            Term("tanh_damper", "c2", c["c2"], (c["beta"],)),
            Term("coulomb", "c3", c["c3"]),
            Term("preload", "gamma", c["gamma"]),
        ),
        dead_band=c["delta"],
        breakaway=c["F_break"],
        stop_velocity=c["epsilon"],
        description=f"CERL TR M-226 Eq 10, Table 1 run {run}",
    )


def format_table1(units: str = "us") -> str:
    """Table 1 as text, in the report's units ('us') or SI ('si')."""
    if units not in ("us", "si"):
        raise ValueError(f"units must be 'us' or 'si', got {units!r}")
    table = load_table1()
    lines = [f"Table 1: optimized constants ({table.source})",
             f"{'constant':<10}{'unit':<12}" + "".join(f"{r:>12}" for r in RUNS)]
    for n in NAMES:
        unit = table.us_units[n] if units == "us" else si_unit(n)
        vals = [from_si(table.runs[r][n], unit) if units == "us" else table.runs[r][n]
                for r in RUNS]
        lines.append(f"{n:<10}{unit:<12}" + "".join(f"{v:>12.4g}" for v in vals))
    mass_unit = "lbm" if units == "us" else "kg"
    stroke_unit = us_unit("m") if units == "us" else "m"
    lines.append(f"test configuration: mass {from_si(table.mass, mass_unit):.6g} {mass_unit}, "
                 f"stroke {from_si(table.stroke, stroke_unit):.4g} {stroke_unit}")
    return "\n".join(lines)
