"""Step-pulse table motions: the report's runs A, B, C and any profile in TOML.

A profile is a start position and a list of segments, each a *hold* (stay put
for a duration) or a *ramp* (move to a target in a duration). A ramp follows
the minimum-jerk curve

    u(τ) = u₀ + (u₁ − u₀)(10τ³ − 15τ⁴ + 6τ⁵),   τ = (t − t₀)/T ∈ [0, 1]

which starts and ends with zero velocity *and* zero acceleration, so the
commanded acceleration is continuous (servo-hydraulic actuators cannot step
their acceleration either). For a move Δ in T it peaks at 1.875 Δ/T velocity
and 5.774 Δ/T² acceleration, the least of the common smooth ramps (cycloidal:
2 Δ/T and 6.283 Δ/T²). The stated rise time is the full ramp duration T.

The motion is an exact piecewise quintic (scipy `PPoly`), which the simulator
evaluates without interpolation error. Pure functions: no I/O but `load_profile`.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.interpolate import PPoly

from rig.errors import ConfigError
from rig.paths import data_file
from rig.units import factor

BUILTIN = ("A", "B", "C")
LENGTH_UNITS = ("in", "m", "ft")
PEAK_VELOCITY_FACTOR = 1.875  # max of d/dτ (10τ³ − 15τ⁴ + 6τ⁵)
PEAK_ACCELERATION_FACTOR = 10 / np.sqrt(3)  # max of d²/dτ², 5.774
MAX_DURATION_S = 3600.0  # a whole profile, as one segment: longer is a mistake or hostile
MAX_POSITION_M = 1000.0  # no table travels a kilometre: a bigger position is not a typo of ours


@dataclass(frozen=True)
class Segment:
    """A hold (target is None) or a ramp to `target` (m), lasting `duration` (s)."""

    duration: float
    target: float | None = None

    @property
    def is_ramp(self) -> bool:
        return self.target is not None


@dataclass(frozen=True)
class Profile:
    """A table displacement command; SI."""

    name: str
    segments: tuple[Segment, ...]
    start: float = 0.0
    description: str = ""

    @property
    def duration(self) -> float:
        return float(sum(s.duration for s in self.segments))

    def motion(self) -> PPoly:
        """u(t) as an exact piecewise quintic in local time (PPoly), t from 0."""
        breaks = [0.0]
        coefs = []
        u = self.start
        for seg in self.segments:
            T = seg.duration
            if seg.is_ramp:
                d = seg.target - u
                coefs.append([6 * d / T**5, -15 * d / T**4, 10 * d / T**3, 0.0, 0.0, u])
                u = seg.target
            else:
                coefs.append([0.0, 0.0, 0.0, 0.0, 0.0, u])
            breaks.append(breaks[-1] + T)
        return PPoly(np.array(coefs).T, np.array(breaks))

    def sample(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """u, u̇, ü at times t (s), held at the ends."""
        m = self.motion()
        tc = np.clip(t, 0.0, self.duration)
        return m(tc), m(tc, 1), m(tc, 2)

    def peaks(self) -> dict[str, float]:
        """Largest |displacement| (m), |velocity| (m/s) and |acceleration| (m/s²)."""
        disp, vel, acc = abs(self.start), 0.0, 0.0
        u = self.start
        for seg in self.segments:
            if seg.is_ramp:
                d = abs(seg.target - u)
                vel = max(vel, PEAK_VELOCITY_FACTOR * d / seg.duration)
                acc = max(acc, PEAK_ACCELERATION_FACTOR * d / seg.duration**2)
                u = seg.target
                disp = max(disp, abs(u))
        return {"displacement": disp, "velocity": vel, "acceleration": acc}


def parse_profile(doc: dict, source: str) -> Profile:
    """Build a Profile from a parsed TOML document; ConfigError names the field."""
    unit = doc.get("units", "in")
    if unit not in LENGTH_UNITS:
        raise ConfigError(source, "units", f"must be one of {LENGTH_UNITS}, got {unit!r}")
    scale = factor(unit)
    name = doc.get("name", Path(source).stem)
    start = _position(doc.get("start", 0.0), scale, source, "start")
    raw = doc.get("segment")
    if not isinstance(raw, list) or not raw:
        raise ConfigError(source, "segment", "needs at least one [[segment]] table")
    segments = []
    for i, s in enumerate(raw, start=1):
        where = f"segment {i}"
        if not isinstance(s, dict):
            raise ConfigError(source, where, "must be a table")
        unknown = set(s) - {"hold", "ramp_to", "duration"}
        if unknown:
            raise ConfigError(source, where, f"unknown keys {sorted(unknown)}")
        if "hold" in s:
            if "ramp_to" in s or "duration" in s:
                raise ConfigError(source, where, "a hold takes only 'hold = seconds'")
            segments.append(Segment(_duration(s["hold"], source, f"{where}.hold")))
        elif "ramp_to" in s:
            if "duration" not in s:
                raise ConfigError(source, f"{where}.duration", "a ramp needs a duration (s)")
            segments.append(Segment(_duration(s["duration"], source, f"{where}.duration"),
                                    _position(s["ramp_to"], scale, source, f"{where}.ramp_to")))
        else:
            raise ConfigError(source, where, "needs 'hold' or 'ramp_to' and 'duration'")
    total = sum(seg.duration for seg in segments)
    if total > MAX_DURATION_S:  # the plan is sampled at the setpoint rate: bound its memory
        raise ConfigError(source, "segment", f"{total:g} s in all is longer than "
                          f"{MAX_DURATION_S:g} s; refusing")
    return Profile(name=str(name), segments=tuple(segments), start=start,
                   description=str(doc.get("description", "")))


def _number(v: object, source: str, field: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
        raise ConfigError(source, field, f"must be a finite number, got {v!r}")
    return float(v)


def _position(v: object, scale: float, source: str, field: str) -> float:
    """A position in m; absurd magnitudes are refused here, before any limit arithmetic."""
    x = _number(v, source, field) * scale
    if abs(x) > MAX_POSITION_M:
        raise ConfigError(source, field, f"{v!r} is beyond ±{MAX_POSITION_M:g} m; refusing")
    return x


def _duration(v: object, source: str, field: str) -> float:
    d = _number(v, source, field)
    if d <= 0:
        raise ConfigError(source, field, f"must be > 0 s, got {d}")
    if d > 3600:
        raise ConfigError(source, field, f"{d} s is longer than an hour; refusing")
    return d


def load_profile(spec: str | Path) -> Profile:
    """A built-in run ('A', 'B', 'C') or a profile TOML file."""
    if str(spec).upper() in BUILTIN and not Path(str(spec)).exists():
        path = data_file("profiles", f"{str(spec).upper()}.toml")
    else:
        path = Path(spec)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(str(path), "", "no such profile file (built-in runs: A, B, C)") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(str(path), "", f"cannot read: {e}") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(str(path), "", f"not valid TOML: {e}") from None
    except RecursionError:  # tomllib recurses per nesting level: a hostile file
        raise ConfigError(str(path), "", "not valid TOML: nested too deeply") from None
    return parse_profile(doc, str(path))
