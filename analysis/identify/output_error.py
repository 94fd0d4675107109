"""Output-error refinement: fit every constant by simulating the measured runs.

The residual is the measured mass displacement x minus the simulated one,
divided by the x sensor's noise σ_x: with the right model it is white noise of
unit variance, and its RMS is the "residual / noise" figure of fit.

Errors in variables: the table displacement u that drives the model is
measured too. Feeding its raw samples (and their twice-differentiated noise)
to the simulator would put that noise into the simulated x and bias every
constant; instead the model is driven by a smoothing spline of u (λ by
generalised cross-validation), which removes the noise and keeps the
minimum-jerk ramps, whose spectrum lies far below the sensor's 500 Hz Nyquist.
What is left — the spline's small shape error — sets the floor; the residual
is measured on x, whose own noise is the only noise in it.

Parameters are searched in log coordinates (all are positive), the Jacobian
comes from one parallel batch of perturbed simulations per run, and the
covariance is σ²(JᵀJ)⁻¹ mapped back by the delta method.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
from scipy.interpolate import PPoly, make_smoothing_spline
from scipy.optimize import least_squares

from analysis.model.isolator import IsolatorModel
from analysis.simulate import RunSetup, simulate_runs

FD_STEP = 1e-3  # log step: large enough to see slopes, not single stick/slip event flips
Z95 = 1.959963984540054
UNSTABLE = 1e6  # residual (noise units) of a sample whose simulation diverged
# the cost is a χ² (residual in noise units): a relative change of 1e-6 of ~1e4 is 0.01,
# far below the change of 1 that one standard error of a constant makes
COST_TOL = 1e-6
HOLD_LOG_STD = 0.5  # a constant less determined than ±65 % is held (see `determined`)
GRAM_RCOND = 1e-12  # singular values of J below this × the largest: a direction not determined


def gram_inverse(J: np.ndarray) -> np.ndarray:
    """(JᵀJ)⁻¹ from the SVD of J, not by inverting JᵀJ.

    Forming JᵀJ squares J's condition number, and its pseudo-inverse can come out
    with a slightly negative diagonal, or change a verdict with the last bits of
    the BLAS kernel. From J = U S Vᵀ it is V S⁻² Vᵀ: symmetric and positive by
    construction. A direction the data do not determine (s below GRAM_RCOND of
    the largest) gets the variance of that floor, a very large one, where a
    pseudo-inverse would give it none.
    """
    return _svd_gram_inverse(J, drop_undetermined=False)


def determined_gram_inverse(J: np.ndarray) -> np.ndarray:
    """(JᵀJ)⁻¹ on the directions J determines, zero on those it does not.

    For the covariance of the table-motion estimate, whose undetermined directions are
    not the data's to propagate: the duration of a 0.7 ms ramp (shorter than one sample,
    fitted to a lagged servo's corner) moves no sample of u, so the record says
    nothing about it, yet it moves the simulated x between samples. With
    `gram_inverse`'s floor it got a variance of ~1e12, and that times its sensitivity
    put ±2e6 lb/in on k1 (unseen campaign 1205); what the samples do not determine is
    left out of the input's share instead.
    """
    return _svd_gram_inverse(J, drop_undetermined=True)


def _svd_gram_inverse(J: np.ndarray, drop_undetermined: bool) -> np.ndarray:
    _, sv, vt = np.linalg.svd(np.asarray(J, float), full_matrices=False)
    if sv.size == 0:
        return np.zeros((J.shape[1], J.shape[1]))
    floor = GRAM_RCOND * max(float(sv[0]), np.finfo(float).tiny)
    if drop_undetermined:
        vt, sv = vt[sv > floor], sv[sv > floor]
    w = vt.T / np.maximum(sv, floor)
    return w @ w.T


@dataclass(frozen=True)
class RunData:
    """One run as the output-error fit sees it; SI."""

    name: str
    t: np.ndarray  # (n,) uniform, s
    motion: PPoly  # smoothed table displacement u(t)
    x: np.ndarray  # (n,) measured mass displacement, m
    sigma_x: float  # x sensor noise, m

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    @cached_property
    def first_motion(self) -> float:
        """Time (s) the table motion first leaves its starting level.

        Cached: every simulation of the run asks for its start state, and this
        evaluates the motion at every sample.
        """
        u = self.motion(self.t)
        moved = np.flatnonzero(np.abs(u - u[0]) > 1e-9)
        return float(self.t[moved[0]]) if moved.size else float(self.t[-1])


INPUT_CUTOFF = 50.0  # Hz: the table's servo-hydraulic motion has no content above this
REST_WEIGHT = 1e-5  # data weight while the table is at rest: cutoff falls ~18x (w^(1/4))
REST_WINDOW = 0.05  # s: a window whose range stays within noise is at rest
REST_RANGE = 8.0  # noise σ: the range of 50 Gaussian samples stays below ~6σ


def noise_sigma(u: np.ndarray) -> float:
    """White-noise σ from the second difference (var = 6σ²), robust by the MAD."""
    d2 = np.diff(np.asarray(u, float), 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))


def table_at_rest(u: np.ndarray, dt: float, sigma: float) -> np.ndarray:
    """True where the table is still: the range over REST_WINDOW stays within noise.

    Motion is widened by half a window each side, so the ends of every ramp,
    where the acceleration is largest relative to the velocity, stay in it.
    """
    n = max(round(REST_WINDOW / dt), 3)
    windows = np.lib.stride_tricks.sliding_window_view(np.asarray(u, float), n)
    moving = np.zeros(len(u), bool)
    busy = np.ptp(windows, axis=1) > REST_RANGE * sigma
    for k in np.flatnonzero(busy):  # a window that moves marks all its samples
        moving[k:k + n] = True
    grow = np.convolve(moving, np.ones(2 * (n // 2) + 1), mode="same") > 0
    return ~grow


def smooth_motion(t: np.ndarray, u: np.ndarray, cutoff: float = INPUT_CUTOFF) -> PPoly:
    """The table displacement as a smoothing cubic spline that drives the model.

    The spline minimises Σ w_i(u_i − f(t_i))² + λ∫f''², whose transfer function
    on a uniform grid is 1/(1 + λ dt ω⁴ / w): λ = 1/(dt ω_c⁴) puts the half-power
    point at ω_c where w = 1. Measured on run C with 25 µm noise, 50 Hz gives the
    smallest acceleration error (0.6 m/s² RMS on a 56 m/s² peak; 28 Hz: 0.9,
    89 Hz: 1.9). Where the table is at rest the weight drops to REST_WEIGHT:
    static friction lets the mass go when m|ü| passes breakaway (0.034 m/s² for
    the report's isolator), so the input's acceleration noise must stay well
    below that while the table is still; there it does (~6e-4 m/s² at 25 µm).
    """
    t = np.asarray(t, float)
    u = np.asarray(u, float)
    dt = float(np.median(np.diff(t)))
    lam = 1.0 / (dt * (2 * np.pi * cutoff) ** 4)
    w = np.where(table_at_rest(u, dt, noise_sigma(u)), REST_WEIGHT, 1.0)
    return PPoly.from_spline(make_smoothing_spline(t, u, w=w, lam=lam))


@dataclass(frozen=True)
class OutputErrorFit:
    """Refined model and the statistics of the refinement."""

    model: IsolatorModel
    names: tuple[str, ...]
    values: np.ndarray  # SI
    std: np.ndarray  # SI, from the Jacobian
    covariance: np.ndarray  # SI
    residual_rms: float  # RMS of (x_sim − x_meas)/σ_x: 1 for a right model
    cost_evaluations: int
    success: bool
    message: str
    # (rows, J) Jacobian of the scaled residual in log coordinates, at the optimum
    jacobian: np.ndarray | None = field(default=None, repr=False, compare=False)
    residual: np.ndarray | None = field(default=None, repr=False, compare=False)  # scaled, ditto
    input_covariance: bool = False  # True once the input estimate's share is in `covariance`
    # per run (J_x, C_p) of that share (`input_error.input_sensitivities`), for reuse
    input_sensitivity: tuple = field(default=(), repr=False, compare=False)
    # held constants: (lowest, highest) value the runs cannot tell from the held one
    # (a slice of the cost, `slice_residuals`); absent where not scanned
    consistent: dict[str, tuple[float, float]] = field(default_factory=dict, compare=False)

    @property
    def ci95(self) -> np.ndarray:
        """(J, 2) 95 % confidence intervals, SI."""
        return np.column_stack([self.values - Z95 * self.std, self.values + Z95 * self.std])

    def as_dict(self) -> dict[str, float]:
        return dict(zip(self.names, self.values.tolist()))


def _vectors(model: IsolatorModel, names: Sequence[str], theta: np.ndarray) -> np.ndarray:
    """Rows of kernel parameter vectors: the base point, then each log-step."""
    idx = model.vector_index()
    base = model.vector()
    rows = np.tile(base, (len(names) + 1, 1))
    for j, n in enumerate(names):
        rows[:, idx[n]] = np.exp(theta[j])
        rows[j + 1, idx[n]] = np.exp(theta[j] + FD_STEP)
    return rows


REST_SAMPLES = 50  # the step-pulse profiles rest 0.1 s before they move


def initial_offset(run: RunData, sensor_gain: float = 0.0) -> float:
    """z at the start of a run (m), from its first samples at rest.

    The dead band lets the mass come to rest anywhere within ±δ, so a run that
    follows another starts where that one left it, not at z = 0. Read through the
    inverse of a mass-sensor gain error when one is modelled.
    """
    k = min(REST_SAMPLES, run.t.size)
    return float(np.mean(run.x[:k] / (1.0 + sensor_gain) - run.motion(run.t[:k])))


START_WINDOW = 90  # samples: the step-pulse profiles rest 0.1 s before they move
DRIFT_SIGMAS = 4.0
EDGE_SIGMAS = 3.0


def start_state(run: RunData, sensor_gain: float = 0.0, dead_band: float = 0.0
                ) -> tuple[float, float]:
    """(z, ż) at the run's first sample.

    A mass held by static friction starts at rest, where the dead band let it
    settle (`initial_offset`). One pushed by a constant force beyond breakaway
    (a tilted track, a force offset) may still be creeping when the next run
    starts, and starting it at rest costs millimetres within a second. A
    quadratic through z over the samples before the table moves tells the two
    apart: its slope at the start is taken when it exceeds DRIFT_SIGMAS of its
    standard error (white x noise; 0.4 mm/s at 25 µm over 90 samples). A mass
    that starts at rest and then accelerates (a first run under such a force)
    has a slope of zero there, and the simulator reproduces its acceleration.

    A mass at rest within EDGE_SIGMAS of its estimate's error from the edge of
    the dead band is put on the edge: a force beyond breakaway holds the mass
    exactly there (the springs' jump pushes back), and a start a few µm off to
    either side would begin the run in the wrong mode.
    """
    still = run.t < run.first_motion
    k = int(min(START_WINDOW, np.count_nonzero(still)))
    if k < 10:
        return initial_offset(run, sensor_gain), 0.0
    t = run.t[:k] - run.t[0]
    z = run.x[:k] / (1.0 + sensor_gain) - run.motion(run.t[:k])
    X = np.vander(t, 3, increasing=True)
    coef = np.linalg.lstsq(X, z, rcond=None)[0]
    std_slope = run.sigma_x * np.sqrt(np.linalg.inv(X.T @ X)[1, 1])
    if abs(coef[1]) > DRIFT_SIGMAS * std_slope:
        return float(coef[0]), float(coef[1])
    z0 = initial_offset(run, sensor_gain)
    std_z0 = run.sigma_x / np.sqrt(min(REST_SAMPLES, run.t.size))
    if dead_band > 0 and abs(abs(z0) - dead_band) < EDGE_SIGMAS * std_z0:
        z0 = float(np.sign(z0) * dead_band)
    return z0, 0.0


def _setups(model: IsolatorModel, runs: Sequence[RunData]) -> list[RunSetup]:
    return [RunSetup(run.motion, run.t[-1] - run.t[0], run.dt, run.t[0],
                     *start_state(run, dead_band=model.dead_band)) for run in runs]


def _simulated_x(run: RunData, z: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Simulated x (rows, n); a diverged simulation far off."""
    return np.where(np.isfinite(z), z + u, UNSTABLE * run.sigma_x)


def slice_residuals(model: IsolatorModel, runs: Sequence[RunData], name: str,
                    values: Sequence[float]) -> np.ndarray:
    """(len(values), n) scaled residual of all runs with constant `name` at each of
    `values`, the rest as in `model`: one parallel batch. A slice of the cost, not a
    profile: the other constants are not refitted, so it can only understate how far
    a value can go."""
    rows = np.tile(model.vector(), (len(values), 1))
    rows[:, model.vector_index()[name]] = values
    batches = simulate_runs(model, _setups(model, runs), [rows] * len(runs))
    return np.hstack([(_simulated_x(run, b.z, b.u) - run.x) / run.sigma_x
                      for run, b in zip(runs, batches)])


HAC_LAGS = 200  # samples (0.2 s at 1 kHz): a ramp's length, the scale of the rig's model error


def bartlett_lags(n: int, max_lag: int = HAC_LAGS):
    """(lag, weight) of the Bartlett window, lags 1..max_lag within n samples."""
    return ((lag, 1.0 - lag / (max_lag + 1)) for lag in range(1, min(max_lag, n - 1) + 1))


def with_log_covariance(fit: OutputErrorFit, extra: np.ndarray, **changes) -> OutputErrorFit:
    """`fit` with `extra` (a covariance of the log constants: another source's share)
    added to its covariance, std recomputed; `changes` as `dataclasses.replace`."""
    cov = fit.covariance + extra * np.outer(fit.values, fit.values)
    return replace(fit, covariance=cov, std=np.sqrt(np.maximum(np.diag(cov), 0.0)), **changes)


def correlated_std_factor(J: np.ndarray, r: np.ndarray, inverse: np.ndarray,
                          white: np.ndarray, max_lag: int = HAC_LAGS) -> np.ndarray:
    """Per constant, how much the residual's autocorrelation widens its standard error
    beyond white noise's (≥ 1): the sandwich (JᵀJ)⁻¹ Jᵀ Σ J (JᵀJ)⁻¹ with Σ from the
    residual's autocovariance (Newey–West, Bartlett window), Ljung's output-error
    covariance for noise that is not white.

    Applied as a factor on the white covariance (its correlations kept): a model a few
    µm off the rig leaves a slow residual that moves the constants far more than the
    sensor's white noise does, and an error bar counting only the latter is too
    narrow (measured on 20 rig campaigns: 95 % intervals covered the rig's constants in
    50 % of cases with white noise alone, 68 % with this).
    """
    Jr = J * r[:, None]
    meat = Jr.T @ Jr
    for lag, w in bartlett_lags(r.size, max_lag):
        g = Jr[lag:].T @ Jr[:-lag]
        meat += w * (g + g.T)
    sandwich = np.diag(inverse @ meat @ inverse)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(white > 0, sandwich / white, 1.0)
    return np.sqrt(np.maximum(np.nan_to_num(ratio, nan=1.0), 1.0))


def correlated_noise_factor(residual: np.ndarray, direction: np.ndarray,
                            sizes: Sequence[int], max_lag: int = HAC_LAGS) -> float:
    """How much more the residual's noise moves a χ² comparison along `direction` than
    white noise of unit variance would: dᵀΣd / dᵀd, Σ the residual's autocovariance
    (Bartlett window to `max_lag` samples, per run), at least 1.

    A model a few µm off the truth leaves a slow, correlated residual (the rig's
    table motion and integration); along a slow direction it moves a cost difference
    many times more than the sensor's white noise would, and a test that counts only
    the white noise then takes that model error for a significant difference.
    """
    num = den = 0.0
    start = 0
    for n in sizes:
        r, d = residual[start:start + n], direction[start:start + n]
        start += n
        num += float(r @ r) / n * float(d @ d)
        for lag, w in bartlett_lags(n, max_lag):
            gamma = float(r[lag:] @ r[:-lag]) / n
            num += 2.0 * w * gamma * float(d[lag:] @ d[:-lag])
        den += float(d @ d)
    return max(num / den, 1.0) if den > 0 else 1.0


def residual_and_jacobian(model: IsolatorModel, names: Sequence[str], theta: np.ndarray,
                          runs: Sequence[RunData], with_jacobian: bool,
                          base: Sequence[np.ndarray] | None = None
                          ) -> tuple[np.ndarray, np.ndarray | None, list[np.ndarray]]:
    """Scaled residual (x_sim − x)/σ_x of all runs, its Jacobian in log coordinates,
    and the simulated x of each run at θ.

    `base`: each run's simulated x at θ when already known (the optimiser asks for
    the residual at θ before the Jacobian there), so the batch simulates only the
    perturbed rows: 8 instead of 9 per run, one round fewer on two cores.
    """
    rows = _vectors(model, names, theta)
    rows = rows if with_jacobian else rows[:1]
    if base is not None:
        rows = rows[1:]
    batches = simulate_runs(model, _setups(model, runs), [rows] * len(runs))
    res, jac, xs = [], [], []
    for k, (run, b) in enumerate(zip(runs, batches)):
        x = _simulated_x(run, b.z, b.u)
        if base is not None:
            x = np.vstack([base[k][None, :], x])
        xs.append(x[0])
        res.append((x[0] - run.x) / run.sigma_x)
        if with_jacobian:
            jac.append(((x[1:] - x[0]) / run.sigma_x / FD_STEP).T)
    return np.concatenate(res), (np.vstack(jac) if with_jacobian else None), xs


def scaled_residual(model: IsolatorModel, runs: Sequence[RunData]) -> np.ndarray:
    """(x_sim − x)/σ_x of all runs, concatenated, at `model`."""
    return residual_and_jacobian(model, (), np.empty(0), runs, False)[0]


def determined(model: IsolatorModel, runs: Sequence[RunData], names: Sequence[str],
               limit: float = HOLD_LOG_STD
               ) -> tuple[tuple[str, ...], tuple[str, ...], tuple[np.ndarray, np.ndarray]]:
    """Split `names` into those the runs determine and those they do not, at the start.

    Also returns the scaled residual and the Jacobian (columns of the determined
    constants) at the start: `refine(at_start=...)` begins there, so the search
    does not simulate them again.

    A constant whose standard error at the start point (from the Jacobian, in log
    coordinates) exceeds `limit` is not determined by these runs: fitting it
    would let it wander along a flat cost (the breakaway force of a step-pulse
    test is passed within ~0.1 ms of a ramp's start, far below one 1 kHz sample).
    Such constants are held at their start value and reported as held.

    The standard error is the one the sensor's noise alone would give (the
    residual is in noise units: variance 1), not the start's misfit: a start
    whose simulated mass settles at the wrong place in the dead band has a
    residual of 1000 σ, which would call every constant undetermined and hold
    the shape constants at the equation-error values (measured: a mass 4 g
    different tipped `sim generate` runs from 0.95 σ to 1573 σ that way).
    """
    theta = np.log([model.parameters()[n] for n in names])
    r, J, _ = residual_and_jacobian(model, names, theta, runs, True)
    log_std = np.sqrt(np.diag(gram_inverse(J)))
    keep = tuple(n for n, s in zip(names, log_std) if s <= limit)
    # each column is its own constant's perturbation from one base point: the
    # determined ones' columns are the Jacobian of a fit of those alone
    cols = [j for j, n in enumerate(names) if n in keep]
    return keep, tuple(n for n in names if n not in keep), (r, J[:, cols])


def refine(model: IsolatorModel, runs: Sequence[RunData], names: Sequence[str],
           max_nfev: int = 60,
           at_start: tuple[np.ndarray, np.ndarray] | None = None) -> OutputErrorFit:
    """Least-squares fit of the named constants (all > 0) to the runs' measured x.

    `at_start`: the scaled residual and its Jacobian at `model`, when known (a run
    refitted alone from the joint optimum has them as rows of the joint fit's),
    so the search skips simulating them again.
    """
    names = tuple(names)
    start = model.parameters()
    for n in names:
        if not start[n] > 0:
            raise ValueError(f"output error fits {n} in log coordinates: start value must be "
                             f"> 0, got {start[n]}")
    theta0 = np.log([start[n] for n in names])

    last: dict[str, object] = {}

    def at_theta0(theta: np.ndarray) -> bool:
        # exp then log of the start values can differ from theta0 in the last bit
        return at_start is not None and np.allclose(theta, theta0, rtol=0.0, atol=1e-12)

    def fun(theta: np.ndarray) -> np.ndarray:
        if at_theta0(theta):
            return at_start[0]
        r, _, xs = residual_and_jacobian(model, names, theta, runs, False)
        last.update(theta=theta.copy(), xs=xs)
        return r

    def jac(theta: np.ndarray) -> np.ndarray:
        if at_theta0(theta):
            return at_start[1]
        known = np.array_equal(theta, last.get("theta"))
        return residual_and_jacobian(model, names, theta, runs, True,
                                     base=last["xs"] if known else None)[1]

    # a decade either way of the start: the start is the equation-error estimate
    bounds = (theta0 - np.log(10.0), theta0 + np.log(10.0))
    sol = least_squares(fun, theta0, jac=jac,
                        bounds=bounds, method="trf", x_scale="jac", max_nfev=max_nfev,
                        ftol=COST_TOL, xtol=COST_TOL)
    # scipy's final residual and Jacobian are at sol.x (loss "linear" leaves them as
    # they were evaluated): no need to simulate the runs once more
    return _fit_at(model, names, sol.x, np.asarray(sol.fun), np.asarray(sol.jac), sol.nfev,
                   bool(sol.success), str(sol.message))


def _fit_at(model: IsolatorModel, names: tuple[str, ...], theta: np.ndarray, r: np.ndarray,
            J: np.ndarray, evaluations: int, success: bool, message: str) -> OutputErrorFit:
    """The fit at log constants θ with scaled residual r and Jacobian J there."""
    values = np.exp(theta)
    fitted = model.with_parameters(**dict(zip(names, values.tolist())))
    dof = max(r.size - len(names), 1)
    s2 = float(r @ r / dof)
    inverse = gram_inverse(J)
    cov_theta = s2 * inverse
    factor = correlated_std_factor(J, r, inverse, np.diag(cov_theta))
    cov_theta = cov_theta * np.outer(factor, factor)
    cov = cov_theta * np.outer(values, values)  # delta method from log coordinates
    return OutputErrorFit(model=fitted, names=names, values=values,
                          std=np.sqrt(np.maximum(np.diag(cov), 0.0)), covariance=cov,
                          residual_rms=float(np.sqrt(np.mean(r**2))),
                          cost_evaluations=evaluations, success=success, message=message,
                          jacobian=J, residual=r)


# χ² (noise units). A fit is taken as converged when the next Gauss–Newton step
# would cut the cost by less than ONE_STEP_SLACK: the cut is the step's length in
# standard errors, squared (|J δ|² = δᵀ JᵀJ δ), so 0.25 is half a standard error.
# The kept Jacobian must predict the first step's cost to within LINEAR_SLACK, one
# standard error's worth: where it does not (measured on run C, the largest
# motions: 3–35 χ² above the prediction, where runs A and B stay below 0.7), the
# steps converge to a point set by the start's Jacobian, not the run's optimum
ONE_STEP_SLACK = 0.25
LINEAR_SLACK = 1.0
CHORD_STEPS = 3


def one_step(model: IsolatorModel, runs: Sequence[RunData], names: Sequence[str],
             at_start: tuple[np.ndarray, np.ndarray]) -> OutputErrorFit | None:
    """The fit from a nearby optimum by Gauss–Newton steps with its Jacobian, checked.

    From a start within a few standard errors of the optimum (a run refitted
    alone from the joint fit of all runs), Gauss–Newton steps that keep the
    start's Jacobian (the chord method) reach the optimum for the cost of one
    simulation of the run per step, where iterating with fresh finite-difference
    Jacobians costs 3–15 of them at n + 1 simulations each. One step is Le Cam's
    one-step estimator, already asymptotically efficient; the next step's
    predicted cut (`ONE_STEP_SLACK`) says whether another is needed.

    A first step whose cost the kept Jacobian does not predict (`LINEAR_SLACK`),
    a step that raises the cost (friction and the dead band make it jump), or no
    convergence within CHORD_STEPS returns None: the caller then iterates in full.
    The covariance uses the start's Jacobian, the residual the last step's.
    """
    names = tuple(names)
    r, J0 = at_start
    theta0 = np.log([model.parameters()[n] for n in names])
    theta = theta0
    for k in range(CHORD_STEPS + 1):
        step = np.linalg.lstsq(J0, -r, rcond=None)[0]
        if k > 0 and float(np.sum((J0 @ step) ** 2)) <= ONE_STEP_SLACK:
            return _fit_at(model, names, theta, r, J0, k, True,
                           f"{k} Gauss–Newton step(s) from the joint fit, its Jacobian kept")
        if k == CHORD_STEPS:
            return None
        trial = np.clip(theta + step, theta0 - np.log(10.0), theta0 + np.log(10.0))
        r_trial = residual_and_jacobian(model, names, trial, runs, False)[0]
        cost = float(r_trial @ r_trial)
        predicted = float(np.sum((r + J0 @ (trial - theta)) ** 2))
        if not cost < float(r @ r) or (k == 0 and cost > predicted + LINEAR_SLACK):
            return None
        theta, r = trial, r_trial
    return None
