"""Measured base-excited runs from rig HDF5 run files and from other rigs' CSV.

CSV: a header row, then one sample per row; columns `t` (s), `u` (table) and
`x` (mass absolute displacement), in metres unless told otherwise. A header
may carry its unit in brackets (`u [in]`, as `sim response` and `sim generate`
write); it must then agree with `--units` when both are given. Where neither
names a unit, metres are assumed, and a column that spans more than a table can
travel is refused with the unit it is likely in: inches read as metres fitted
nonsense at exit 0. Run files carry their payload mass in their configuration:
it is the isolated mass unless the user gives one, and a given mass a few per
cent away from it is named in a warning. A run that did not end in success
(never armed, e-stopped, failed) is skipped with a warning unless asked for.
Run files: channels `table_u`
and `mass_x` (metres), sampled by different sensors, so both are put on one
uniform grid at the slower channel's rate over the time they share, laid on the
mass sensor's own sampling instants: x, which output error fits sample by sample
against its noise σ_x, keeps its samples as they are. A grid between x's samples
made each x a weighted mean of two, down to 0.71 σ_x of noise at mid-way, which
the third-difference σ_x reads as 0.41 σ_x: a right model would have shown
resid/noise up to 1.7. u is interpolated onto that grid, and the table sensor's
own samples are kept beside it (`MeasuredRun.table_samples`, on the table's own
uniform grid: a missing sample is interpolated, no other moves): the table
motion is fitted to those. Interpolated, u's noise is a weighted mean of two
samples whose weights follow the phase between the two sensors' clocks, and that
phase drifts through a run (two clocks 65 ppm apart: a quarter of a sample
over 3.6 s), so the noise the table motion's accept test reads at the rests was not
the noise along the ramps: measured on 20 rig campaigns, one run's step-pulse
fit was refused for it, and the smoothing spline that replaced it
left its x at 2.3× the noise.

Each sensor channel's times are first put back on one straight line of its
sample index: the rig places a sample on its clock fit as that stands when the
sample is written (rig.run.recorder, half a second after arrival) and only the last
half second on the final fit of the whole run, so a channel's times step by up to
0.1 ms wherever the fit moved (measured on a campaign: 0.05–0.11 ms peak to peak
on the table channel). A sensor samples on its own steady clock, so the final
fit's line, extended over the whole channel, places every sample as the last
ones are (measured: 2–11 µs peak to peak). Kept as written when the times do not
lie within a quarter sample of one line (a clock that stepped, a reboot).

Plausibility (a warning, the data is still used): a displacement that moves
faster than any isolator test could (MAX_SPEED, twice the fastest step-pulse
and the actuators' 2.7 m/s) between two samples, beyond its noise — the
staircase of a sensor repeating its last value while the table moves.

Anything unusable raises `DataError` naming the file, the rule and the value;
anything usable but imperfect (a non-uniform clock that was resampled) is
returned as a warning for the caller to show.
"""

from __future__ import annotations

import csv
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from analysis.identify.foreign import FOREIGN_SUFFIXES, read_foreign
from analysis.identify.prepare import MeasuredRun
from rig.cli_support import OLD_UNIT_WORDS
from rig.config import MAX_STROKE, parse_config
from rig.errors import ConfigError, DataError
from rig.runfile import RunFile, check_readable, open_run
from rig.units import from_si, to_si

UNITS = ("m", "in")
UNIT_WORDS = {"m": "metres", "in": "inches"}
# m: the farthest a table can travel, end to end of the actuators' ±MAX_STROKE; a CSV
# read as metres that spans more is in another unit
MAX_TABLE_TRAVEL = 2.0 * MAX_STROKE
MASS_TOLERANCE = 0.03  # a given mass further than this from the run file's is named
ENDED_EARLY = ("abort", "fail")  # exit statuses of a run that did not run its profile
MIN_SAMPLES = 200  # the shortest ramp of interest (0.12 s) at 1 kHz plus rests
MIN_DURATION = 0.2  # s
JITTER = 0.01  # of the median step: a clock steadier than this is taken as uniform
REFIT_STEP = 5e-6  # s: a jump in a channel's times beyond its µs rounding: the fit moved
MAX_SPEED = 5.0  # m/s: run C peaks at 2.2 m/s, the actuators' valves allow 2.7 m/s
JUMP_NOISE = 8.0  # σ of a difference (√2 σ of the samples) a jump must exceed besides
HEADER = re.compile(r"^\s*([^\[\]]+?)\s*(?:\[\s*([^\]]+?)\s*\])?\s*$")


# s: a run file's channels come by different paths (CAN, serial), each placed late by
# its path's smallest delivery latency; measured p99 0.24 ms (docs/time_alignment.md)
RUNFILE_SKEW_LIMIT = 0.25e-3


@dataclass
class Loaded:
    """The runs read, and warnings about data that was usable but imperfect."""

    runs: list[MeasuredRun] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def load_runs(paths: list[Path], mass: float | None = None, units: str | None = None,
              include_aborted: bool = False, channels: tuple[str, str] | None = None
              ) -> Loaded:
    """Read every file (.h5/.hdf5 run files; .mf4/.mdf/.tdms by analysis.identify.foreign,
    its u and x channels named by `channels`; anything else as CSV).

    mass (kg): the isolated mass; None takes it from the run files' configuration
    (CSV carries none). A run that did not end in success (never armed, e-stopped)
    is skipped with a warning unless `include_aborted`.
    """
    if mass is not None and not (np.isfinite(mass) and mass > 0):
        raise DataError(f"mass must be a positive number of kg, got {mass}")
    out = Loaded()
    names: set[str] = set()
    read: list[tuple[Path, np.ndarray, np.ndarray, np.ndarray, tuple | None]] = []
    file_masses: dict[Path, float] = {}
    for path in paths:
        path = Path(path)
        if not path.exists():
            raise DataError(f"{path}: no such file")
        table = None
        if path.suffix.lower() in (".h5", ".hdf5"):
            run = _read_runfile(path, out.warnings, include_aborted)
            if run is None:
                continue
            t, u, x, table, payload = run
            if payload is not None:
                file_masses[path] = payload
        elif path.suffix.lower() in FOREIGN_SUFFIXES:
            t, u, x, assumed = read_foreign(path, channels, units, out.warnings)
        else:
            t, u, x, assumed = _read_csv(path, units)
        t, u, x = _uniform(path, t, u, x, out.warnings)
        if path.suffix.lower() not in (".h5", ".hdf5"):  # run files: checked per channel
            for column, v in (("u", u), ("x", x)):
                _check_travel(path, column, v, assumed)
                _check_speed(path, column, t, v, out.warnings)
        read.append((path, t, u, x, table))
    if not read:
        raise DataError("no run to fit: every file was skipped (see the warnings above); "
                        "--include-aborted fits runs that did not end in success")
    kg = _isolated_mass(mass, file_masses, [r[0] for r in read], out.warnings)
    for path, t, u, x, table in read:
        # a run file's two channels come by two paths: the table's own samples, a skew
        out.runs.append(MeasuredRun(_unique(path.stem, names), t, u, x, kg,
                                    skew_limit=RUNFILE_SKEW_LIMIT if table else 0.0,
                                    table_samples=table))
    return out


def _isolated_mass(given: float | None, in_files: dict[Path, float], paths: list[Path],
                   warnings: list[str]) -> float:
    """The mass to fit with: the one given, else the run files' payload mass (one for all)."""
    distinct = sorted(set(in_files.values()))
    if len(distinct) > 1 and max(distinct) > (1 + MASS_TOLERANCE) * min(distinct):
        listed = ", ".join(f"{p.name} {m:.1f} kg" for p, m in in_files.items())
        if given is None:
            raise DataError(f"the run files disagree on the payload mass ({listed}): one fit "
                            "needs one mass; give --mass KG or --mass-lb LB")
        warnings.append(f"the run files disagree on the payload mass ({listed}); using "
                        f"--mass {given:.1f} kg")
    if given is None:
        if not in_files:
            raise DataError("a base-excited fit needs the isolated mass: CSV files carry none "
                            f"({', '.join(p.name for p in paths)}); give --mass KG or "
                            "--mass-lb LB")
        return float(next(iter(in_files.values())))
    for p, m in in_files.items():
        if abs(given / m - 1.0) > MASS_TOLERANCE:
            warnings.append(f"{p}: --mass {given:.1f} kg ({from_si(given, 'lbm'):.1f} lb) "
                            f"disagrees with the run file's payload mass {m:.1f} kg "
                            f"({from_si(m, 'lbm'):.1f} lb); fitting with --mass")
            break
    return float(given)


def _check_travel(path: Path, column: str, v: np.ndarray, assumed: bool) -> None:
    """Refuse a column that, in the unit it was read in, moves further than a shaker table
    can: a file in inches read as metres fitted nonsense at exit 0. `assumed`: the unit
    was named nowhere (metres were taken)."""
    span = float(np.ptp(v))
    if span <= MAX_TABLE_TRAVEL:
        return
    likely = next((u for u in UNITS if u != "m" and to_si(span, u) <= MAX_TABLE_TRAVEL), None)
    how = "read as metres" if assumed else "in the unit given"
    raise DataError(f"{path}: column {column} spans {span:.3g} m {how}, more than "
                    f"a shaker table travels ({MAX_TABLE_TRAVEL:g} m)" + (
                        f": likely in {UNIT_WORDS[likely]} ({to_si(span, likely):.3g} m); "
                        f"give --units {OLD_UNIT_WORDS[likely]} or write the unit in the "
                        f"header (e.g. '{column} [{likely}]')"
                        if likely and assumed else "; check the file's units"))


def _unique(stem: str, taken: set[str]) -> str:
    name, k = stem, 2
    while name in taken:
        name, k = f"{stem}-{k}", k + 1
    taken.add(name)
    return name


def _read_csv(path: Path, units: str | None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """t, u, x (s, m) and whether the displacement unit was assumed (named nowhere)."""
    if units is not None and units not in UNITS:
        raise DataError(f"unknown units {units!r} (known: {', '.join(UNITS)})")
    columns, rows = read_csv_table(path)
    missing = [c for c in ("t", "u", "x") if c not in columns]
    if missing:
        raise DataError(f"{path}: no column {', '.join(repr(c) for c in missing)} (columns: "
                        f"{', '.join(columns)}; base-excited CSV needs t, u, x)")
    data = {c: csv_column(path, rows, columns[c][0], c) for c in ("t", "u", "x")}
    if columns["t"][1] not in (None, "s"):
        raise DataError(f"{path}: time must be in s, header says {columns['t'][1]!r}")
    out = [data["t"]]
    for c in ("u", "x"):
        out.append(np.asarray(to_si(data[c], _unit(path, c, columns[c][1], units)), float))
    assumed = units is None and all(columns[c][1] is None for c in ("u", "x"))
    return out[0], out[1], out[2], assumed


def read_csv_table(path: Path) -> tuple[dict[str, tuple[int, str | None]], list[list[str]]]:
    """A CSV's header as column name (lower case) → (index, unit in brackets or None),
    and its data rows; DataError, naming the file, for anything unreadable."""
    try:
        with open(path, newline="", encoding="utf-8") as f:
            rows = list(csv.reader(f))
    except UnicodeDecodeError as e:  # a binary or corrupt file given as CSV
        raise DataError(f"{path}: not a UTF-8 text CSV (byte {e.start}: {e.reason})") from None
    except csv.Error as e:  # a NUL byte, a field beyond the csv module's limit
        raise DataError(f"{path}: not a readable CSV: {e}") from None
    except OSError as e:  # a directory, no permission
        raise DataError(f"{path}: cannot read: {e.strerror or e}") from None
    if not rows:
        raise DataError(f"{path}: empty file")
    columns = {m.group(1).lower(): (i, m.group(2))
               for i, h in enumerate(rows[0]) if (m := HEADER.match(h))}
    return columns, rows[1:]


def _unit(path: Path, column: str, header: str | None, given: str | None) -> str:
    if header is not None and header not in UNITS:
        raise DataError(f"{path}: column {column} in unknown units {header!r} "
                        f"(known: {', '.join(UNITS)})")
    if header is not None and given is not None and header != given:
        raise DataError(f"{path}: column {column} is in {header} but --units says "
                        f"{OLD_UNIT_WORDS.get(given, given)} ({given})")
    return header or given or "m"


def csv_column(path: Path, rows: list[list[str]], i: int, name: str) -> np.ndarray:
    """Column i of the data rows as finite floats; DataError naming the row otherwise."""
    values = np.empty(len(rows))
    for k, row in enumerate(rows):
        try:
            values[k] = float(row[i])
        except (IndexError, ValueError):
            cell = row[i] if i < len(row) else "(missing)"
            raise DataError(f"{path}: row {k + 2}, column {name}: {cell!r} is not a number"
                            ) from None
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise DataError(f"{path}: row {bad[0] + 2}, column {name}: {values[bad[0]]} "
                        f"({bad.size} non-finite values)")
    return values


def _read_runfile(path: Path, warnings: list[str], include_aborted: bool = False):
    """x's grid t, u and x on it, the table channel on its own uniform grid, and the
    payload mass (kg) the run's configuration names (None if it names none); None for a
    run skipped because it did not end in success."""
    check_readable(path, _read_channels)  # HDF5 may hang or crash on a damaged file
    run = _read_channels(path)
    if run.status.state != "success" and run.status.state in ENDED_EARLY:
        why = f"the run ended in {run.status.state}" + (
            f" ({run.status.reason})" if run.status.reason else "")
        if not include_aborted:
            warnings.append(f"{path}: skipped: {why}; --include-aborted fits it")
            return None
        warnings.append(f"{path}: {why}; fitted as asked (--include-aborted)")
    if not run.status.complete:
        raise DataError(f"{path}: run is not complete (exit status {run.status.state}"
                        + (f": {run.status.reason}" if run.status.reason else "") + ")")
    for name in ("table_u", "mass_x"):
        if name not in run.channels:
            raise DataError(f"{path}: no channel {name!r} (channels: "
                            f"{', '.join(run.channels)})")
        if run.channels[name].units != "m":
            raise DataError(f"{path}: channel {name} in {run.channels[name].units}, expected m")
    cu, cx = run.channels["table_u"], run.channels["mass_x"]
    for c in (cu, cx):
        _check_time(path, c.time, c.name)
        _check_speed(path, c.name, c.time, c.value, warnings)
    tu, tx = _final_fit_times(cu.time), _final_fit_times(cx.time)
    if run.gaps:
        warnings.append(f"{path}: {sum(g.count for g in run.gaps)} samples missing in "
                        f"{len(run.gaps)} gaps; interpolated across them")
    # the sensors run on their own clocks: one grid at the slower rate over the common span,
    # starting on a sample of x (module doc)
    dt = max(float(np.median(np.diff(tu))), float(np.median(np.diff(tx))))
    t0, t1 = max(tu[0], tx[0]), min(tu[-1], tx[-1])
    if t1 - t0 < MIN_DURATION:
        raise DataError(f"{path}: the two channels overlap for {max(t1 - t0, 0):.3f} s, "
                        f"need {MIN_DURATION} s")
    first = int(np.searchsorted(tx, t0 - 1e-9 * dt))
    if first < tx.size and tx[first] < t1 - MIN_DURATION:
        t0 = float(tx[first])
    t = t0 + dt * np.arange(int(np.floor((t1 - t0) / dt + 1e-9)) + 1)
    own = np.linspace(tu[0], tu[-1], round((tu[-1] - tu[0]) / float(np.median(np.diff(tu)))) + 1)
    return (t, np.interp(t, tu, cu.value), np.interp(t, tx, cx.value),
            (own, np.interp(own, tu, cu.value)), _payload_mass(run))


def _payload_mass(run: RunFile) -> float | None:
    """kg: the payload mass of the configuration the run was made with."""
    try:
        doc = tomllib.loads(str(run.meta.get("configuration_toml", "")))
        return float(parse_config(doc, str(run.path)).table.payload_mass)
    except (tomllib.TOMLDecodeError, ConfigError, TypeError, ValueError, AttributeError):
        return None  # a file written without its configuration: the mass must be given


def _final_fit_times(t: np.ndarray) -> np.ndarray:
    """A channel's times on the line of its last stretch without a step (module doc)."""
    dt = float(np.median(np.diff(t)))
    k = np.round((t - t[0]) / dt)  # sample index; a missing sample is a skipped index
    steps = np.flatnonzero(np.abs(np.diff(t) - dt * np.diff(k)) > REFIT_STEP)
    last = steps[-1] + 1 if steps.size else 0
    if t.size - last < 50:  # too short to carry a rate: the line through all
        last = 0
    A = np.c_[np.ones(t.size - last), k[last:]]
    (a, b), *_ = np.linalg.lstsq(A, t[last:], rcond=None)
    line = a + b * k
    if np.max(np.abs(line - t)) > 0.25 * dt or np.any(np.diff(line) <= 0):
        return t
    return line


def _check_speed(path: Path, name: str, t: np.ndarray, v: np.ndarray,
                 warnings: list[str]) -> None:
    """Warn (one line) when v jumps between two samples faster than a test moves.

    Values or times that are not finite, or times that do not advance, are other
    rules' business (they raise DataError later): this check only looks past them.
    """
    if v.size < 3 or not (np.all(np.isfinite(v)) and np.all(np.diff(t) > 0)):
        return
    with np.errstate(all="ignore"):
        dv, dt = np.abs(np.diff(v)), np.diff(t)
        d2 = np.diff(v, 2)
        sigma = 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / np.sqrt(6.0)
        allowed = MAX_SPEED * dt + JUMP_NOISE * np.sqrt(2.0) * sigma
        jumps = np.flatnonzero(dv > allowed)
        if not jumps.size:
            return
        k = int(jumps[np.argmax(dv[jumps] / dt[jumps])])
        jump_mm, dt_ms, speed = dv[k] * 1e3, dt[k] * 1e3, dv[k] / dt[k]
    warnings.append(f"{path}: {name} jumps {jumps.size} times faster than any isolator test "
                    f"moves (largest {jump_mm:.3g} mm in {dt_ms:.3g} ms at "
                    f"t = {t[k + 1]:.6g} s, {speed:.3g} m/s; at most {MAX_SPEED:g} m/s "
                    f"expected): a sensor holding its last value? Data used as is")


def _read_channels(path: Path) -> RunFile:
    return open_run(path, raw=False)


def _check_time(path: Path, t: np.ndarray, what: str) -> None:
    if t.size < MIN_SAMPLES:
        raise DataError(f"{path}: {what} has {t.size} samples, need at least {MIN_SAMPLES}")
    broken = np.flatnonzero(~np.isfinite(t))
    if broken.size:  # a damaged file (found by fuzzing: one flipped bit made an inf)
        k = int(broken[0])
        raise DataError(f"{path}: {what}: time is {t[k]} at sample {k}, {broken.size} "
                        "samples without a finite time")
    step = np.diff(t)
    bad = np.flatnonzero(step <= 0)
    if bad.size:
        k = int(bad[0])
        kind = "duplicate" if step[k] == 0 else "decreasing"
        raise DataError(f"{path}: {what}: {kind} time at sample {k + 1} "
                        f"(t = {t[k + 1]:.6g} s after {t[k]:.6g} s)")
    if t[-1] - t[0] < MIN_DURATION:
        raise DataError(f"{path}: {what} lasts {t[-1] - t[0]:.3g} s, need {MIN_DURATION} s")


def _uniform(path: Path, t: np.ndarray, u: np.ndarray, x: np.ndarray, warnings: list[str]
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The samples on a uniform grid: as they are if the clock is steady, else resampled."""
    _check_time(path, t, "time")
    step = np.diff(t)
    dt = float(np.median(step))
    if np.max(np.abs(step - dt)) <= JITTER * dt:
        return t[0] + dt * np.arange(t.size), u, x
    dt = float(t[-1] - t[0]) / (t.size - 1)  # a jittered clock's mean step is its rate
    grid = t[0] + dt * np.arange(int(np.floor((t[-1] - t[0]) / dt + 1e-9)) + 1)
    warnings.append(f"{path}: time steps vary from {step.min() * 1e3:.4g} to "
                    f"{step.max() * 1e3:.4g} ms; resampled linearly at {dt * 1e3:.4g} ms")
    return grid, np.interp(grid, t, u), np.interp(grid, t, x)
