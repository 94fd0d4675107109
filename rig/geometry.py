"""Platform motion → the six actuators: extension, velocity, acceleration and force.

Pure functions: no I/O, no clock. The platform translates rigidly along its x axis
(the report's table moves along one horizontal axis; the actuators hold y and yaw),
so an actuator's extension from mid-stroke is the projection of the platform
displacement on its line of action, n_i · (u, 0) = n_ix u; its velocity and
acceleration follow the same way. That is first order in u/L: a cross actuator of
length L also lengthens by about u²/2L as it swings (6.5 mm for 0.14 m on 1.5 m),
which is neglected here and sits well inside the stroke margin.

Force assumption: the actuators accelerate platform + payload (the payload taken as
rigidly coupled, an upper bound) along x with no y force and no yaw moment about the
platform centre, where the mass centre is assumed. Of the force sets that do so we
take the least-squares one (minimum Σ F_i², the pseudo-inverse): each actuator's share
is in proportion to its line of action's x component when the layout is balanced, as
the default is (the four x actuators take a quarter each, signed; the y actuators
none). Bearing friction, gravity (carried by the bearings) and piston mass are neglected.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from rig.config import RigConfig
from rig.profile import Profile


def x_components(config: RigConfig) -> np.ndarray:
    """(6,) x component of each actuator's line of action (1 pushes +x, −1 pulls)."""
    return config.table.lines_of_action[:, 0].copy()


def actuator_setpoints(config: RigConfig, u: ArrayLike) -> np.ndarray:
    """Extensions from mid-stroke (m), shape (n, 6), for table displacements `u` (m), (n,)."""
    return np.outer(_motion(u, "u"), x_components(config))


def actuator_velocity(config: RigConfig, u_dot: ArrayLike) -> np.ndarray:
    """Extension rates (m/s), shape (n, 6), for table velocities `u_dot` (m/s), (n,)."""
    return np.outer(_motion(u_dot, "u_dot"), x_components(config))


def actuator_acceleration(config: RigConfig, u_ddot: ArrayLike) -> np.ndarray:
    """Extension accelerations (m/s²), (n, 6), for table accelerations `u_ddot` (m/s²), (n,)."""
    return np.outer(_motion(u_ddot, "u_ddot"), x_components(config))


def force_shares(config: RigConfig) -> np.ndarray:
    """(6,) force each actuator supplies (N, + pushes along its line of action) per newton
    of x force on the platform, with zero y force and zero yaw moment (module docstring)."""
    n = config.table.lines_of_action
    r = config.table.positions
    equilibrium = np.vstack([n[:, 0], n[:, 1], r[:, 0] * n[:, 1] - r[:, 1] * n[:, 0]])
    shares = np.linalg.pinv(equilibrium) @ np.array([1.0, 0.0, 0.0])
    shares[np.abs(shares) < 1e-12] = 0.0  # exact zeros for actuators that carry nothing
    return shares


def actuator_force(config: RigConfig, u_ddot: ArrayLike) -> np.ndarray:
    """Actuator forces (N), (n, 6), to give platform + payload the accelerations `u_ddot`
    (m/s², (n,))."""
    total = config.table.moving_mass * _motion(u_ddot, "u_ddot")
    return np.outer(total, force_shares(config))


def setpoint_times(duration: float, rate: float) -> np.ndarray:
    """Setpoint instants (s), (n,): 0, 1/rate, … up to and including `duration` if on the grid."""
    count = int(np.floor(duration * rate + 1e-9)) + 1
    return np.arange(count) / rate


@dataclass(frozen=True, eq=False)
class ActuatorPlan:
    """What the six actuators will be asked to do, one row per setpoint (read-only arrays).

    t (s), (n,); extension (m), velocity (m/s), acceleration (m/s²) and force (N), (n, 6),
    column i for actuator i + 1. Row k is setpoint sample index k.
    """

    profile: str
    rate: float
    t: np.ndarray
    extension: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    force: np.ndarray


def actuator_plan(config: RigConfig, profile: Profile) -> ActuatorPlan:
    """The whole plan of `profile` sampled at the configured setpoint rate."""
    rate = config.rates.setpoint
    t = setpoint_times(profile.duration, rate)
    u, u_dot, u_ddot = profile.sample(t)
    arrays = (t, actuator_setpoints(config, u), actuator_velocity(config, u_dot),
              actuator_acceleration(config, u_ddot), actuator_force(config, u_ddot))
    for a in arrays:
        a.flags.writeable = False
    return ActuatorPlan(profile.name, rate, *arrays)


def _motion(values: ArrayLike, name: str) -> np.ndarray:
    a = np.asarray(values, dtype=float)
    if a.ndim != 1:
        raise ValueError(f"{name} must be a 1-D array of table motion, got shape {a.shape}")
    return a
