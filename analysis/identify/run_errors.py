"""How well a model reproduces a measured run: one definition for the fit and the loop.

Both tables a user reads — the fit's per-run errors and the loop's before/after
lines — come from `compare`, so the same run gives the same numbers in both
(two definitions had shown NRMSE ẍ 8.61 % and 11.07 % for one run):

- NRMSE of z, ż, ẍ: RMS(model − measured) / RMS(measured), with z measured as
  x − u from the raw mass samples and ż, ẍ the smoothed derivatives; the model's
  ż and ẍ are differences of its x at the same samples (the loop's prediction is x
  through the sensor's map, and nothing else of it is measured);
- force RMS: m · RMS(ẍ_model − ẍ_measured), the inertial force the model leaves
  unexplained (N inside; lb in the report's units);
- residual / noise: RMS(x_model − x_measured) / σ_x, 1 for a right model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RunError:
    """NRMSE as fractions (None where the run has no derivatives), force RMS in N."""

    z: float
    zd: float | None
    xdd: float | None
    force_rms: float | None
    residual_over_noise: float

    def as_dict(self) -> dict[str, float]:
        return {k: v for k, v in self.__dict__.items() if v is not None}


def compare(mass: float, t: np.ndarray, x_meas: np.ndarray, u: np.ndarray, ud: np.ndarray,
            sigma_x: float, x_model: np.ndarray, zd_meas: np.ndarray | None = None,
            xdd_meas: np.ndarray | None = None) -> RunError:
    """The errors of a model's x against one measured run; of ż and ẍ where the run has
    them (smoothed). All arrays on the run's samples t."""
    n = min(x_meas.size, x_model.size)
    zd = xdd = force = None
    if zd_meas is not None and xdd_meas is not None:
        xd = np.gradient(x_model[:n], t[:n])
        xdd_model = np.gradient(xd, t[:n])
        zd = nrmse(xd - ud[:n], zd_meas[:n])
        xdd = nrmse(xdd_model, xdd_meas[:n])
        force = float(mass * np.sqrt(np.mean((xdd_model - xdd_meas[:n]) ** 2)))
    return RunError(z=nrmse(x_model[:n] - u[:n], x_meas[:n] - u[:n]), zd=zd, xdd=xdd,
                    force_rms=force,
                    residual_over_noise=float(np.sqrt(np.mean((x_model[:n] - x_meas[:n]) ** 2))
                                              / sigma_x))


def nrmse(model: np.ndarray, measured: np.ndarray) -> float:
    return float(np.sqrt(np.mean((model - measured) ** 2)) / np.sqrt(np.mean(measured ** 2)))
