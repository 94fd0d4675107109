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

The runs and their smoothed input are in `run_data`, the simulated residual and
its Jacobian in `residuals`, (JᵀJ)⁻¹ and the correlated-noise factors in `covariance`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares

from analysis.identify.covariance import correlated_std_factor, gram_inverse
from analysis.identify.residuals import residual_and_jacobian
from analysis.identify.run_data import RunData
from analysis.model.isolator import IsolatorModel

Z95 = 1.959963984540054
# the cost is a χ² (residual in noise units): a relative change of 1e-6 of ~1e4 is 0.01,
# far below the change of 1 that one standard error of a constant makes
COST_TOL = 1e-6
HOLD_LOG_STD = 0.5  # a constant less determined than ±65 % is held (see `determined`)


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


def with_log_covariance(fit: OutputErrorFit, extra: np.ndarray, **changes) -> OutputErrorFit:
    """`fit` with `extra` (a covariance of the log constants: another source's share)
    added to its covariance, std recomputed; `changes` as `dataclasses.replace`."""
    cov = fit.covariance + extra * np.outer(fit.values, fit.values)
    return replace(fit, covariance=cov, std=np.sqrt(np.maximum(np.diag(cov), 0.0)), **changes)


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
