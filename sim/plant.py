"""The simulated table and isolator: six servo actuators, a rigid platform, the mass on Eq 10.

Time runs on the host's monotonic clock from `t0`, on a fixed grid of `dt` (1 ms,
the simulator's own output interval). The plant is advanced in chunks of
`chunk` steps (20 ms), computed *ahead* of real time by one chunk, so a sensor
sampling at host time t always finds the state at t already computed and
interpolates between grid points instead of extrapolating.

Why chunked calls into `analysis.simulate` rather than a Python RK4 per step:
the compiled integrator is the one the analysis fits with (dead band, static
friction with event location, stateful terms), so the simulated rig and the
analysis cannot disagree about the model; one call per 20 ms costs ~0.3 ms.
Each chunk's table motion is the quintic Hermite through the actuators' positions,
velocities and accelerations at the grid points (C² across grid points and
chunks), padded by one step each side, and the state (z, ż and the terms'
internal states) carries from one chunk into the next.

Why C², padded: the integrator is RK4 on fixed steps whose last stage reads the
table acceleration at the step's end, a grid point; a cubic Hermite's ü jumps
there (and the first-order lag's own ü jumps wherever the target's slope
changes), and at a chunk's first and last point the integrator holds the motion
(ü = 0). Each of those stages was wrong by the jump, always the same sign along
a ramp: measured on run A, the served x was 1.6 mm off the converged solution
of the same plant by the end of the first ramp and 40 mm after the return, run
C 0.45 mm RMS, which no model of the table motion can reproduce. One ü per grid
point makes the motion C², and the quintic still passes through the exact
positions and velocities, so each step's velocity change is the servo's own.

The actuators are servo-hydraulic: position follows the setpoint with a
first-order lag `tau` and the servovalve's velocity limit (flow / area).
Fault injection: `Plant.stick(j, t)` sticks actuator j's servovalve from host
time t on (no flow: the piston stops wherever it is, whatever the target).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PPoly

from analysis.model.isolator import IsolatorModel
from analysis.model.terms import kind
from analysis.simulate import simulate
from analysis.simulate.motion import quintic_at, quintic_hermite
from sim.hermite import cubic_at

SERVO_TAU = 0.005  # s, first-order lag of a servo-hydraulic actuator (~30 Hz bandwidth)
DT = 1e-3  # s, plant grid
CHUNK = 20  # steps per call into the integrator
SUBSTEPS = 4  # RK4 steps per grid step: the lag's ü kinks inside a step cost 7.7 µm RMS of x
# on run A at 1, 2.5 µm at 4 (against 0.05 ms steps); 4 cost ~10 % more than 1 per chunk


@dataclass
class ServoAxis:
    """One actuator's motion state: extension (m) and its rate (m/s) at the last grid point."""

    max_velocity: float  # m/s
    position: float = 0.0
    velocity: float = 0.0
    target: float | None = None  # m, the last step's target
    stuck: bool = False  # a stuck servovalve: no flow, the piston stays put

    acceleration: float = 0.0  # m/s², p'' at the last grid point (end of the last step)

    def step(self, target: float, dt: float, tau: float = SERVO_TAU) -> None:
        """Advance one step toward `target` (m): first-order lag, then the rate limit.

        The target moves linearly from the last step's to this one (the controller's
        C² interpolation of its setpoints, sampled every step), and the lag
        p' = (r − p)/τ is solved exactly for that ramp. Position and velocity are then
        continuous across grid points, as the Hermite the integrator reads needs:
        holding the target over the step makes the velocity jump by Δr/τ at every
        point, which the cubic turns into a table acceleration of hundreds of m/s²
        (measured: 760 m/s² on run A's 20 m/s² ramp).
        """
        if self.stuck:
            self.velocity, self.acceleration, self.target = 0.0, 0.0, target
            return
        r0 = self.position if self.target is None else self.target
        slope = (target - r0) / dt
        decay = math.exp(-dt / tau)
        new = target - slope * tau + (self.position - r0 + slope * tau) * decay
        limit = self.max_velocity * dt
        self.position += min(max(new - self.position, -limit), limit)
        rate = (target - self.position) / tau  # p' at the end of the step
        self.velocity = min(max(rate, -self.max_velocity), self.max_velocity)
        # p'' = (r' − p')/τ at the end of the step (its left limit); 0 while rate-limited
        self.acceleration = (slope - rate) / tau if rate == self.velocity else 0.0
        self.target = target


class Plant:
    """Table + isolator + mass, advanced by `advance_to(t)`; thread-safe readers.

    targets: host time (s) → (6,) actuator targets (m); called on the plant thread.
    x_components: (6,) n_ix of each actuator's line of action.
    """

    def __init__(self, model: IsolatorModel, targets: Callable[[float], np.ndarray],
                 x_components: np.ndarray, max_velocity: np.ndarray, t0: float,
                 dt: float = DT, chunk: int = CHUNK) -> None:
        self.model, self._targets, self.dt, self.chunk = model, targets, dt, chunk
        self._nx = [float(v) for v in x_components]
        self._norm = sum(v * v for v in self._nx)
        self.axes = [ServoAxis(float(v)) for v in max_velocity]
        self.t0 = t0
        self._z, self._zd = 0.0, 0.0
        self._s = np.zeros(len(model.terms))
        self._stateful = [j for j, t in enumerate(model.terms) if kind(t.kind).has_state]
        self._lock = threading.Lock()
        self._steps = 0  # grid points computed so far beyond t0
        # the whole history (1 kHz × a few minutes is small): the truth the tests compare to
        self._t, self._u, self._x = [t0], [0.0], [0.0]
        self._ud, self._udd, self._xd = [0.0], [0.0], [0.0]  # for interpolation in `at`
        self._ext: list[np.ndarray] = [np.zeros(6)]
        self._stuck_from: list[float | None] = [None] * len(self.axes)
        self._advancing = threading.RLock()  # one thread computes chunks at a time

    def stick(self, j: int, t: float) -> float:
        """Stick axis j's servovalve from host time `t` (s) on; returns when it takes effect.

        Grid points already computed (up to one chunk ahead) keep their motion, so the
        fault begins at `t` or at the first grid point not yet computed, whichever is later.
        """
        with self._lock:
            start = max(t, self.computed_until)
            self._stuck_from[j] = start
        return start

    @property
    def computed_until(self) -> float:
        """Host time (s) of the last computed grid point."""
        return self.t0 + self._steps * self.dt

    def advance_to(self, t: float) -> None:
        """Compute chunks until the grid covers host time `t` (s); any thread."""
        with self._advancing:
            while self.computed_until < t:
                self._chunk()

    def _chunk(self) -> None:
        n, dt = self.chunk, self.dt
        ts = self.computed_until + dt * np.arange(n + 1)
        u, ud, udd = np.empty(n + 1), np.empty(n + 1), np.empty(n + 1)
        ext = np.empty((n, 6))
        u[0], ud[0], udd[0] = self._table()
        for k in range(1, n + 1):
            target = self._targets(float(ts[k]))
            for axis, r, stuck in zip(self.axes, target, self._stuck_from):
                if stuck is not None and ts[k] >= stuck:
                    axis.stuck = True
                axis.step(float(r), dt)
            ext[k - 1] = [a.position for a in self.axes]
            u[k], ud[k], udd[k] = self._table()
        motion = _quintic(ts, u, ud, udd)
        r = simulate(self.model, motion, duration=n * dt, dt=dt, t0=float(ts[0]),
                     substeps=SUBSTEPS, z0=self._z, zd0=self._zd, s0=self._s)
        self._z, self._zd = float(r.z[-1]), float(r.zd[-1])
        for j, term in ((j, self.model.terms[j]) for j in self._stateful):
            self._s[j] = r.states[term.name][-1]
        with self._lock:
            self._t.extend(ts[1:].tolist())
            self._u.extend(u[1:].tolist())
            self._x.extend((r.z[1:] + u[1:]).tolist())
            self._ud.extend(ud[1:].tolist())
            self._udd.extend(udd[1:].tolist())
            self._xd.extend((r.zd[1:] + ud[1:]).tolist())
            self._ext.extend(ext)
            self._steps += n

    def _table(self) -> tuple[float, float, float]:
        """Platform x displacement, velocity and acceleration: least squares over the
        actuators' extensions."""
        n = self._nx  # plain floats: numpy costs more than it saves on six numbers
        u = sum(w * a.position for w, a in zip(n, self.axes))
        v = sum(w * a.velocity for w, a in zip(n, self.axes))
        acc = sum(w * a.acceleration for w, a in zip(n, self.axes))
        return u / self._norm, v / self._norm, acc / self._norm

    def at(self, t: float) -> tuple[float, float]:
        """(u, x) in m at host time `t` (s), interpolated on the grid; held before its start.

        u is the quintic the isolator was driven with, x the cubic Hermite through the
        mass's position and velocity: linear interpolation was up to h²ü/8 off
        (7 µm in run C's ramp, a quarter of the sensor noise, always the same sign).

        A sensor asking past the computed grid (the loop thread that keeps it a chunk
        ahead was starved of CPU) computes the missing chunks itself: holding the last
        value instead made a loaded machine log 25 ms stairs with 10 mm risers.
        """
        if t > self.computed_until:
            self.advance_to(t)
        with self._lock:
            i = (t - self.t0) / self.dt
            k = min(max(math.floor(i), 0), len(self._t) - 2) if len(self._t) > 1 else 0
            if len(self._t) == 1:
                return self._u[0], self._x[0]
            w = min(max(i - k, 0.0), 1.0)
            h = self.dt
            u = quintic_at(w, h, self._u[k], self._ud[k], self._udd[k],
                            self._u[k + 1], self._ud[k + 1], self._udd[k + 1])
            x = cubic_at(w, h, self._x[k], self._xd[k], self._x[k + 1], self._xd[k + 1])
            return u, x

    def extensions(self, t: float) -> np.ndarray:
        """(6,) actuator extensions (m) at the grid point at or before host time `t` (s)."""
        with self._lock:
            k = min(max(math.floor((t - self.t0) / self.dt), 0), len(self._ext) - 1)
            return self._ext[k].copy()

    def history(self) -> dict[str, np.ndarray]:
        """Every grid point so far: t (host s), u, x (m), extensions (n, 6) (m)."""
        with self._lock:
            return {"t": np.array(self._t), "u": np.array(self._u), "x": np.array(self._x),
                    "extension": np.array(self._ext)}


def warm_up(model: IsolatorModel) -> None:
    """Make the plant's first call to the integrator now, before anything is served.

    In a new environment that call compiles (or loads) the numba kernel, which takes
    seconds; made from the first chunk it would stall the sensors past the rig's
    liveness limit and abort the first run.
    """
    ts = DT * np.arange(CHUNK + 1)
    zeros = np.zeros(CHUNK + 1)
    simulate(model, _quintic(ts, zeros, zeros, zeros), duration=CHUNK * DT, dt=DT, t0=0.0, z0=0.0,
             zd0=0.0, s0=np.zeros(len(model.terms)))


def _quintic(t: np.ndarray, u: np.ndarray, ud: np.ndarray, udd: np.ndarray) -> PPoly:
    """The quintic Hermite through (t, u, u̇, ü) as a PPoly, padded by one step each side.

    C²: the integrator's last RK4 stage of a step reads ü at the next piece's start,
    which equals this piece's end. The padding (the first and last pieces continued)
    keeps the chunk's ends inside the breaks, where the integrator would hold u.
    """
    h = np.diff(t)
    c = quintic_hermite(t, u, ud, udd).c
    first = _shifted(c[:, 0], -h[0])
    last = _shifted(c[:, -1], h[-1])
    return PPoly(np.column_stack([first, c, last]), np.r_[t[0] - h[0], t, t[-1] + h[-1]])


def _shifted(c: np.ndarray, a: float) -> np.ndarray:
    """Coefficients (highest first) of q(y) = p(y + a) for p with coefficients `c`."""
    out = np.zeros_like(c)
    for coef in c:  # Horner on polynomials: q = q·(y + a) + coef
        out = np.r_[out[1:], 0.0] + a * out
        out[-1] += coef
    return out
