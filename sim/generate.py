"""`sim generate`: measured-looking runs from the simulated rig, fast, as CSV.

The runs of a campaign are simulated back to back in one integration, with a
rest between them, so that a stateful effect carries from one run to the next
as it would on the bench (the fluid the report's run C found warm was heated by
the runs before it). Each run is then cut out and measured: the table and mass
sensors add white noise and quantise to their resolution, and sensor effects
distort the mass channel. The CSV holds only what a rig would have logged,
`t,u,x`; the injected effects are written nowhere.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.model.isolator import IsolatorModel
from analysis.model.report_constants import report_model
from analysis.simulate import simulate
from rig.profile import Profile, Segment, load_profile
from rig.units import factor
from sim.effects import Effect, distort_mass_sensor, with_effects

SENSOR_NOISE = 0.001 * 0.0254  # m rms, one optical sensor sample (data/rig.toml)
SENSOR_RESOLUTION = 1.0e-6  # m per count (data/rig.toml)
PAUSE = 5.0  # s of rest between runs
REPOSITION = 1.0  # s, ramp between runs that do not start where the last one ended


@dataclass(frozen=True)
class GeneratedRun:
    """One measured run and the truth behind it; SI, arrays (n,)."""

    name: str
    t: np.ndarray  # s from the run's start
    u: np.ndarray  # measured table displacement, m
    x: np.ndarray  # measured mass displacement, m
    u_true: np.ndarray
    x_true: np.ndarray


def campaign_profile(profiles: Sequence[Profile], pause: float = PAUSE
                     ) -> tuple[Profile, list[tuple[float, float]]]:
    """All profiles as one motion with rests between; and each run's (start, end) in it (s)."""
    segments: list[Segment] = []
    spans = []
    t, u = 0.0, profiles[0].start
    for i, p in enumerate(profiles):
        if i:
            segments.append(Segment(pause))
            t += pause
            if p.start != u:
                segments.append(Segment(REPOSITION, p.start))
                t += REPOSITION
        spans.append((t, t + p.duration))
        segments.extend(p.segments)
        t += p.duration
        for s in p.segments:
            if s.is_ramp:
                u = s.target
    return Profile("campaign", tuple(segments), profiles[0].start), spans


def generate_campaign(runs: Sequence[str] = ("A", "B", "C"), effects: Sequence[Effect] = (),
                      model: IsolatorModel | None = None, noise: float = SENSOR_NOISE,
                      seed: int = 0, pause: float = PAUSE, dt: float = 1e-3
                      ) -> list[GeneratedRun]:
    """Simulate the runs back to back with `effects` and measure them with noisy sensors."""
    truth = with_effects(model or report_model("average"), tuple(effects))
    profiles = [load_profile(r) for r in runs]
    whole, spans = campaign_profile(profiles, pause)
    r = simulate(truth, whole.motion(), dt=dt)
    x_seen = distort_mass_sensor(r.t, r.x, tuple(effects))
    rng = np.random.default_rng(seed)
    out = []
    for p, (t0, t1) in zip(profiles, spans):
        i0, i1 = round(t0 / dt), round(t1 / dt) + 1
        out.append(GeneratedRun(
            name=p.name, t=r.t[i0:i1] - r.t[i0],
            u=measure(r.u[i0:i1], noise, rng), x=measure(x_seen[i0:i1], noise, rng),
            u_true=r.u[i0:i1], x_true=r.x[i0:i1]))
    return out


def measure(true: np.ndarray, noise: float, rng: np.random.Generator,
            resolution: float = SENSOR_RESOLUTION) -> np.ndarray:
    """A displacement as an optical sensor reports it: white noise, then whole counts."""
    noisy = true + rng.normal(0.0, noise, true.shape) if noise > 0 else true
    return np.round(noisy / resolution) * resolution


def write_run_csv(run: GeneratedRun, path: Path, units: str = "m") -> None:
    """`t [s],u [in],x [in]`: displacements in `units` (m or in), named in the header
    so that no reader has to guess them."""
    scale = 1.0 / factor(units)
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(["t [s]", f"u [{units}]", f"x [{units}]"])
        for row in zip(run.t, run.u * scale, run.x * scale):
            w.writerow([f"{row[0]:.6f}", f"{row[1]:.9g}", f"{row[2]:.9g}"])
