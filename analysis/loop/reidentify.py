"""Each force candidate identified from the data again, not refitted from the base's valley.

The base fit has absorbed what a missing effect does into Eq 10's constants: a
large dry friction becomes c2 tanh(βż) with the dead band closed (δ → 0), for
then the two are the same force, and output error refitted from there with the
friction added sees a look-alike of c2 and stays. What sets the friction apart
is the dead band — Eq 10 has only c1 ż inside it, friction acts there too — and
only a fit that searches δ again with the friction in the model can see it.

So each candidate whose force is a function of (z, ż) — a regressor, the
report's appendix A with one more column — is identified by variable projection
(`analysis.identify.varpro.project`): α, β and δ searched, every linear
coefficient and the candidate's solved at each point, from the measured z, ż, ẍ.
Equation error has no valleys along the coefficients, so the start it gives the
output-error refit has never seen the base's compromise; and its σ² with and
without the candidate, both with the shapes searched, ranks the candidates by
what the data say rather than by a linearisation at the base fit.

A term with a state driven by the motion alone (a Bouc–Wen loop's r, the fluid's
θ) has a regressor too, though not of each sample's (z, ż): its column is
integrated along the whole runs (`regressors.campaign_column`), each run from
a zero state or the fluid carried warm from one run into the next, and handed to
the projection beside Eq 10's columns; the way that fits better is the start's.
A base fit far from an unseen thermal drift (α 356 1/m against 81, 409 x noise)
left every start but this one in another valley. Sensor effects have no
regressor; they keep the loop's other starts.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import minimize_scalar

from analysis.identify.pipeline import LINEAR
from analysis.identify.regressors import campaign_column, carries_state
from analysis.identify.varpro import Data, project
from analysis.loop.candidates import Candidate
from analysis.model.isolator import IsolatorModel

SHAPES = ("alpha", "beta", "delta")


@dataclass(frozen=True)
class Reidentified:
    """A model identified by equation error with the candidate in it, and its σ² (N²);
    for a term with a state, whether each run started it from zero (else None)."""

    model: IsolatorModel
    sigma2: float
    fresh_states: bool | None = None
    sensor: dict[str, float] = field(default_factory=dict)  # a sensor effect's value
    # the same candidate with k2 tanh(αz) saturated at the dead band's edge, where
    # equation error cannot tell that from the α it chose (`_saturated`)
    saturated: Reidentified | None = None


@dataclass(frozen=True)
class Moving:
    """The runs' samples with relative motion (`data`), and the whole runs they came
    from: a term with a state is integrated along those, then sampled by `mask`."""

    data: Data
    z: Sequence[np.ndarray]
    zd: Sequence[np.ndarray]
    dt: float
    mask: np.ndarray
    xdd: Sequence[np.ndarray] = ()
    u: Sequence[np.ndarray] = ()  # the table's displacement and velocity (m, m/s): what a
    ud: Sequence[np.ndarray] = ()  # scale error of the mass sensor does not touch


MIN_MOVING = 100  # samples with relative motion an identification by equation error needs


def moving(zd: np.ndarray, stop_velocity: float) -> np.ndarray | None:
    """Which samples have relative motion (appendix A drops rest); None where fewer than
    MIN_MOVING do (a stop velocity a fit has raised past nearly every sample's speed):
    then there is nothing to identify by equation error."""
    mask = np.abs(zd) > max(2.0 * stop_velocity, 1e-3)
    return mask if np.count_nonzero(mask) >= MIN_MOVING else None


def moving_data(z: Sequence[np.ndarray], zd: Sequence[np.ndarray],
                xdd: Sequence[np.ndarray], stop_velocity: float, dt: float,
                u: Sequence[np.ndarray] = (), ud: Sequence[np.ndarray] = ()
                ) -> Moving | None:
    """The runs' samples with relative motion, stacked; None where too few move (`moving`)."""
    zs, zds, xdds = (np.concatenate(list(v)) for v in (z, zd, xdd))
    mask = moving(zds, stop_velocity)
    if mask is None:
        return None
    return Moving(Data(zs[mask], zds[mask], xdds[mask]), list(z), list(zd), dt, mask,
                  list(xdd), list(u), list(ud))


def state_columns(model: IsolatorModel, name: str, runs: Moving) -> dict[bool, np.ndarray]:
    """Term `name`'s column on the moving samples, by whether each run starts its state
    from zero (True) or from where the run before left it (False; the same column for
    a state the regressors reset each run)."""
    j = [t.name for t in model.terms].index(name)
    fresh = campaign_column(model, j, runs.z, runs.zd, runs.dt, carried=False)
    out = {True: fresh[runs.mask]}
    if carries_state(model.terms[j]):  # else the carried column is this one again
        carried = campaign_column(model, j, runs.z, runs.zd, runs.dt)
        if not np.array_equal(carried, fresh):
            out[False] = carried[runs.mask]
    return out


def base_projection(model: IsolatorModel, data: Data) -> Reidentified:
    """Eq 10 (the model's own force terms) with α, β, δ searched: what a candidate must beat."""
    free = [t.name for t in model.terms if t.name in LINEAR or t.coef != 0.0]
    proj = project(model, data, SHAPES, free=free, signed=_signed(model, free))
    return Reidentified(proj.model, proj.fit.sigma2)


def with_candidate(model: IsolatorModel, c: Candidate, param: str, runs: Moving
                   ) -> Reidentified | None:
    """The model with the candidate's term, identified by equation error; None where the
    candidate has no regressor or no shape keeps the springs and dampers positive (the
    projection then stays at its start: nothing was identified).

    A term with a state is projected at each shape of the library's grid too (`shapes`),
    each way its state may start a run; the lowest σ² is the start. Its column costs one
    integration along the runs, a projection ~0.1 s."""
    if not c.term_kind or param not in model.parameters():
        return None
    free = [t.name for t in model.terms if t.name in LINEAR or t.coef != 0.0 or t.name == param]
    # the effect's own sign is checked after the solve: a drift's c_T is negative
    signed = _signed(model, free) + [param]
    if not c.stateful:
        r = _projected(model, c, param, runs.data, free, signed, None)
        return _saturated(r, c, param, runs, free, signed) if r is not None else None
    best = None
    for shape in dict.fromkeys([c.shape, *c.shapes]):
        m = _reshaped(model, param, shape)
        for fresh, col in state_columns(m, param, runs).items():
            r = _projected(m, c, param, replace(runs.data, columns={param: col}), free,
                           signed, fresh)
            if r is not None and (best is None or r.sigma2 < best.sigma2):
                best = r
    if best is not None and c.term_kind == "thermal_damper":
        best = _damping_kept(best, c, param, runs, free, signed)
    return _saturated(best, c, param, runs, free, signed) if best is not None else None


# α δ below which k2 tanh(αz) is a softening spring across the stroke rather than a step
# at the dead band's edge, and the α δ values tried for the step (tanh 0.76 to 0.999)
SOFT_EDGE = 1.0
STEP_EDGE = 2.0  # a step at the edge: tanh 0.96 there (a preload's force handed back too)
SATURATED_EDGE = (SOFT_EDGE, STEP_EDGE, 4.0)
# σ² within this fraction of the chosen shape's: equation error cannot tell the two apart
# (its ẍ is differentiated twice; output error can)
INDISTINCT = 0.05


def _saturated(r: Reidentified, c: Candidate, param: str, runs: Moving, free: Sequence[str],
               signed: Sequence[str]) -> Reidentified:
    """`r`, with the candidate identified again at α δ in SATURATED_EDGE, β and δ searched,
    as `r.saturated` where one of those fits within INDISTINCT of `r`'s σ².

    A stiffness effect the model lacks (a hardening, a compression-only spring) bends
    k2 tanh(αz) into a softening spring across the stroke, α a tenth of Table 1's, and
    equation error with the effect added keeps that α: its cost is flat in α to 1 %
    from 10 to 2000 1/m (an unseen compression spring, α 98 1/m at δ 23 mm). Output
    error is not flat: refitted from α 8.6 1/m the campaign stayed at 2.9 x noise, from
    its truth 1.0 x. A drift named after such a spring needs it too: with the
    compression spring's refit from the saturated spring accepted, an unseen drift
    refitted from equation error's soft α stayed at 14.5 x noise, 1.09 x with this.
    """
    p = r.model.parameters()
    delta = p.get("delta", 0.0)
    # not for a force that does not bend the spring's shape along z: a constant offset;
    # nor for a preload, the saturated spring's look-alike, whose own starts search the
    # valley where the two trade (`candidate_fit._split_starts`)
    if (c.takes_over == "k2" or c.term_kind == "force_offset" or "alpha" not in p
            or p.get("k2", 0.0) == 0.0 or delta <= 0.0 or p["alpha"] * delta >= SOFT_EDGE):
        return r
    data = runs.data
    if c.stateful:  # its column as `r` started the runs (α moves it not)
        cols = state_columns(r.model, param, runs)
        data = replace(data, columns={param: cols.get(bool(r.fresh_states), cols[True])})
    best = None
    for edge in SATURATED_EDGE:
        m = r.model.with_parameters(alpha=edge / delta)
        at = _projected(m, c, param, data, free, signed, r.fresh_states, ("beta", "delta"))
        if at is not None and (best is None or at.sigma2 < best.sigma2):
            best = at
    if best is None or best.sigma2 > (1.0 + INDISTINCT) * r.sigma2:
        return r
    return replace(r, saturated=best)


def with_sensor_gain(model: IsolatorModel, c: Candidate, runs: Moving) -> Reidentified | None:
    """The mass sensor's scale identified with Eq 10. Where the sensor reads (1 + g) x,
    the mass moved x_meas/(1 + g): appendix A on that motion, α, β, δ searched, fits
    best at the sensor's gain, its σ² taken in the measured force's scale ((1 + g)² σ²:
    shrinking the motion must not count as explaining it). Searched over g by bounded
    Brent (~20 projections). A base fit bends k1, α and δ to absorb a gain (an unseen
    7.8 % one: refitted from there the gain stayed 13 x the noise)."""
    if not runs.u:
        return None
    free = [t.name for t in model.terms if t.name in LINEAR or t.coef != 0.0]
    signed = _signed(model, free)

    # the moving samples once: each g only rescales them
    u, ud = (np.concatenate(v)[runs.mask] for v in (runs.u, runs.ud))
    x = np.concatenate(runs.z)[runs.mask] + u
    xd = np.concatenate(runs.zd)[runs.mask] + ud
    xdd = np.concatenate(runs.xdd)[runs.mask]

    def data_at(g: float) -> Data:
        s = 1.0 + g
        return Data(x / s - u, xd / s - ud, xdd / s)

    def cost(g: float) -> float:
        v = project(model, data_at(g), SHAPES, free=free, signed=signed).fit.sigma2
        return (1.0 + g) ** 2 * v if np.isfinite(v) else 1e300

    lo, hi = c.bounds(model)
    g = float(minimize_scalar(cost, bounds=(lo, hi), method="bounded",
                              options={"xatol": 1e-3}).x)
    proj = project(model, data_at(g), SHAPES, free=free, signed=signed)
    if not np.isfinite(proj.fit.sigma2) or np.any(
            [v <= 0 for n, v in proj.fit.as_dict().items() if n not in signed]):
        return None
    return Reidentified(proj.model, proj.fit.sigma2, sensor={c.parameter: g})


def _reshaped(model: IsolatorModel, param: str, shape: tuple[float, ...]) -> IsolatorModel:
    return model.with_parameters(**dict(zip(model.term(param).shape_names(), shape)))


def _projected(model: IsolatorModel, c: Candidate, param: str, data: Data,
               free: Sequence[str], signed: Sequence[str], fresh: bool | None,
               shapes: Sequence[str] = SHAPES) -> Reidentified | None:
    """The candidate's model projected with `shapes` searched; None where the candidate
    comes out of its own sign or another spring or damper not positive."""
    proj = project(model, data, shapes, free=free, signed=signed)
    values = proj.fit.as_dict()
    if not np.isfinite(proj.fit.sigma2) or c.sign * values[param] < 0 or np.any(
            [v <= 0 for n, v in values.items() if n not in signed]):
        return None
    return Reidentified(proj.model, proj.fit.sigma2, fresh)


def _damping_kept(r: Reidentified, c: Candidate, param: str, runs: Moving,
                  free: Sequence[str], signed: Sequence[str]) -> Reidentified:
    """The drift stopped where it would take all of c1: a fluid thins to its hot
    viscosity, not to a negative one. The measured motion may never heat the fluid that
    far, and equation error then sees no limit at all; but a refit's trial motions
    can, and output error through a negative damping goes elsewhere: an unseen drift
    (cooling in 4.1 s, measured θ at most 0.29 K) refitted from the limit at c1/|c_T|
    (0.41 K) reached 1.4 x noise, from none or from 0.8 K 54–68 x."""
    p = r.model.parameters()
    if p[param] == 0.0:
        return r  # equation error found no drift (a faint name tried): no limit to put
    heating, tau, theta_max = r.model.term(param).shape
    limit = p["c1"] / abs(p[param])
    if 0.0 < theta_max <= limit:
        return r
    m = _reshaped(r.model, param, (heating, tau, limit))
    cols = state_columns(m, param, runs)
    col = cols.get(bool(r.fresh_states), cols[True])
    again = _projected(m, c, param, replace(runs.data, columns={param: col}), free, signed,
                       r.fresh_states)
    return again if again is not None else r


def _signed(model: IsolatorModel, free: Sequence[str]) -> list[str]:
    """Effects already added whose sign is free (an offset, an asymmetry): not required > 0."""
    return [n for n in free if n not in LINEAR and model.term(n).kind in
            ("extension_damper", "compression_spring", "force_offset", "cubic_spring")]
