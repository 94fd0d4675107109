"""Force-driven records from other rigs' CSV: a time column, a force and a position by name.

The file has a header row and one sample per row; `.csv.gz` is read as gzipped
CSV. Time is the column `t` (or `time`), in seconds. The force column is in N
and the position column in m unless `units` says otherwise. A name may carry
its unit as a suffix (`qm_m`, `force_N`) or in brackets (`x [in]`); a bracketed
unit is checked against `units`, a suffix is only part of the name.

Anything unusable raises a one-line `DataError` naming the file and the problem.
A clock with jitter (EMPS: ±0.03 µs on 1 ms) is taken as uniform at its mean step.
"""

from __future__ import annotations

import gzip
import io
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rig.errors import DataError
from rig.units import UnitError, to_si

TIME_NAMES = ("t", "time")
MIN_SAMPLES = 200  # fewer cannot hold a filter's transient and a useful record
JITTER = 0.01  # of the mean step: a clock steadier than this is taken as uniform
BRACKET = re.compile(r"^\s*([^\[\]]+?)\s*(?:\[\s*([^\]]+?)\s*\])?\s*$")


@dataclass(frozen=True)
class ForceRecord:
    """One force-driven record on a uniform clock, SI: t (s), force (N), position (m)."""

    name: str
    path: Path
    t: np.ndarray
    force: np.ndarray
    position: np.ndarray
    force_column: str
    position_column: str

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    def section(self, start: int, stop: int, name: str | None = None) -> ForceRecord:
        """Samples [start, stop) (0-based, half open), e.g. a benchmark's train slice."""
        if not 0 <= start < stop <= self.t.size:
            raise DataError(f"{self.path}: section [{start}, {stop}) is outside the "
                            f"{self.t.size} samples")
        s = slice(start, stop)
        return ForceRecord(name or f"{self.name}[{start}:{stop}]", self.path, self.t[s],
                           self.force[s], self.position[s], self.force_column,
                           self.position_column)


def read_table(path: Path) -> tuple[list[str], np.ndarray]:
    """Header and numbers of a CSV or gzipped CSV; shape (rows, columns)."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: no such file")
    opener = gzip.open if path.name.lower().endswith(".gz") else open
    try:
        with opener(path, "rt", encoding="utf-8", newline="") as f:
            text = f.read()
    except (OSError, UnicodeDecodeError, EOFError) as e:
        raise DataError(f"{path}: cannot read: {e}") from None
    first, _, body = text.partition("\n")
    header = [h.strip() for h in first.strip().split(",")]
    if not first.strip() or not body.strip():
        raise DataError(f"{path}: no data rows after the header")
    try:
        data = np.loadtxt(io.StringIO(body), delimiter=",", ndmin=2)
    except ValueError as e:  # numpy names the row and column (counted in the data rows)
        raise DataError(f"{path}: {str(e).strip().splitlines()[0]}") from None
    if data.shape[1] != len(header):
        raise DataError(f"{path}: {data.shape[1]} values per row but {len(header)} names "
                        "in the header")
    return header, data


def load_force_record(path: Path, force: str, position: str, units: str | None = None,
                      force_units: str | None = None) -> ForceRecord:
    """Read `force` and `position` (column names, case-insensitive) and the time column.

    `units` is the position column's unit (default m), `force_units` the force's (default N),
    both rig.units names (m, in, ft; N, lbf).
    """
    path = Path(path)
    header, data = read_table(path)
    columns = {_bare(h): (i, _bracket_unit(h)) for i, h in enumerate(header)}
    listing = ", ".join(header)
    time = next((n for n in TIME_NAMES if n in columns), None)
    if time is None:
        raise DataError(f"{path}: no time column 't' (columns: {listing})")
    picked = {}
    for role, name in (("force", force), ("position", position)):
        key = _bare(name)
        if key not in columns:
            raise DataError(f"{path}: no {role} column {name!r} (columns: {listing})")
        picked[role] = columns[key]
    t = data[:, columns[time][0]]
    if columns[time][1] not in (None, "s"):
        raise DataError(f"{path}: time must be in s, header says {columns[time][1]!r}")
    values = {}
    for role, default, given in (("force", "N", force_units), ("position", "m", units)):
        i, header_unit = picked[role]
        unit = _unit(path, header[i], header_unit, given, default)
        values[role] = np.asarray(to_si(data[:, i], unit), float)
    for i, v in ((columns[time][0], t), (picked["force"][0], values["force"]),
                 (picked["position"][0], values["position"])):
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            raise DataError(f"{path}: row {bad[0] + 2}, column {header[i]}: {data[bad[0], i]} "
                            f"({bad.size} non-finite values)")
    t = uniform_clock(path, t)
    return ForceRecord(_stem(path), path, t, values["force"], values["position"],
                       header[picked["force"][0]], header[picked["position"][0]])


def uniform_clock(path: Path, t: np.ndarray) -> np.ndarray:
    """t as an exact uniform grid; refuses too few samples, repeated, decreasing or gapped time."""
    if t.size < MIN_SAMPLES:
        raise DataError(f"{path}: {t.size} samples, need at least {MIN_SAMPLES}")
    step = np.diff(t)
    bad = np.flatnonzero(step <= 0)
    if bad.size:
        k = int(bad[0])
        kind = "duplicate" if step[k] == 0 else "decreasing"
        raise DataError(f"{path}: {kind} time at row {k + 3} (t = {t[k + 1]:.9g} s after "
                        f"{t[k]:.9g} s)")
    dt = float(t[-1] - t[0]) / (t.size - 1)
    worst = int(np.argmax(np.abs(step - dt)))
    if abs(step[worst] - dt) > JITTER * dt:
        raise DataError(f"{path}: time step at row {worst + 3} is {step[worst] * 1e3:.6g} ms, "
                        f"the mean is {dt * 1e3:.6g} ms: a gap or an uneven clock "
                        "(force-driven fits need uniform sampling)")
    return t[0] + dt * np.arange(t.size)


def _bare(header: str) -> str:
    m = BRACKET.match(header)
    return (m.group(1) if m else header).strip().lower()


def _bracket_unit(header: str) -> str | None:
    m = BRACKET.match(header)
    return m.group(2) if m else None


def _unit(path: Path, column: str, header: str | None, given: str | None, default: str) -> str:
    if header is not None and given is not None and header != given:
        raise DataError(f"{path}: column {column} is in {header} but the units given are {given}")
    unit = header or given or default
    try:
        to_si(1.0, unit)
    except UnitError as e:
        raise DataError(f"{path}: column {column}: {e}") from None
    return unit


def _stem(path: Path) -> str:
    name = path.name
    for ext in (".csv.gz", ".gz", ".csv"):
        if name.lower().endswith(ext):
            return name[: -len(ext)]
    return path.stem
