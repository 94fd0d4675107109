"""`sim response`: the noise-free response of the report's model to a base motion."""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.model.report_constants import report_model
from analysis.simulate import Response, simulate
from rig.profile import load_profile
from rig.units import STANDARD_GRAVITY, from_si

# column → SI unit; the US unit comes from rig.units
COLUMNS = {"t": "s", "u": "m", "x": "m", "z": "m", "zd": "m/s", "xdd": "m/s^2"}
US = {"s": "s", "m": "in", "m/s": "in/s", "m/s^2": "in/s^2", "N": "lb"}


@dataclass(frozen=True)
class Peak:
    name: str
    value: float  # SI
    unit: str  # SI
    time: float  # s


def run_response(run: str, constants: str = "average") -> Response:
    """Simulate profile `run` (A, B, C or a TOML file) with Table 1 column `constants`."""
    return simulate(report_model(constants), load_profile(run).motion())


def peaks(r: Response) -> list[Peak]:
    """Largest magnitude of each response variable and when it occurs."""
    out = []
    for name, unit in (("u", "m"), ("z", "m"), ("zd", "m/s"), ("xdd", "m/s^2")):
        series = getattr(r, name)
        i = int(np.argmax(np.abs(series)))
        out.append(Peak(name, float(series[i]), unit, float(r.t[i])))
    return out


LABELS = {"u": "table displacement u", "z": "relative displacement z",
          "zd": "relative velocity ż", "xdd": "mass acceleration ẍ"}


def format_peaks(r: Response, units: str) -> str:
    lines = [f"{'peak':<26}{'value':>12}  {'unit':<8}{'at t (s)':>9}"]
    for p in peaks(r):
        unit = US[p.unit] if units == "us" else p.unit
        value = from_si(p.value, unit) if units == "us" else p.value
        extra = f"   ({p.value / STANDARD_GRAVITY:+.3f} g)" if p.name == "xdd" else ""
        lines.append(f"{LABELS[p.name]:<26}{value:>+12.4f}  {unit:<8}{p.time:>9.3f}{extra}")
    return "\n".join(lines)


def write_csv(r: Response, path: Path, units: str) -> None:
    """Every sample with the force terms; header names carry the units."""
    columns = {name: (getattr(r, name), unit) for name, unit in COLUMNS.items()}
    columns.update({f"F_{k}": (v, "N") for k, v in r.forces.items()})
    header, data = [], []
    for name, (values, unit) in columns.items():
        shown = US[unit] if units == "us" else unit
        header.append(f"{name} [{shown}]")
        data.append(from_si(values, shown) if units == "us" else values)
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(np.column_stack(data).tolist())
