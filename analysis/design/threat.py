"""A threat: the base motion an isolator must protect its equipment from.

`A`, `B`, `C` or a profile TOML file (the commanded step pulses), or a CSV record:
`t [s],u [in]` (table displacement, measured or specified) or `t [s],a [g]` (base
acceleration, integrated twice from rest). The CSV is read as `sim response --motion`
reads it (docs/predict.md), through the same analysis helpers, so a record one
command accepts the other does too; time with gaps or going backwards, a column
without its unit, a cell that is not a number are refused with one line.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.predict import BaseMotion, profile_motion, read_motion_csv


@dataclass(frozen=True)
class Threat:
    """A named base motion (SI) and what the design's default box is scaled by."""

    name: str
    drive: BaseMotion

    def times(self) -> np.ndarray:
        """The drive's own output grid (s)."""
        d = self.drive
        return d.t0 + d.dt * np.arange(round(d.duration / d.dt) + 1)

    def peak_velocity(self) -> float:
        """Largest |u̇| (m/s)."""
        return float(np.max(np.abs(self.drive.motion(self.times(), 1))))

    def peak_acceleration(self) -> float:
        """Largest |ü| (m/s²)."""
        return float(np.max(np.abs(self.drive.motion(self.times(), 2))))


def read_threat(spec: str) -> Threat:
    """A profile (A, B, C, a TOML file) or a CSV record of u(t) or a(t)."""
    path = Path(spec)
    if path.suffix.lower() == ".csv":
        return Threat(path.stem, read_motion_csv(path))
    drive = profile_motion(spec)
    return Threat(drive.source.removeprefix("profile "), drive)
