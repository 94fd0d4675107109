"""Output-error fitting for the loop: signed parameters, a sensor map, warm fluid.

A *hypothesis* is an isolator model plus the mass sensor's output map
x_meas(t) = (1 + g) x(t − d). Its prediction of a campaign simulates the runs
in the order given and carries the fluid temperature of a thermal term from
each run into the next (the rests between runs are taken as short against the
casing's cooling time, minutes). The fit works on parameters divided by their
size, so signed effects (an offset, a delay, a viscosity that falls) fit as
easily as positive ones, and returns the covariance from the Jacobian with the
residual's autocorrelation accounted for: residual samples 1 ms apart are not
independent, and pretending they were would make every effect "significant".
The loop's refits (`refit_free`) size and bound each parameter by what it is: a
candidate by its typical size, Eq 10's constants by their values (a dead band the base
fit closed free to open again).

The score test asks, from the fitted Jacobian alone, how much a candidate
parameter added at zero would reduce the residual after every fitted
parameter readjusts (the Lagrange-multiplier test): the cheap first look that
decides which candidates earn a full refit.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numba
import numpy as np
from scipy.interpolate import PPoly
from scipy.optimize import least_squares

from analysis.identify.regressors import state_after
from analysis.identify.run_data import RunData, start_state
from analysis.loop.budget import spend
from analysis.loop.candidates import (
    SENSOR_DELAY,
    SENSOR_GAIN,
    SENSOR_PARAMETERS,
    Candidate,
    shape_floor,
)
from analysis.model.isolator import IsolatorModel
from analysis.model.terms import BOUC_WEN
from analysis.simulate import RunSetup, simulate_batch, simulate_runs
from analysis.simulate.tangent import runs_sensitivity

MAX_NFEV = 40  # evaluations of a refit: past it the step is seldom worth its time
UNSTABLE = 1e6  # residual, in noise units, given to samples of a run that diverged
FD_STEP = 3e-3  # of a parameter's size: above the integrator's noise, below curvature
DEAD_BAND_BOUNDS = (1e-5, 0.1)  # m, where a refit frees δ
DEAD_BAND_SCALE = 1e-3  # m


@dataclass(frozen=True)
class Hypothesis:
    """A model of the isolator and of the mass sensor."""

    model: IsolatorModel
    sensor_gain: float = 0.0  # g, 1
    sensor_delay: float = 0.0  # d, s
    # each run starts with the terms' internal states (Bouc–Wen r, fluid θ) at zero, as
    # after a long rest or a re-zeroed rig, rather than where the run before left them
    fresh_states: bool = False

    def value(self, name: str) -> float:
        if name in SENSOR_PARAMETERS:
            return getattr(self, name)
        return self.model.parameters()[name]

    def with_values(self, values: dict[str, float]) -> Hypothesis:
        sensor = {k: v for k, v in values.items() if k in SENSOR_PARAMETERS}
        rest = {k: v for k, v in values.items() if k not in SENSOR_PARAMETERS}
        return replace(self, model=self.model.with_parameters(**rest), **sensor)


def predict(h: Hypothesis, runs: Sequence[RunData], names: Sequence[str] = (),
            rows: np.ndarray | None = None) -> list[np.ndarray]:
    """Predicted x_meas (R, n_k) of each run for R value rows of `names` (default: h itself)."""
    names = tuple(names)
    rows = np.zeros((1, 0)) if rows is None else np.atleast_2d(rows)
    idx = h.model.vector_index()
    V = np.tile(h.model.vector(), (rows.shape[0], 1))
    gain = np.full(rows.shape[0], h.sensor_gain)
    delay = np.full(rows.shape[0], h.sensor_delay)
    for j, n in enumerate(names):
        if n == SENSOR_GAIN:
            gain = rows[:, j]
        elif n == SENSOR_DELAY:
            delay = rows[:, j]
        else:
            V[:, idx[n]] = rows[:, j]
    # the fluid temperature a run leaves is carried by each row's own heating and cooling
    # time, which a refit frees: carried by the start's, a refit could move τ a
    # thousandfold while every trial's next run began at the temperature the start's τ
    # left, and the fitted model predicted alone was not the model fitted
    thermal = [(j, [V[:, idx[n]] for n in t.shape_names()[:2]])
               for j, t in enumerate(h.model.terms) if t.kind == "thermal_damper"]
    # the seals' state is carried by `h`'s loop shape for every row, a refit's trial a and
    # b acting within runs only (a known gap): carried by each row's own, two unseen
    # Bouc–Wen campaigns (one with a sensor gain) were named nothing where they were
    # named right (1.48 x noise for the pair), the refit of the library's loop against
    # another's shape ending insignificant
    hysteretic = [(j, t.shape) for j, t in enumerate(h.model.terms) if t.kind == "bouc_wen"]
    S0 = np.zeros((rows.shape[0], len(h.model.terms)))
    if not carries_states(h):  # each run starts from zero states
        return _sensed(runs, gain, delay, _independent_runs(h, runs, V, S0, gain))
    out = []
    z_end = None
    for run in runs:
        # each row starts at rest where its own sensor map says the mass was
        x = np.empty((V.shape[0], run.t.size))
        groups = _start_groups(run, gain, h.model.dead_band)
        if z_end is not None:
            z_start = np.empty_like(z_end)
            for z0, _, rows_z0 in groups:
                z_start[rows_z0] = z0
            for j, shape in hysteretic:  # the seals follow the mass's settling between runs
                S0[:, j] = hysteresis_along(S0[:, j], z_end, z_start, shape)
        zd_all = np.empty_like(x)
        for z0, zd0, rows_z0 in groups:
            b = simulate_batch(h.model, V[rows_z0], run.motion, duration=run.t[-1] - run.t[0],
                               dt=run.dt, t0=run.t[0], s0=S0[rows_z0], z0=z0, zd0=zd0)
            x[rows_z0] = b.z + b.u
            zd_all[rows_z0] = b.zd
            spend(b.rk4_steps)
        out += _sensed([run], gain, delay, [x])
        for j, (heating, tau) in thermal:
            S0[:, j] = fluid_temperature_after(S0[:, j], zd_all, run.dt, heating, tau)
        for j, shape in hysteretic:  # the seals stay loaded while the mass rests
            S0[:, j] = hysteresis_after(S0[:, j], zd_all, run.dt, shape)
        z_end = x[:, -1] - run.motion(run.t[-1])
        if hysteretic:  # the mass swings on after the run is cut: follow it to rest
            z_end = _settle(h, V, S0, hysteretic, z_end, zd_all[:, -1],
                            float(run.motion(run.t[-1])), run.dt)
    return out


def _independent_runs(h: Hypothesis, runs: Sequence[RunData], V: np.ndarray, S0: np.ndarray,
                      gain: np.ndarray) -> list[np.ndarray]:
    """Each run's x (R, n) where no run starts from the state another left: all runs in
    one parallel call, so the cores share every run's rows (run by run, a residual of
    one row per run left a core idle for each of the three). Each row is integrated on
    its own: the same numbers as run by run, bit for bit."""
    setups, vectors, states, rows_of = [], [], [], []
    for k, run in enumerate(runs):
        for z0, zd0, chosen in _start_groups(run, gain, h.model.dead_band):
            setups.append(RunSetup(run.motion, run.t[-1] - run.t[0], run.dt, run.t[0], z0, zd0))
            vectors.append(V[chosen])
            states.append(S0[chosen])
            rows_of.append((k, chosen))
    x = [np.empty((V.shape[0], run.t.size)) for run in runs]
    for (k, chosen), b in zip(rows_of, simulate_runs(h.model, setups, vectors, s0=states)):
        x[k][chosen] = b.z + b.u
        spend(b.rk4_steps)
    return x


def _start_groups(run: RunData, gain: np.ndarray, dead_band: float
                  ) -> list[tuple[float, float, np.ndarray]]:
    """(z0, ż0, rows) per distinct start: each row starts at rest where its own sensor
    map (gain) says the mass was, so rows of one run may start apart."""
    # `start_state` computes each (gain, dead band) once per run: the rows of a batch
    # mostly share one
    starts = np.array([start_state(run, g, dead_band) for g in gain.tolist()])
    return [(float(z0), float(zd0), np.all(starts == (z0, zd0), axis=1))
            for z0, zd0 in np.unique(starts, axis=0)]


def _sensed(runs: Sequence[RunData], gain: np.ndarray, delay: np.ndarray,
            x: Sequence[np.ndarray]) -> list[np.ndarray]:
    """What the mass sensor reads of each run's x: (1 + g) x(t − d), row by row. At no
    delay the samples are read as they are: interpolated at its own knots, np.interp
    returns each knot's value exactly, so skipping it changes no bit (and saves one
    pass over every row of every evaluation of a model without a delay)."""
    return [np.stack([(1.0 + g) * (xr if d == 0.0 else np.interp(run.t - d, run.t, xr))
                      for g, d, xr in zip(gain, delay, xk)]) for run, xk in zip(runs, x)]


UNSTABLE_TRAVEL = 10.0  # m: no isolator on the table moves this far


def runs_away(x: np.ndarray) -> bool:
    """True for a predicted motion that diverged (non-finite, or past UNSTABLE_TRAVEL)."""
    return not (np.all(np.isfinite(x)) and np.max(np.abs(x)) < UNSTABLE_TRAVEL)


SETTLE = 3.0  # s: many times the isolator's slowest decay (m/c1 ≈ 0.45 s)


def _settle(h: Hypothesis, V: np.ndarray, S0: np.ndarray, hysteretic, z_end: np.ndarray,
            zd_end: np.ndarray, u_end: float, dt: float) -> np.ndarray:
    """Each row's z once the mass has come to rest after its run, the table held still;
    its hysteretic states in S0 (updated in place) follow the motion."""
    held = PPoly(np.array([[u_end]]), np.array([0.0, SETTLE]))
    z_rest = np.empty_like(z_end)
    # each row settles from its own state: one run each, all in one parallel call
    rows = range(V.shape[0])
    setups = [RunSetup(held, SETTLE, dt, 0.0, float(z_end[r]), float(zd_end[r])) for r in rows]
    settled = simulate_runs(h.model, setups, [V[r:r + 1] for r in rows],
                            s0=[S0[r:r + 1] for r in rows])
    for r, b in zip(rows, settled):
        spend(b.rk4_steps)
        for j, shape in hysteretic:
            S0[r, j] = hysteresis_after(S0[r:r + 1, j], b.zd, dt, shape)[0]
        z_rest[r] = b.z[0, -1]
    return z_rest


def hysteresis_along(r0: np.ndarray, z_from: np.ndarray, z_to: np.ndarray,
                     shape: tuple[float, float, float], steps: int = 200) -> np.ndarray:
    """Bouc–Wen r after the mass moved straight from z_from to z_to (rows), e.g. settling
    between runs: dr/dz = 1 − a sgn(dz) |r|ⁿ⁻¹ r − b |r|ⁿ, by RK4 in z."""
    a, b, n = shape
    r = np.array(r0, float)
    h = (np.asarray(z_to, float) - np.asarray(z_from, float)) / steps
    sd = np.sign(h)

    def f(r):
        rn = np.abs(r) ** n
        return 1.0 - a * sd * np.sign(r) * rn - b * rn

    for _ in range(steps):
        k1 = f(r)
        k2 = f(r + 0.5 * h * k1)
        k3 = f(r + 0.5 * h * k2)
        r = r + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + f(r + h * k3))
    return r


def hysteresis_after(r0: np.ndarray, zd: np.ndarray, dt: float,
                     shape: tuple[float, float, float]) -> np.ndarray:
    """Bouc–Wen r at the end of a run along the sampled ż (R, n).

    r does not relax at rest, so a run starts with the state the last one left.
    """
    return np.array([state_after(BOUC_WEN, shape, row, dt, r) for r, row in zip(r0, zd)])


def fluid_temperature_after(theta0: np.ndarray, zd: np.ndarray, dt: float,
                            heating: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """θ at the end of a run: θ' = a ż² − θ/τ solved exactly for the sampled ż (R, n),
    heating a and cooling time τ per row (R,).

    A row that diverged heats without bound (inf): the fit treats its run as unstable.
    Each row is summed on its own (numpy's pairwise sum, not a BLAS product, whose last
    bits follow the kernel and the batch's size): a row is predicted the same in any
    batch, and a drift that takes the damping near zero amplifies a last bit run by run.
    """
    n = zd.shape[1]
    age = dt * np.arange(n - 1, -1, -1)
    theta = np.empty(zd.shape[0])
    with np.errstate(over="ignore", invalid="ignore"):
        for r, (a, cooling) in enumerate(zip(heating, tau)):
            heat = np.sum(zd[r] ** 2 * np.exp(-age / cooling))
            theta[r] = theta0[r] * np.exp(-dt * (n - 1) / cooling) + a * dt * heat
    return theta


@dataclass(frozen=True)
class Fit:
    """A fitted hypothesis and its statistics; values and std in SI."""

    hypothesis: Hypothesis
    names: tuple[str, ...]
    values: np.ndarray
    std: np.ndarray
    correlation: np.ndarray
    residuals: tuple[np.ndarray, ...]  # per run, in units of the sensor noise
    jacobian: np.ndarray  # d residual / d (value / scale), at the optimum
    scales: np.ndarray
    evaluations: int

    @property
    def rss(self) -> float:
        return float(sum(r @ r for r in self.residuals))

    @property
    def n_samples(self) -> int:
        return int(sum(r.size for r in self.residuals))

    @property
    def residual_over_noise(self) -> float:
        """RMS of (x_pred − x_meas)/σ_x: 1 for a right model."""
        return float(np.sqrt(self.rss / self.n_samples))

    def param(self, name: str) -> tuple[float, float]:
        j = self.names.index(name)
        return float(self.values[j]), float(self.std[j])


def refit(h: Hypothesis, runs: Sequence[RunData], names: Sequence[str],
          scales: Sequence[float], bounds: Sequence[tuple[float, float]],
          fit_runs: Sequence[int] | None = None, max_nfev: int = MAX_NFEV,
          fd_step: float = FD_STEP) -> Fit:
    """Least squares of the named parameters on the runs `fit_runs` (default all);
    `fd_step`: the Jacobian's finite-difference step, of each scaled parameter."""
    names = tuple(names)
    scales = np.asarray(scales, float)
    use = list(range(len(runs))) if fit_runs is None else list(fit_runs)
    last = max(use) + 1  # runs after the last fitted one cannot change it
    start = np.array([h.value(n) for n in names]) / scales
    lo = np.array([b[0] for b in bounds]) / scales
    hi = np.array([b[1] for b in bounds]) / scales
    start = np.clip(np.nan_to_num(start), lo, hi)
    evaluator = _Evaluator(h, runs[:last], names, scales, use, fd_step)
    sol = least_squares(evaluator.residual, start, jac=evaluator.jacobian,
                        bounds=(lo, hi), method="trf", max_nfev=max_nfev)
    values = sol.x * scales
    fitted = h.with_values(dict(zip(names, values.tolist())))
    r, J = evaluator.residual(sol.x), evaluator.jacobian(sol.x)
    per_run = _split(r, [runs[k].t.size for k in use])
    cov = covariance(r, J, per_run) * np.outer(scales, scales)
    # a direction the data do not determine can come out of pinv slightly negative
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    # a constant that moves nothing (a drift's limit the fluid never reaches) is not
    # known exactly: pinv gives it variance 0, and it would read as infinitely significant
    std[~np.any(J != 0.0, axis=0)] = np.inf
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(std, std)
    corr[~np.isfinite(std)] = np.nan
    corr[:, ~np.isfinite(std)] = np.nan
    corr[~np.isfinite(corr)] = np.nan  # a constant the data do not determine: no correlation
    corr = np.clip(corr, -1.0, 1.0)  # a clamped tiny variance must not read as |ρ| > 1
    return Fit(fitted, names, values, std, corr, tuple(per_run), J, scales, int(sol.nfev))


def refit_free(h: Hypothesis, data: Sequence[RunData], names: Sequence[str],
               candidates: dict[str, Candidate], fit_runs: Sequence[int] | None = None,
               max_nfev: int = MAX_NFEV, fd_step: float = FD_STEP) -> Fit:
    """`refit` of the free parameters `names`, each at its size and within its bounds: a
    candidate's parameter (`candidates`, keyed by parameter) by its physics, the dead
    band within DEAD_BAND_BOUNDS, every other constant within 1/50 to 50 times its value
    (of its sign)."""
    scales, bounds = [], []
    for n in names:
        if n in candidates:
            c = candidates[n]
            scales.append(c.typical(h.model))
            bounds.append(c.bounds(h.model))
        elif n == "delta":  # may have been closed by the base fit: free to open again
            scales.append(max(abs(h.value(n)), DEAD_BAND_SCALE))
            bounds.append(DEAD_BAND_BOUNDS)
        else:
            # signed: an effect added on an earlier step may be negative (a force offset of
            # -4 kN), and bounds of |v| clipped it to +80 N at the start
            v, floor = h.value(n), shape_floor(h.model, n)
            scales.append(abs(v))
            bounds.append((max(min(0.02 * v, 50.0 * v), floor), max(0.02 * v, 50.0 * v)))
    return refit(h, data, names, scales, bounds, fit_runs=fit_runs, max_nfev=max_nfev,
                 fd_step=fd_step)


class _Evaluator:
    """Residual and Jacobian of the scaled parameters θ, computed apart.

    The Jacobian is forward differences of step `fd_step`. With `tangent` it is the
    motion's forward sensitivities instead (`simulate.tangent`: one integration of each
    run with the tangent of every parameter, about five plain simulations' cost where
    finite differences take n + 1), the sensor map's by the chain rule, wherever no run
    starts from the internal states the one before left (those the tangent does not
    follow across runs and the settling between). The refits keep the finite
    differences: over the unseen benchmark the exact slopes cost as much in all and end
    in worse valleys more often (docs/loop.md, "Speed").

    The trust-region solver evaluates the residual at every trial point but the
    Jacobian only where a step is accepted, so a rejected trial costs one simulated
    row. For finite differences, rows are integrated in parallel, one per thread, so a
    trial also simulates the first few perturbed rows on threads that would otherwise
    idle (n mod threads of them): an accepted step then costs no more parallel rounds
    than one n + 1 batch. Each row of a batch is integrated on its own, so residual and
    Jacobian are bit for bit those of the single n + 1 batch, and the solver takes the
    same path.
    """

    def __init__(self, h, runs, names, scales, use, fd_step, tangent: bool = False):
        self.h, self.runs, self.names, self.scales, self.use = h, runs, names, scales, use
        self.fd_step = fd_step
        self.tangent = tangent and not carries_states(h)
        self.ahead = 0 if self.tangent else len(names) % max(numba.get_num_threads(), 1)
        self._rows: dict[bytes, tuple[list[np.ndarray], np.ndarray]] = {}  # θ → (x, residual)
        self._jac: tuple[bytes, np.ndarray] | None = None

    def _steps(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Finite-difference steps and the perturbed rows, exactly as one n + 1 batch."""
        steps = self.fd_step * np.maximum(np.abs(theta), 1.0)
        rows = np.tile(theta, (len(self.names) + 1, 1))
        rows[1:] += np.diag(steps)
        return steps, rows[1:]

    def _at(self, theta: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
        """Predictions at θ and at its first `ahead` perturbations; residual at θ."""
        key = theta.tobytes()
        if key not in self._rows:
            rows = np.vstack([theta[None, :], self._steps(theta)[1][: self.ahead]])
            with np.errstate(over="ignore", invalid="ignore"):
                pred = predict(self.h, self.runs, self.names, rows * self.scales)
                res = [(pred[k][0] - self.runs[k].x) / self.runs[k].sigma_x for k in self.use]
            # a trial that makes the model unstable (damping driven negative) must look
            # bad, not stop the search
            # (a run that diverged to a huge but finite value is as bad, and its square
            # must not overflow the solver's sums)
            r = np.clip(np.nan_to_num(np.concatenate(res), nan=UNSTABLE, posinf=UNSTABLE,
                                      neginf=-UNSTABLE), -UNSTABLE, UNSTABLE)
            if len(self._rows) >= 4:
                self._rows.pop(next(iter(self._rows)))
            self._rows[key] = (pred, r)
        return self._rows[key]

    def residual(self, theta: np.ndarray) -> np.ndarray:
        return self._at(theta)[1]

    def jacobian(self, theta: np.ndarray, *_) -> np.ndarray:
        key = theta.tobytes()
        if (self._jac is None or self._jac[0] != key) and self.tangent:
            self._jac = (key, self._tangent_jacobian(theta))
        elif self._jac is None or self._jac[0] != key:
            ahead = self._at(theta)[0]
            steps, rows = self._steps(theta)
            with np.errstate(over="ignore", invalid="ignore"):
                rest = (predict(self.h, self.runs, self.names, rows[self.ahead:] * self.scales)
                        if self.ahead < len(self.names) else [p[:0] for p in ahead])
                jac = [((np.vstack([ahead[k][1:], rest[k]]) - ahead[k][0])
                        / self.runs[k].sigma_x / steps[:, None]).T for k in self.use]
            J = np.nan_to_num(np.vstack(jac), nan=0.0, posinf=0.0, neginf=0.0)
            # a perturbed row that diverged says nothing about the slope
            J[np.abs(J) > UNSTABLE / self.fd_step] = 0.0
            self._jac = (key, J)
        return self._jac[1]

    def _tangent_jacobian(self, theta: np.ndarray) -> np.ndarray:
        """d residual / d θ from the motion's forward sensitivities (simulate.tangent), the
        sensor map's by the chain rule: x_meas = (1 + g) x(t − d)."""
        values = theta * self.scales
        h = self.h.with_values(dict(zip(self.names, values.tolist())))
        g, d, delta = h.sensor_gain, h.sensor_delay, h.model.dead_band
        steps = self._steps(theta)[0] * self.scales  # in SI, as the FD Jacobian's
        columns = [None if n in SENSOR_PARAMETERS else n for n in self.names]
        setups, slopes = [], []
        for k in self.use:
            run = self.runs[k]
            z0, zd0 = start_state(run, g, delta)
            setups.append(RunSetup(run.motion, run.t[-1] - run.t[0], run.dt, run.t[0], z0, zd0))
            # the start is read from the data through the sensor's gain and put on the dead
            # band's edge: its slopes by the finite difference the FD Jacobian takes
            d0 = np.zeros((len(self.names), 2))
            for j, n in enumerate(self.names):
                if n in (SENSOR_GAIN, "delta"):
                    moved = (start_state(run, g + steps[j], delta) if n == SENSOR_GAIN
                             else start_state(run, g, delta + steps[j]))
                    d0[j] = (np.array(moved) - (z0, zd0)) / steps[j]
            slopes.append(d0)
        jac = []
        with np.errstate(over="ignore", invalid="ignore"):
            for k, (z, dz) in zip(self.use, runs_sensitivity(h.model, setups, columns, slopes)):
                run = self.runs[k]
                x = z + run.motion(run.t)
                dx = np.vstack([(1.0 + g) * np.interp(run.t - d, run.t, row) for row in dz])
                for j, n in enumerate(self.names):
                    if n == SENSOR_GAIN:
                        dx[j] += np.interp(run.t - d, run.t, x)
                    elif n == SENSOR_DELAY:
                        dx[j] = -(1.0 + g) * slope_before(run.t, x, run.t - d)
                jac.append((dx * self.scales[:, None] / run.sigma_x).T)
        J = np.nan_to_num(np.vstack(jac), nan=0.0, posinf=0.0, neginf=0.0)
        J[np.abs(J) > UNSTABLE / self.fd_step] = 0.0  # as the FD Jacobian's: a run diverged
        return J


def slope_before(t: np.ndarray, x: np.ndarray, s: np.ndarray) -> np.ndarray:
    """dx/dt of the linear interpolant of x on t just before each s (a delay's slope
    seen as the delay grows); zero before t[0], where the interpolant holds x[0]."""
    j = np.searchsorted(t, s, side="left")
    inside = (j > 0) & (j < t.size)
    j = np.clip(j, 1, t.size - 1)
    return np.where(inside, (x[j] - x[j - 1]) / (t[j] - t[j - 1]), 0.0)


def carries_states(h: Hypothesis) -> bool:
    """Whether a run starts from the internal states (fluid θ, seals' r) the run before
    left: then the prediction hands states between runs, which the tangent does not follow."""
    return not h.fresh_states and any(t.kind in ("thermal_damper", "bouc_wen")
                                      for t in h.model.terms)


def _split(r: np.ndarray, sizes: Sequence[int]) -> list[np.ndarray]:
    return np.split(r, np.cumsum(sizes)[:-1])


def covariance(r: np.ndarray, J: np.ndarray, per_run: Sequence[np.ndarray]) -> np.ndarray:
    """σ²(JᵀJ)⁻¹, inflated by (1 + ρ₁)/(1 − ρ₁) for lag-1 autocorrelation ρ₁ of the residual."""
    dof = max(r.size - J.shape[1], 1)
    s2 = float(r @ r / dof)
    rho = lag1(per_run)
    inflation = (1 + rho) / (1 - rho) if rho > 0 else 1.0
    return s2 * inflation * np.linalg.pinv(J.T @ J)


def lag1(per_run: Sequence[np.ndarray]) -> float:
    num = sum(float(r[1:] @ r[:-1]) for r in per_run)
    den = sum(float(r @ r) for r in per_run)
    return min(num / den, 0.99) if den > 0 else 0.0


@dataclass(frozen=True)
class Score:
    """What adding a parameter at zero would do, predicted from the Jacobian."""

    name: str
    statistic: float  # LM: predicted RSS reduction over the residual variance, χ²₁ under H0
    predicted_value: float  # SI
    predicted_rss_drop: float  # fraction of the current RSS


def score(fit: Fit, runs: Sequence[RunData], candidate_h: Hypothesis, parameter: str,
          typical: float, sign: int) -> Score:
    """Lagrange-multiplier test of `parameter` (zero in `candidate_h`) against `fit`."""
    n_runs = len(fit.residuals)
    pred = predict(candidate_h, runs[:n_runs], (parameter,), np.array([[0.0], [typical]]))
    with np.errstate(over="ignore", invalid="ignore"):
        col = np.concatenate([(p[1] - p[0]) / run.sigma_x for p, run in zip(pred, runs)])
    r = np.concatenate(fit.residuals)
    J = fit.jacobian
    if not np.all(np.isfinite(col)):
        # the typical size makes the model unstable (damping driven negative): no
        # linearisation at zero to test, and a NaN start would stop the refit
        return Score(parameter, 0.0, 0.0, 0.0)
    proj = col - J @ np.linalg.lstsq(J, col, rcond=None)[0]
    denom = float(proj @ proj)
    if not denom > 0.0:
        return Score(parameter, 0.0, 0.0, 0.0)
    step = -float(proj @ r) / denom  # in units of `typical`
    if sign and np.sign(step) != sign:
        return Score(parameter, 0.0, step * typical, 0.0)
    drop = float((proj @ r) ** 2 / denom)
    # under the test's null (the model right but for this parameter) the residual is white
    # noise, so σ² is not inflated here; the refit's t-statistic is, and validation follows
    s2 = fit.rss / max(r.size - J.shape[1], 1)
    return Score(parameter, drop / s2, step * typical, drop / fit.rss)

