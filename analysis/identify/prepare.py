"""A measured run made ready for both stages: x differentiated, the table motion
estimated from the table sensor's own samples, rest dropped."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from analysis.identify.input_error import refine_table
from analysis.identify.run_data import RunData
from analysis.identify.table_motion import TableMotion, estimate_table_motion
from analysis.signals.differentiate import differentiate
from analysis.signals.rest import active_mask


@dataclass(frozen=True)
class MeasuredRun:
    """One base-excited run: table u and mass x absolute displacement; SI."""

    name: str
    t: np.ndarray  # s, uniform
    u: np.ndarray  # m
    x: np.ndarray  # m
    mass: float  # kg
    # s: the largest time offset between the u and x channels the acquisition allows
    # (`channel_skew`); 0: the channels are taken as simultaneous
    skew_limit: float = 0.0
    # (s, m): the table sensor's own samples where it has its own clock (a run file);
    # None: u at t is what the sensor took
    table_samples: tuple[np.ndarray, np.ndarray] | None = None

    def table_channel(self) -> tuple[np.ndarray, np.ndarray]:
        """(t s, u m) as the table sensor took them: what its motion is fitted to."""
        return self.table_samples if self.table_samples is not None else (self.t, self.u)


@dataclass(frozen=True)
class PreparedRun:
    """A run made ready for both stages: derivatives, rest dropped, the input estimated."""

    run: MeasuredRun
    z: np.ndarray  # m, smoothed
    zd: np.ndarray  # m/s
    xdd: np.ndarray  # m/s²
    active: np.ndarray  # bool: samples kept for equation error (rest dropped)
    oe: RunData
    table: TableMotion
    sigma_x: float  # m, the mass sensor's noise
    method: str  # differentiation method used
    settings: dict = field(default_factory=dict)


def prepare(run: MeasuredRun, method: str = "auto") -> PreparedRun:
    """Differentiate x, estimate u(t) and u̇(t), drop rest.

    The table motion is fitted to the table sensor's own samples: its noise is white
    there, where u interpolated onto x's instants has neighbours correlated by the
    clocks' phase, which drifts through a run (`analysis.identify.loading`).
    """
    dt = float(run.t[1] - run.t[0])
    dx = differentiate(run.x, dt, method=method)
    tu, uu = run.table_channel()
    table = refine_table(tu, uu, estimate_table_motion(tu, uu))
    u, ud = table.motion(run.t), table.motion.derivative()(run.t)
    z, zd = dx.x - u, dx.v - ud
    active = active_mask(zd, dt, dx.noise_v)
    oe = RunData(run.name, run.t, table.motion, run.x, dx.noise)
    return PreparedRun(run=run, z=z, zd=zd, xdd=dx.a, active=active, oe=oe, table=table,
                       sigma_x=dx.noise, method=dx.method, settings=dict(dx.settings))
