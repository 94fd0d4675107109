"""A profile as Setup shows it: loaded, its table motion sampled, its limits checked.

Pure: no Textual, no I/O beyond reading the profile file, so it is tested as data.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rig.config import RigConfig
from rig.errors import LimitError, RigError
from rig.limits import QUANTITIES, Margins, check_all
from rig.paths import data_file
from rig.profile import BUILTIN, Profile, load_profile
from rig.units import from_si, us_unit
from rig.wire.bus_load import check_bus_load

PREVIEW_POINTS = 200  # samples of u(t) in the preview plot


@dataclass(frozen=True)
class ProfileChoice:
    """`spec` (A, B, C or a path) checked against `config`.

    profile/text are None/"" if it could not be read (`error`); `refused` is the
    LimitError's message when a limit (or the bus budget) refuses it; margins are
    there whenever the plan could be computed, refused or not.
    """

    spec: str
    profile: Profile | None
    text: str
    margins: Margins | None
    refused: str = ""
    error: str = ""

    @property
    def ok(self) -> bool:
        return self.profile is not None and not self.refused and not self.error

    @property
    def label(self) -> str:
        return self.profile.name if self.profile is not None else self.spec

    def preview(self, points: int = PREVIEW_POINTS) -> tuple[np.ndarray, np.ndarray]:
        """(t s, u m) of the commanded table motion; empty if there is no profile."""
        if self.profile is None:
            return np.empty(0), np.empty(0)
        t = np.linspace(0.0, self.profile.duration, points)
        return t, self.profile.sample(t)[0]


def choose(config: RigConfig, spec: str) -> ProfileChoice:
    """Load and check `spec`; never raises for a bad profile (the reason is in the result)."""
    try:
        profile = load_profile(spec)
        text = profile_text(spec)
    except (RigError, OSError, ValueError) as exc:
        return ProfileChoice(spec, None, "", None, error=str(exc).splitlines()[0])
    try:
        margins = check_all(config, profile)
        check_bus_load(config)
    except LimitError as exc:
        return ProfileChoice(spec, profile, text, getattr(exc, "margins", None), refused=str(exc))
    return ProfileChoice(spec, profile, text, margins)


def profile_text(spec: str) -> str:
    """The TOML text of `spec` as written into the run file."""
    builtin = spec.upper() in BUILTIN and not Path(spec).exists()
    path = data_file("profiles", f"{spec.upper()}.toml") if builtin else Path(spec)
    return path.read_text(encoding="utf-8")


def margin_rows(margins: Margins, units: str) -> list[tuple[str, list[tuple[str, bool]]]]:
    """Per actuator: (name, [(cell text, ok) per quantity]); a cell is `peak margin%`."""
    rows = []
    for act in sorted({m.actuator for m in margins.items}):
        cells = []
        name = ""
        for q in QUANTITIES:
            m = margins.get(act, q)
            name = f"{m.actuator} {m.name}"
            unit = m.unit if units == "si" else us_unit(m.unit)
            cells.append((f"{_peak(from_si(m.peak, unit), unit)} {m.fraction:>3.0%}", m.ok))
        rows.append((name, cells))
    return rows


def quantity_units(units: str) -> list[str]:
    """Column units of `margin_rows` for `units` "us" or "si"."""
    si = {"stroke": "m", "velocity": "m/s", "acceleration": "m/s^2", "force": "N"}
    return [si[q] if units == "si" else us_unit(si[q]) for q in QUANTITIES]


def _peak(value: float, unit: str) -> str:
    if unit in ("m", "m/s"):
        return f"{value:.3f}"
    if unit in ("in", "in/s", "m/s^2"):
        return f"{value:.1f}" if unit != "in" else f"{value:.2f}"
    return f"{value:,.0f}"
