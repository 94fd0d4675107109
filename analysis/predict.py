"""Predict a run with an identified model: the response, its peaks, and their band.

The identified model (with every effect the loop added) is driven by a base
motion — a profile, a table displacement record or a base acceleration record —
from rest with the mass centred (z = ż = 0, internal states at zero: cold
fluid, relaxed seals). The peaks' band comes from the fit's covariance: the
estimated constants are drawn from the multivariate normal it describes and
every draw is simulated in one parallel call, so the band is what the
constants' uncertainty does to the peaks through the nonlinear model, not a
linearisation of it. Constants the fit held carry no uncertainty and stay put.
All SI.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike
from scipy.integrate import cumulative_trapezoid
from scipy.interpolate import PPoly

from analysis.identify.input_error import refine_table
from analysis.identify.loading import csv_column, read_csv_table
from analysis.identify.table_motion import estimate_table_motion
from analysis.model.isolator import N_GLOBAL, IsolatorModel
from analysis.model.model_json import SENSOR_NAMES, IdentifiedModel
from analysis.simulate import DEFAULT_DT, Response, motion_from_samples, simulate, simulate_batch
from analysis.simulate.motion import quintic_hermite
from rig.errors import DataError
from rig.profile import load_profile
from rig.units import factor

BANDED = ("z", "zd", "xdd")  # the peaks a band is given for: what an isolator is judged by
UNITS = {"u": "m", "x": "m", "z": "m", "zd": "m/s", "xdd": "m/s^2"}
DRAWS = 200  # enough for the 2.5 and 97.5 percentiles to within ~1 % of the band's width
MIN_SAMPLES = 4  # a cubic through the record needs four points
GAP = 1.5  # a time step this many median steps long is a gap: samples are missing
# A record is a specified (exact) motion when its 4th differences are not white noise:
# for white noise of σ the robust σ read from 4th and from 6th differences agree, for a
# smooth signal the 6th are smaller by (ω dt)² (measured, 25 µm noise: 0.98; profile A
# sampled at 1 kHz: 0, its rests are exact)
WHITE = 0.7
EXACT = 1e-9  # m: below this the "noise" is the CSV's decimal rounding


@dataclass(frozen=True)
class BaseMotion:
    """The table motion that drives a prediction, and the output grid (SI)."""

    motion: PPoly  # u(t), m
    t0: float  # s
    duration: float  # s
    dt: float  # s, output sample interval
    source: str  # how the motion was obtained, for the user


@dataclass(frozen=True)
class Peak:
    name: str
    value: float  # SI, signed: the largest magnitude
    unit: str  # SI
    time: float  # s


@dataclass(frozen=True)
class Prediction:
    """The nominal response, its peaks and, from the covariance, the peaks' band (SI)."""

    response: Response
    peaks: tuple[Peak, ...]  # u, z, ż, ẍ
    force_peaks: tuple[Peak, ...]  # each term's force, then static friction
    level: float = 0.0  # %, of the band; 0: no band
    band: dict[str, tuple[float, float]] = field(default_factory=dict)  # peak → (low, high)
    # variable → (low, high) at each sample, (n,) each: the band around the time history
    envelope: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    draws: int = 0  # draws simulated
    diverged: int = 0  # draws whose response was not finite (left out of the band)


def profile_motion(spec: str, dt: float = DEFAULT_DT) -> BaseMotion:
    """A profile (A, B, C or a TOML file) as the table commands it."""
    prof = load_profile(spec)
    return BaseMotion(prof.motion(), 0.0, prof.duration, dt, f"profile {prof.name}")


def sampled_motion(t: ArrayLike, u: ArrayLike, where: str = "motion") -> BaseMotion:
    """A table displacement record u(t) (s, m): measured (noisy) or specified (exact).

    Measured, it is estimated as the fit estimates its inputs (step-pulse ramps
    refined on the whole record, else a smoothing spline), so the prediction of a
    fitted run is driven exactly as the fit drove it; a spline through the samples
    would hand the sensor's noise, differentiated twice, to the model as base
    acceleration. Specified, the interpolating cubic through the samples is used.
    """
    t, u = np.asarray(t, float), np.asarray(u, float)
    dt = check_time(t, where)
    if is_exact(u):
        return BaseMotion(motion_from_samples(t, u), t[0], t[-1] - t[0], dt,
                          f"{where}: table displacement, exact samples (cubic spline)")
    table = estimate_table_motion(t, u)
    table = refine_table(t, u, table)
    return BaseMotion(table.motion, t[0], t[-1] - t[0], dt,
                      f"{where}: measured table displacement ({table.method}, residual "
                      f"{table.residual_over_noise:.2f} x its noise {table.sigma * 1e6:.3g} µm)")


def integrated_motion(t: ArrayLike, a: ArrayLike, where: str = "motion") -> BaseMotion:
    """A base acceleration record a(t) (s, m/s²) integrated twice, from rest at u = 0.

    Drift: a constant offset of the accelerometer integrates to a velocity ramp and
    a parabola of displacement. The table is at rest at both ends of a shock
    record, so the offset is the one that brings the velocity back to zero at the
    end, and it is removed before integrating.
    """
    t, a = np.asarray(t, float), np.asarray(a, float)
    dt = check_time(t, where)
    v = cumulative_trapezoid(a, t, initial=0.0)
    offset = v[-1] / (t[-1] - t[0])
    a = a - offset
    v = v - offset * (t - t[0])
    u = cumulative_trapezoid(v, t, initial=0.0)
    return BaseMotion(quintic_hermite(t, u, v, a), t[0], t[-1] - t[0], dt,
                      f"{where}: base acceleration integrated twice (offset "
                      f"{offset:.3g} m/s² removed)")


def check_time(t: np.ndarray, where: str) -> float:
    """The median time step (s) of a record; DataError on too few, unordered or missing samples."""
    if t.size < MIN_SAMPLES:
        raise DataError(f"{where}: {t.size} samples, need at least {MIN_SAMPLES}")
    step = np.diff(t)
    bad = np.flatnonzero(step <= 0)
    if bad.size:
        k = int(bad[0])
        raise DataError(f"{where}: time is not increasing at row {k + 3} (t = {t[k + 1]:.6g} s "
                        f"after {t[k]:.6g} s)")
    dt = float(np.median(step))
    gaps = np.flatnonzero(step > GAP * dt)
    if gaps.size:
        k = int(gaps[0])
        raise DataError(f"{where}: gap in time at row {k + 3}: {t[k]:.6g} s to {t[k + 1]:.6g} s "
                        f"({step[k] / dt:.1f} x the median step {dt * 1e3:.4g} ms; "
                        f"{gaps.size} gap(s))")
    return dt


def is_exact(u: np.ndarray) -> bool:
    """True when the samples carry no white noise (a specified motion, not a measured one)."""
    s4, s6 = _difference_sigma(u, 4), _difference_sigma(u, 6)
    return s4 <= EXACT or s6 < WHITE * s4


def _difference_sigma(u: np.ndarray, order: int) -> float:
    # white noise of σ: the order-k difference has variance C(2k, k) σ²; the MAD keeps the
    # motion's own (rare, large) differences from counting as noise
    d = np.diff(u, order)
    norm = float(np.sqrt({4: 70.0, 6: 924.0}[order]))
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / norm)


def predict(identified: IdentifiedModel, drive: BaseMotion, level: float = 95.0,
            draws: int = DRAWS, seed: int = 0) -> Prediction:
    """The model's response to `drive`, and the `level` % band of its peaks (0: none)."""
    model = identified.model
    r = simulate(model, drive.motion, duration=drive.duration, dt=drive.dt, t0=drive.t0)
    peaks = tuple(peak(name, getattr(r, name), r.t, UNITS[name]) for name in
                  ("u", "z", "zd", "xdd"))
    forces = tuple(peak(name, f, r.t, "N") for name, f in r.forces.items())
    out = Prediction(r, peaks, forces)
    if level <= 0 or draws <= 0 or not identified.names:
        return out
    rows = parameter_draws(identified, draws, seed)
    b = simulate_batch(model, rows, drive.motion, duration=drive.duration, dt=drive.dt,
                       t0=drive.t0)
    ok = np.all(np.isfinite(b.z) & np.isfinite(b.zd) & np.isfinite(b.xdd), axis=1)
    if not ok.any():
        raise DataError(f"every one of {draws} draws from the covariance diverged")
    q = (50.0 - level / 2.0, 50.0 + level / 2.0)
    band, envelope = {}, {}
    for p in peaks:
        if p.name not in BANDED:
            continue
        series = getattr(b, p.name)[ok]
        # each draw's extreme on the nominal peak's side: a band with one sign throughout
        extreme = series.max(axis=1) if p.value >= 0 else series.min(axis=1)
        lo, hi = np.percentile(extreme, q)
        band[p.name] = (float(lo), float(hi))
        low, high = np.percentile(series, q, axis=0)
        envelope[p.name] = (low, high)
    return Prediction(r, peaks, forces, level, band, envelope, draws, int(np.sum(~ok)))


def peak(name: str, series: np.ndarray, t: np.ndarray, unit: str) -> Peak:
    """The largest magnitude of `series`, signed, and when it occurs."""
    i = int(np.argmax(np.abs(series)))
    return Peak(name, float(series[i]), unit, float(t[i]))


def parameter_draws(identified: IdentifiedModel, draws: int, seed: int = 0) -> np.ndarray:
    """(draws, P) kernel rows (`IsolatorModel.vector()` layout) of the estimated constants
    drawn from N(estimate, covariance); the held ones at their values.

    The mass sensor's gain and delay do not move the mass, so they are left out:
    the marginal of a multivariate normal is its sub-block. Constants that must not
    be negative (mass, dead band, breakaway, stop velocity, every shape constant)
    are clipped at zero; with the fits' relative errors of a few per cent or less
    no draw comes near it.
    """
    model = identified.model
    keep = [i for i, n in enumerate(identified.names) if n not in SENSOR_NAMES]
    C = identified.covariance[np.ix_(keep, keep)]
    # by eigenvectors: a covariance with a direction the data barely determine is
    # positive semi-definite to rounding only, where a Cholesky factor fails
    w, V = np.linalg.eigh(C)
    L = V * np.sqrt(np.clip(w, 0.0, None))
    rng = np.random.default_rng(seed)
    idx = model.vector_index()
    slots = [idx[identified.names[i]] for i in keep]
    rows = np.tile(model.vector(), (draws, 1))
    rows[:, slots] += rng.standard_normal((draws, len(keep))) @ L.T
    rows[:, _nonnegative(model)] = np.maximum(rows[:, _nonnegative(model)], 0.0)
    return rows


def _nonnegative(model: IsolatorModel) -> list[int]:
    idx = model.vector_index()
    return list(range(N_GLOBAL)) + [idx[n] for t in model.terms for n in t.shape_names()]


# the units a motion CSV may give its displacement or acceleration column in
LENGTH_UNITS = ("m", "in", "ft")
ACCELERATION_UNITS = ("m/s^2", "in/s^2", "g")


def base_motion(spec: str) -> BaseMotion:
    """A profile (A, B, C, a TOML file) or a CSV record of u(t) or a(t)."""
    if Path(spec).suffix.lower() == ".csv":
        return read_motion_csv(Path(spec))
    return profile_motion(spec)


def read_motion_csv(path: Path) -> BaseMotion:
    """`t [s],u [in]` (table displacement) or `t [s],a [g]` (base acceleration); other
    columns are ignored. The displacement or acceleration must name its unit."""
    columns, rows = read_csv_table(path)
    if "t" not in columns or not ({"u", "a"} & set(columns)):
        raise DataError(f"{path}: need columns t and u (table displacement) or t and a (base "
                        f"acceleration), found {', '.join(columns) or 'none'}")
    name, allowed = ("u", LENGTH_UNITS) if "u" in columns else ("a", ACCELERATION_UNITS)
    t_unit, unit = columns["t"][1], columns[name][1]
    if t_unit not in (None, "s"):
        raise DataError(f"{path}: time must be in s, header says {t_unit!r}")
    if unit not in allowed:
        raise DataError(f"{path}: column {name} needs its unit in the header, one of "
                        f"{', '.join(allowed)} (e.g. '{name} [{allowed[1]}]'), got {unit!r}")
    t = csv_column(path, rows, columns["t"][0], "t")
    v = csv_column(path, rows, columns[name][0], name) * factor(unit)
    return (sampled_motion if name == "u" else integrated_motion)(t, v, str(path))


__all__ = [
    "BaseMotion",
    "Peak",
    "Prediction",
    "base_motion",
    "check_time",
    "integrated_motion",
    "is_exact",
    "parameter_draws",
    "peak",
    "predict",
    "profile_motion",
    "read_motion_csv",
    "sampled_motion",
]
