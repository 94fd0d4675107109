"""Simulated measured runs from a known isolator: the truth identification tests recover.

The rig's optical displacement sensors are taken as white noise of σ on both
the table u and the mass x (default 0.001 in = 25.4 µm), sampled at 1 kHz.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from analysis.identify.prepare import MeasuredRun
from analysis.model.isolator import IsolatorModel
from analysis.simulate import simulate
from rig.profile import load_profile

SENSOR_NOISE = 2.54e-5  # m, 0.001 in


def synthetic_run(model: IsolatorModel, profile: str, noise: float = SENSOR_NOISE,
                  rate: float = 1000.0, seed: int | np.random.Generator = 0,
                  name: str | None = None) -> MeasuredRun:
    """Run `profile` (A, B, C or a file) through `model`, add sensor noise σ (m) to u and x."""
    rng = np.random.default_rng(seed)
    prof = load_profile(profile)
    r = simulate(model, prof.motion(), duration=prof.duration, dt=1.0 / rate)
    u = r.u + noise * rng.standard_normal(r.t.size)
    x = r.x + noise * rng.standard_normal(r.t.size)
    return MeasuredRun(name or prof.name, r.t, u, x, model.mass)


def synthetic_runs(model: IsolatorModel | Sequence[IsolatorModel],
                   profiles: Sequence[str] = ("A", "B", "C"), noise: float = SENSOR_NOISE,
                   seed: int = 0) -> list[MeasuredRun]:
    """One run per profile; `model` may be one model or one per profile."""
    models = [model] * len(profiles) if isinstance(model, IsolatorModel) else list(model)
    rng = np.random.default_rng(seed)
    return [synthetic_run(m, p, noise, seed=rng) for m, p in zip(models, profiles)]
