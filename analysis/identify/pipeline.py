"""From measured base-excited runs to an identified isolator, in the report's stages.

1. Appendix A as the report did it: Eq 10's coefficients by least squares at
   the report's hand-tuned α, β, δ (reproducible, and the baseline).
2. Variable projection: α, β, δ found automatically, coefficients solved inside.
3. Output error: every constant the runs determine (static friction included)
   refined jointly on all runs by simulating them; then each run alone, started
   from the joint estimate (Table 1's columns).

The reported estimate is the joint output-error one: equation error works on
twice-differentiated noisy displacement, which biases it (the smoother that
tames the noise also rounds the peaks of ẍ and ż, and the error is correlated
with the regressors), while output error compares the simulated displacement
with the measured one, where the only noise is the sensor's.

Errors in variables: the table displacement u drives the model and is itself
measured. Both stages use the table motion estimated by `analysis.table_motion`
(minimum-jerk ramps fitted to the samples, accepted only if what is left is
the sensor's noise; else a smoothing spline) for u and u̇, so the table
sensor's noise enters neither the regressors nor the simulated response.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from analysis.differentiate import differentiate
from analysis.identify.equation_error import LinearFit, fit_coefficients
from analysis.identify.input_error import refine_table, with_input_uncertainty
from analysis.identify.output_error import (
    HOLD_LOG_STD,
    OutputErrorFit,
    RunData,
    determined,
    initial_offset,
    one_step,
    refine,
)
from analysis.identify.regressors import regressor_matrix
from analysis.identify.varpro import Data, Projection, project
from analysis.model.isolator import IsolatorModel
from analysis.model.report_constants import report_model
from analysis.rest import active_mask
from analysis.simulate import simulate
from analysis.table_motion import TableMotion, estimate_table_motion

LINEAR = ("k1", "k2", "c1", "c2")
REFINED = ("k1", "k2", "c1", "c2", "alpha", "beta", "delta", "F_break", "epsilon")
FLAG_SIGMAS = 3.0  # a run's constant must differ from the runs' median by more than this…
FLAG_RELATIVE = 0.25  # …and by this fraction of it: A and B differ by up to 21 % in Table 1
CONSISTENT = 2.0  # residual / noise under the joint model below which a run starts there
PER_RUN_GRID = 7  # coarser than the joint search: each run only needs a start
MIN_START = {"delta": 1e-4, "F_break": 1.0, "epsilon": 1e-4}  # SI: log coordinates need > 0

Progress = Callable[[str], None]


@dataclass(frozen=True)
class MeasuredRun:
    """One base-excited run: table u and mass x absolute displacement; SI."""

    name: str
    t: np.ndarray  # s, uniform
    u: np.ndarray  # m
    x: np.ndarray  # m
    mass: float  # kg


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
    """Differentiate x, estimate u(t) and u̇(t), drop rest."""
    dt = float(run.t[1] - run.t[0])
    dx = differentiate(run.x, dt, method=method)
    table = refine_table(run.t, run.u, estimate_table_motion(run.t, run.u))
    u, ud = table.motion(run.t), table.motion.derivative()(run.t)
    z, zd = dx.x - u, dx.v - ud
    active = active_mask(zd, dt, dx.noise_v)
    oe = RunData(run.name, run.t, table.motion, run.x, dx.noise)
    return PreparedRun(run=run, z=z, zd=zd, xdd=dx.a, active=active, oe=oe, table=table,
                       sigma_x=dx.noise, method=dx.method, settings=dict(dx.settings))


@dataclass(frozen=True)
class RunError:
    """How well a model reproduces one run: NRMSE as fractions, force RMS in N."""

    z: float
    zd: float
    xdd: float
    force_rms: float  # RMS of the equation error m ẍ + F(z, ż) over the moving samples
    residual_over_noise: float  # RMS(x_sim − x_meas) / σ_x: 1 for a right model


@dataclass(frozen=True)
class IsolatorFit:
    """Every stage's result; `model` is the reported estimate (see `estimate`)."""

    model: IsolatorModel
    estimate: str  # which stage `model` comes from
    appendix_a: LinearFit
    projection: Projection
    joint: OutputErrorFit | None
    held: tuple[str, ...] = ()  # constants the runs do not determine, held at the start
    per_run: dict[str, OutputErrorFit] = field(default_factory=dict)
    errors: dict[str, RunError] = field(default_factory=dict)
    flagged: dict[str, list[str]] = field(default_factory=dict)  # run → constants that differ
    prepared: tuple[PreparedRun, ...] = ()

    def values_std(self) -> tuple[dict[str, float], dict[str, float]]:
        """The reported constants and their standard errors (SI; absent: not estimated)."""
        if self.joint is not None:
            return self.model.parameters(), dict(zip(self.joint.names, self.joint.std.tolist()))
        f = self.projection.fit
        return self.model.parameters(), dict(zip(f.names, f.std.tolist()))


def _stack(prepared: Sequence[PreparedRun]) -> Data:
    return Data(*(np.concatenate([getattr(p, k)[p.active] for p in prepared])
                  for k in ("z", "zd", "xdd")))


def start_model(mass: float) -> IsolatorModel:
    """Eq 10 with the report's structure and its average constants as the start."""
    return report_model("average").with_parameters(m=mass)


def identify(runs: Sequence[MeasuredRun], refine_output_error: bool = True,
             per_run: bool = True, method: str = "auto",
             progress: Progress = lambda message: None) -> IsolatorFit:
    """Identify Eq 10 (with dead band and static friction) from base-excited runs."""
    masses = {r.mass for r in runs}
    if len(masses) != 1:
        raise ValueError(f"runs of one isolator share one mass, got {sorted(masses)} kg")
    progress("differentiating, estimating the table motion, dropping rest")
    prepared = tuple(prepare(r, method) for r in runs)
    data = _stack(prepared)
    model0 = start_model(masses.pop())
    progress("appendix A: least squares at the report's alpha, beta, delta")
    appendix_a = fit_coefficients(model0, data.z, data.zd, data.xdd, free=LINEAR)
    progress("variable projection over alpha, beta, delta")
    proj = project(model0, data, free=LINEAR)
    model, estimate, joint, held = proj.model, "variable projection", None, ()
    runs_fit: dict[str, OutputErrorFit] = {}
    if refine_output_error:
        progress("output error: all runs")
        joint = _refine(proj.model, prepared, progress)
        model, estimate = joint.model, "joint output error"
        held = tuple(n for n in REFINED if n not in joint.names)
    errors = {p.run.name: run_error(model, p) for p in prepared}
    if per_run and refine_output_error and len(prepared) > 1:
        start = 0
        for k, p in enumerate(prepared):
            rows = slice(start, start + p.oe.t.size)
            start += p.oe.t.size
            # the joint optimum's residual and Jacobian rows of this run are where its own
            # fit starts: no need to simulate them again
            at_start = (None if joint.jacobian is None or joint.residual is None else
                        (joint.residual[rows], joint.jacobian[rows]))
            sensitivity = (joint.input_sensitivity[k:k + 1] if joint.input_sensitivity
                           else None)
            runs_fit[p.run.name] = _run_alone(p, model0, model, errors[p.run.name], progress,
                                              free=joint.names, at_start=at_start,
                                              sensitivity=sensitivity)
    return IsolatorFit(model=model, estimate=estimate, appendix_a=appendix_a, projection=proj,
                       joint=joint, held=held, per_run=runs_fit, errors=errors,
                       flagged=flag_runs(runs_fit), prepared=prepared)


def _run_alone(p: PreparedRun, model0: IsolatorModel, joint: IsolatorModel, error: RunError,
               progress: Progress, free: Sequence[str] | None = None,
               at_start: tuple[np.ndarray, np.ndarray] | None = None,
               sensitivity: Sequence[tuple[np.ndarray, np.ndarray]] | None = None
               ) -> OutputErrorFit:
    """One run's own output-error fit, from the joint estimate if it fits the run.

    A run the joint model leaves at more than CONSISTENT × its noise has other
    constants (the report's run C): it starts from its own variable projection,
    as a start far off would leave output error in another basin.
    """
    if error.residual_over_noise <= CONSISTENT:
        progress(f"run {p.run.name}: output error from the joint estimate")
        # what the joint fit held, one run of it cannot determine either
        return _refine(joint, [p], progress, free=free, at_start=at_start,
                       sensitivity=sensitivity)
    progress(f"run {p.run.name}: variable projection, output error")
    own = project(model0, _stack([p]), free=LINEAR, grid=PER_RUN_GRID).model
    if any(own.parameters()[n] <= 0 for n in LINEAR):
        # equation error alone cannot separate this run's terms: start from the joint fit
        own = joint
    return _refine(own, [p], progress)


def _refine(start: IsolatorModel, prepared: Sequence[PreparedRun], progress: Progress,
            free: Sequence[str] | None = None,
            at_start: tuple[np.ndarray, np.ndarray] | None = None,
            sensitivity: Sequence[tuple[np.ndarray, np.ndarray]] | None = None
            ) -> OutputErrorFit:
    """Output error over the constants of REFINED that these runs determine.

    Checked twice: at the start (cheap, one Jacobian) and at the optimum, where
    the Jacobian is the one that counts; a constant found undetermined there is
    put back to its start value and the rest refitted. The standard errors
    include the estimated input's share (errors in variables, `input_error`).
    """
    runs = [p.oe for p in prepared]
    start = _positive_start(start)
    if free is None:
        free, held, at_start = determined(start, runs, REFINED)
        fit = refine(start, runs, free, at_start=at_start)
    else:  # given (a fit on more data already split them): skip the start's Jacobian
        free, held = tuple(free), tuple(n for n in REFINED if n not in free)
        # from a nearby optimum one checked Gauss–Newton step is the fit
        fit = one_step(start, runs, free, at_start) if at_start is not None else None
        if fit is None:
            fit = refine(start, runs, free, at_start=at_start)
            sensitivity = None  # iterated away from the start: its input sensitivity too
    loose = [n for n, v, s in zip(fit.names, fit.values, fit.std) if s > HOLD_LOG_STD * v]
    if loose:
        held = held + tuple(loose)
        back = {n: start.parameters()[n] for n in loose}
        fit = refine(fit.model.with_parameters(**back), runs,
                     [n for n in free if n not in loose])
    if held:
        progress(f"  held (not determined by these runs): {', '.join(held)}")
    return with_input_uncertainty(fit, runs, [p.table for p in prepared], sensitivity)


def _positive_start(model: IsolatorModel) -> IsolatorModel:
    p = model.parameters()
    return model.with_parameters(**{n: max(p[n], lo) for n, lo in MIN_START.items()})


def run_error(model: IsolatorModel, p: PreparedRun) -> RunError:
    """Simulate the run from its estimated input and compare with the measured signals."""
    r = simulate(model, p.oe.motion, duration=p.oe.t[-1] - p.oe.t[0], dt=p.oe.dt,
                 t0=p.oe.t[0], z0=initial_offset(p.oe))
    n = min(r.t.size, p.z.size)
    coefs = np.array([t.coef for t in model.terms])
    force = model.mass * p.xdd + regressor_matrix(model, p.z, p.zd) @ coefs

    def nrmse(sim: np.ndarray, meas: np.ndarray) -> float:
        return float(np.sqrt(np.mean((sim[:n] - meas[:n]) ** 2)) / np.sqrt(np.mean(meas[:n]**2)))

    return RunError(z=nrmse(r.z, p.z), zd=nrmse(r.zd, p.zd), xdd=nrmse(r.xdd, p.xdd),
                    force_rms=float(np.sqrt(np.mean(force[p.active] ** 2))),
                    residual_over_noise=float(np.sqrt(np.mean((r.x[:n] - p.run.x[:n]) ** 2))
                                              / p.sigma_x))


def flag_runs(per_run: dict[str, OutputErrorFit]) -> dict[str, list[str]]:
    """Runs whose linear coefficients differ from the other runs' (the report's run C).

    Each run is compared with the median of all runs' estimates (robust: the odd
    run does not drag the reference); a coefficient differs when the gap exceeds
    FLAG_SIGMAS standard errors and FLAG_RELATIVE of the median. With fewer than
    three runs there is no majority to differ from, and nothing is flagged.
    """
    if len(per_run) < 3:
        return {}
    flagged: dict[str, list[str]] = {}
    for n in LINEAR:
        values = {r: f.as_dict()[n] for r, f in per_run.items() if n in f.names}
        if len(values) < 3:
            continue
        median = float(np.median(list(values.values())))
        for r, v in values.items():
            f = per_run[r]
            std = float(f.std[f.names.index(n)])
            if abs(v - median) > max(FLAG_SIGMAS * std, FLAG_RELATIVE * abs(median)):
                flagged.setdefault(r, []).append(n)
    return flagged


__all__ = ["IsolatorFit", "MeasuredRun", "PreparedRun", "RunError", "identify", "prepare"]
