"""Which effect the data ask for next: equation error with a matched filter, judged by BIC.

Output error tells a right model from a wrong one but is slow and many-valleyed;
naming needs a fast look at every candidate from the same start. This is that
look, the report's appendix A with one column per candidate:

- the target is the mass force m ẍ, its ẍ a Savitzky–Golay second derivative of
  the measured x (0.05 s, cubic). That derivative is a smoothing kernel H applied
  to the true ẍ (H, the double running sum of the SG kernel, has unit sum), so
  every regressor φ(z, ż) is filtered by the same H: the spring force's jump at
  the dead band's edge is smeared in the regressor exactly as in the target, and
  no sample near an edge is misfit;
- z and ż come from a shorter smoothing (0.021 s) of x less the estimated table
  motion, and only samples in motion (|ż| > 5 mm/s, a window away from any rest:
  static friction is in no column) are used, one per half window — the filtered
  residual is correlated over about that, so the rows are near independent and
  BIC's n means something;
- the dead band δ is searched again with each candidate (a large dry friction
  is c2 tanh(βż) when δ → 0, which is where a base fit without it goes);
- a sensor delay d shows in the force as −d (F_z u̇ + F_ż ü), a mass-sensor gain
  g as g (F_z x + F_ż ẋ), both from the current model's F: one column each.

Forward selection: the candidate whose column lowers BIC = n ln(RSS/n) + p ln n
the most is next, if it lowers it by more than `BIC_MARGIN`. The loop refits by
output error only what this names, in its order.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.ndimage import minimum_filter1d
from scipy.optimize import lsq_linear
from scipy.signal import lfilter, savgol_coeffs, savgol_filter

from analysis.identify.pipeline import LINEAR
from analysis.identify.regressors import campaign_regressors
from analysis.identify.run_data import RunData
from analysis.loop.candidates import CANDIDATES, SENSOR_DELAY, SENSOR_GAIN, Candidate
from analysis.model.isolator import IsolatorModel
from analysis.model.terms import kind

ACCELERATION_WINDOW = 0.051  # s: the SG second derivative of x (cubic)
STATE_WINDOW = 0.021  # s: z and ż (cubic): short enough to keep the dead band's edges
MOVING = 5e-3  # m/s: slower, the mass may be held by static friction (in no column)
# BIC must fall by more than this: "very strong" evidence on Kass & Raftery's scale, and
# room for what no column holds even on a right model (static friction, the smoothing)
BIC_MARGIN = 10.0
DELTA_GRID = np.linspace(0.0, 0.04, 41)  # m: the dead band searched with each candidate
SATURATION_FRACTIONS = (0.25, 0.5)  # of the peak θ: where a thermal drift may stop
# BIC apart by less than this, two shapes of one effect are "not worth more than a bare
# mention" apart on Kass & Raftery's scale: equation error cannot choose between them
SHAPE_TIE = 2.0


@dataclass(frozen=True)
class Naming:
    """The candidates the equation error selects, in order, with their BIC falls."""

    order: tuple[str, ...]
    gains: tuple[float, ...]  # BIC fall of each, in order
    first: dict[str, float]  # every candidate's BIC fall at the first step (evidence)
    delta: float  # m, the dead band of the last selection
    rows: int  # samples the selection used
    # the shape each candidate with shapes to choose was selected at (`Candidate.shapes`), or,
    # not selected, its best at the first step; absent at the library's own shape
    shapes: dict[str, tuple[float, ...]] = field(default_factory=dict)
    # the first name equation error gave at other constants of the same model, where it
    # differs from this one's (`close._name`): refitted next, should the top be refused
    other_first: tuple[str, ...] = ()
    # the names above the margin at those other constants that this view does not rank
    # there: tried after this view's own (`close._name`)
    other_runners: tuple[str, ...] = ()

    @property
    def top_gain(self) -> float:
        """The first name's BIC fall; -inf when nothing is named."""
        return self.gains[0] if self.gains else -np.inf

    def to_try(self) -> tuple[str, ...]:
        """The top name, then, should it be refused, the first name at the other
        constants (`other_first`), then the others above the margin in the order of
        their first step's BIC falls: the forward order after the top holds only with
        the top in the model (a hardening spring's cubic, 3 behind a preload at the
        first step, fell below the margin with the preload in); last the names only
        the other constants rank (`other_runners`)."""
        ahead = self.order[:1] + self.other_first
        rest = sorted((n for n, f in self.first.items() if f > BIC_MARGIN
                       and n not in ahead), key=lambda n: (-self.first[n], n))
        return tuple(dict.fromkeys(ahead + tuple(rest) + self.other_runners))

    def weak(self) -> tuple[str, ...]:
        """The candidate whose column lowered BIC most at the first step, where it lowered
        it at all but by no more than the margin: equation error's ẍ is the noise
        differentiated twice, and a slow force in the low hertz can sit well above the
        sensor noise in x while it barely shows there (a 3.3 % one-sided stiffness on an
        unseen campaign: BIC fall 4.5 on 339 rows, 11.0 x noise by output error, at
        1.00 x with it)."""
        return tuple(n for n in self.faint(1) if self.first[n] > 0.0)

    def faint(self, k: int) -> tuple[str, ...]:
        """The `k` candidates whose columns lowered BIC most at the first step, whether
        they lowered it or not: at a step after the first, with the noise high, every
        fall can sit under the price of a column, and the order is all equation error
        has to say (an unseen 3.5 % hardening spring beside a friction, at 2.3 x the
        rig's noise: the cubic's −3.6 was the best, a one-sided damping's −5.3)."""
        return tuple(sorted(self.first, key=lambda n: (self.first[n], n), reverse=True)[:k])


@dataclass(frozen=True)
class _Columns:
    y: np.ndarray  # filtered, decimated m ẍ
    fixed: dict[str, np.ndarray]  # columns that do not depend on δ
    gated: dict[str, np.ndarray]  # (len(deltas), n) columns that do
    deltas: np.ndarray  # m, the dead bands of the gated columns' rows


def name_effects(model: IsolatorModel, runs: Sequence[RunData], sensor_delay: float = 0.0,
                 present: Sequence[str] = (), max_effects: int = 4) -> Naming:
    """Forward selection by BIC over the candidates not `present` (candidate names)."""
    samples = _samples(runs, model.mass, sensor_delay)
    model = _eq10_shapes(model, samples)
    variants = _variants([n for n in CANDIDATES if n not in present], samples)
    cols = _columns(model, samples, variants)
    base = [n for n in cols.fixed if n.startswith("base:")] + \
        [n for n in cols.gated if n.startswith("base:")]
    pool = sorted({n.split(":", 1)[1] for n in (*cols.fixed, *cols.gated)
                   if n.startswith("cand:")})
    n = cols.y.size
    chosen: list[str] = []
    gains: list[float] = []
    first: dict[str, float] = {}
    first_shape: dict[str, tuple[float, ...]] = {}
    current, delta = _best_bic(cols, base, n)
    while pool and len(chosen) < max_effects:
        trial = {c: _best_bic(cols, base + [f"cand:{x}" for x in chosen + [c]], n)
                 for c in pool}
        falls = {c: current - b for c, (b, _) in trial.items()}
        if not chosen:
            for c in sorted(falls):  # a shaped candidate's evidence: its best shape's
                if falls[c] > first.get(_name(c), -np.inf):
                    first[_name(c)] = falls[c]
                    first_shape[_name(c)] = variants[c].shape
        best = _freed_at_tie(_top(falls, falls), falls)
        if falls[best] <= BIC_MARGIN:
            break
        chosen.append(best)
        gains.append(falls[best])
        current, delta = trial[best]
        pool = [c for c in pool if _name(c) != _name(best)]
    shapes = {k: v for k, v in {**first_shape, **{_name(c): variants[c].shape for c in chosen}}
              .items() if v != CANDIDATES[k].shape}
    return Naming(tuple(_name(c) for c in chosen), tuple(gains), first, delta, n, shapes)


def _freed_at_tie(best: str, falls: dict[str, float]) -> str:
    """`best`, or where it is an effect at the library's shape and a shape a refit frees
    lies within SHAPE_TIE of it, the best such shape. The library's shape is held by the
    refit, a chosen one is freed: output error can walk from a friction built up over
    6 mm/s to one over 1 mm/s, never from the step to 6 mm/s. At a tie, the choice would
    otherwise fall to rounding (unseen Coulomb + hardening: the step 131.4, 6 mm/s 130.9;
    their order, and whether anything was named, followed the BLAS kernel)."""
    if "@" in best or not CANDIDATES[best].free_shape:
        return best
    near = [c for c in falls if _name(c) == best and c != best
            and falls[c] >= falls[best] - SHAPE_TIE]
    return _top(near, falls) if near else best


def _top(labels: Iterable[str], falls: dict[str, float]) -> str:
    """The label of `labels` with the largest fall; ties by name: deterministic."""
    return max(labels, key=lambda c: (falls[c], c))


def _variants(names: Sequence[str], samples: _Samples) -> dict[str, Candidate]:
    """Each candidate under its own name, at the library's shape; one with other shapes
    to choose also under 'name@i' for each of them (its parameter renamed alike: one
    model holds them all while the columns are built). Only those count a shape in BIC:
    the library's shape is the prior, not a choice."""
    out: dict[str, Candidate] = {}
    for name in names:
        c = out[name] = CANDIDATES[name]
        shapes = list(c.shapes)
        if c.term_kind == "thermal_damper":
            shapes += _saturated(c.shapes, samples)
        for i, shape in enumerate(shapes):
            if tuple(shape) != c.shape:
                out[f"{name}@{i}"] = replace(c.shaped(shape), parameter=f"{c.parameter}@{i}")
    return out


def _saturated(shapes: Sequence[tuple[float, ...]], samples: _Samples
               ) -> list[tuple[float, ...]]:
    """Each thermal shape again with its drift stopped at fractions of the peak θ the
    measured motion heats the fluid to: where the damping thins to nothing is a
    property of the fluid, not of the library, so the limit is placed by the data."""
    out = []
    for heating, tau, _ in shapes:
        peak = fluid_temperature_peak([pr[1] for pr in samples.per_run], samples.dt,
                                      heating, tau)
        out += [(heating, tau, f * peak) for f in SATURATION_FRACTIONS if peak > 0.0]
    return out


def fluid_temperature_peak(zd: Sequence[np.ndarray], dt: float, heating: float,
                           tau: float) -> float:
    """The largest θ of θ' = a ż² − θ/τ along the runs in turn, the fluid carried warm
    from one into the next (as the equation error's columns carry it), K."""
    decay = np.exp(-dt / tau)
    theta, peak = 0.0, 0.0
    for v in zd:
        series, _ = lfilter([heating * dt], [1.0, -decay], v * v, zi=[theta * decay])
        theta, peak = float(series[-1]), max(peak, float(series.max()))
    return peak


def _name(label: str) -> str:
    return label.split("@", 1)[0]


SHAPE_SPAN = np.geomspace(0.25, 4.0, 9)  # α and β searched over this span of the model's


def _eq10_shapes(model: IsolatorModel, samples: _Samples) -> IsolatorModel:
    """The model with α and β searched again by the same equation error, without any
    candidate: a base fit that has absorbed an effect moves them (a Bouc–Wen loop
    pushed α and β until a dry friction's column fitted better than its own)."""
    p = model.parameters()
    best = (np.inf, model)
    for a in p["alpha"] * SHAPE_SPAN:
        for b in p["beta"] * SHAPE_SPAN:
            m = model.with_parameters(alpha=float(a), beta=float(b))
            cols = _columns(m, samples, {}, deltas=(m.dead_band,))
            names = list(cols.fixed) + list(cols.gated)
            rss = _best_bic(cols, names, cols.y.size, signed=False)[0]
            if rss < best[0]:
                best = (rss, m)
    return best[1]


def _best_bic(cols: _Columns, names: list[str], n: int, signed: bool = True
              ) -> tuple[float, float]:
    """(BIC, δ) of the columns `names` with δ searched over the grid, the signs physics
    fixes kept where `signed`."""
    fixed_names = [k for k in names if k in cols.fixed]
    fixed = np.column_stack([cols.fixed[k] for k in fixed_names] or [np.zeros(n)])
    gated = [k for k in names if k in cols.gated]
    sign = force_sign if signed else (lambda k: 0)
    # the zero column that stands in for no fixed one is free
    signs = ([sign(k) for k in fixed_names] or [0]) + [sign(k) for k in gated]
    p = len(names) + 1 + sum("@" in k for k in names)  # the coefficients, δ, chosen shapes
    best = (np.inf, 0.0)
    for i, d in enumerate(cols.deltas):
        A = np.column_stack([fixed] + [cols.gated[k][i] for k in gated])
        coef = signed_least_squares(A, cols.y, signs)
        rss = float(np.sum((cols.y - A @ coef) ** 2))
        bic = n * np.log(max(rss, 1e-300) / n) + p * np.log(n)
        if bic < best[0]:
            best = (bic, float(d))
    return best


# The physics fixes some signs, and output error fits only those (Eq 10's k2 and c2 in
# log coordinates, a candidate within `Candidate.bounds`); equation error keeps them too.
# Free in sign, k2 tanh(αz) at k2 < 0 is a hardening spring: unseen hardening 316 (20 %
# of the peak force) and the Coulomb + hardening pair 5030 hid their cubic in it (BIC
# falls 4.2 and −3.5; kept ≥ 0, 84 and 43), and no refit of the cubic was tried
SIGNED_BASE = {"base:k2": +1, "base:c2": +1}


def force_sign(column: str) -> int:
    """The sign physics fixes for the force coefficient of a column ('base:<term>' or
    'cand:<candidate>[@shape]'): +1, −1, or 0 where either is possible."""
    if column.startswith("cand:"):
        return CANDIDATES[_name(column.split(":", 1)[1])].sign
    return SIGNED_BASE.get(column, 0)


def signed_least_squares(A: np.ndarray, y: np.ndarray, signs: Sequence[int]) -> np.ndarray:
    """Least-squares coefficients of y = m ẍ = −F on A's force columns, each column's
    force coefficient of the sign `signs` gives it (0: free), i.e. the coefficient of y
    of the opposite sign: the free solution where it keeps them, else bounded-variable
    least squares on the columns scaled to unit norm (they span decades: z against z³)."""
    coef = np.linalg.lstsq(A, y, rcond=None)[0]
    sg = np.asarray(signs, float)
    if not np.any(coef * sg > 0.0):
        return coef
    norm = np.linalg.norm(A, axis=0)
    norm[norm == 0.0] = 1.0
    lower = np.where(sg < 0, 0.0, -np.inf)
    upper = np.where(sg > 0, 0.0, np.inf)
    return lsq_linear(A / norm, y, bounds=(lower, upper), method="bvls").x / norm


def _odd(seconds: float, dt: float) -> int:
    k = max(round(seconds / dt), 5)
    return k + 1 - k % 2


def _matched_kernel(window: int, dt: float) -> np.ndarray:
    """H with SG''(x) = H ∗ ẍ: the double running sum of the SG kernel (unit sum)."""
    c = savgol_coeffs(window, 3, deriv=2, delta=dt)
    return (np.cumsum(np.cumsum(c)) * dt * dt)[:-2]


@dataclass(frozen=True)
class _Samples:
    """Each run's smoothed states, table motion, target and kept rows: what every
    column is built from, whatever the model's constants."""

    per_run: list[tuple[np.ndarray, ...]]  # (z, ż, x, ẋ, u̇, ü, m ẍ, kept rows)
    H: np.ndarray  # the matched filter
    dt: float
    windows: list[np.ndarray]  # per run: the rows H spans around each kept row (`_windows`)


def _samples(runs: Sequence[RunData], mass: float, sensor_delay: float) -> _Samples:
    dt = float(runs[0].t[1] - runs[0].t[0])
    wa, ws = _odd(ACCELERATION_WINDOW, dt), _odd(STATE_WINDOW, dt)
    stride = max(wa // 2, 1)
    per_run = []
    for r in runs:
        t = r.t - sensor_delay if sensor_delay else r.t
        u, ud, udd = (r.motion(t, k) for k in (0, 1, 2))
        xs = savgol_filter(r.x, ws, 3, mode="nearest")
        xd = savgol_filter(r.x, ws, 3, deriv=1, delta=dt, mode="nearest")
        y = mass * savgol_filter(r.x, wa, 3, deriv=2, delta=dt, mode="nearest")
        z, zd = xs - u, xd - ud
        moving = minimum_filter1d((np.abs(zd) > MOVING).astype(np.uint8), wa) > 0
        moving[:wa] = moving[-wa:] = False
        keep = np.flatnonzero(moving)[::stride]
        per_run.append((z, zd, xs, xd, ud, udd, y, keep))
    H = _matched_kernel(wa, dt)
    return _Samples(per_run, H, dt, [_windows(pr[7], pr[0].size, H.size) for pr in per_run])


def _windows(rows: np.ndarray, n: int, width: int) -> np.ndarray:
    """(rows, width) indices such that x[w] @ H is convolve1d(x, H, mode="nearest")[rows]
    for a kernel H of odd `width`: the filter at the kept rows only, where every column
    is filtered at every δ of the grid and a full convolution of each threw away all but
    one sample in 25 (its numbers agree to the last few bits, 7e-16 of the peak)."""
    return np.clip(rows[:, None] + (width // 2 - np.arange(width))[None, :], 0, n - 1)


def _columns(model: IsolatorModel, samples: _Samples, candidates: dict[str, Candidate],
             deltas: Sequence[float] = tuple(DELTA_GRID)) -> _Columns:
    """Every column on the moving samples of every run, filtered and decimated."""
    per_run, H, dt, W = samples.per_run, samples.H, samples.dt, samples.windows
    models = {name: c.add_to(model) for name, c in candidates.items()
              if c.term_kind}  # the model with the candidate, its parameter
    everything = model  # the model's own terms and every force candidate's
    for name in models:
        everything = candidates[name].add_to(everything)[0]
    gated_terms = everything.structure()[1]

    def stack(cols: Sequence[np.ndarray]) -> np.ndarray:
        return np.concatenate([col[w] @ H for col, w in zip(cols, W)])

    y = np.concatenate([pr[6][pr[7]] for pr in per_run])
    fixed: dict[str, np.ndarray] = {}
    gated: dict[str, list[np.ndarray]] = {}
    zs, zds = [pr[0] for pr in per_run], [pr[1] for pr in per_run]
    blocks = np.cumsum([0] + [len(z) for z in zs])
    opened = _opened(everything, zs, zds, dt)
    for d in deltas:
        Z = _closed_to(opened, gated_terms, _band(d))
        for j, term in enumerate(everything.terms):
            key = _key(model, term.name, models)
            if key is None or (not gated_terms[j] and key in fixed):
                continue  # (an ungated column is the same at every dead band)
            col = stack([Z[a:b, j] for a, b in zip(blocks[:-1], blocks[1:])])
            if not gated_terms[j]:
                fixed[key] = col
            else:
                gated.setdefault(key, []).append(col)
    if SENSOR_DELAY in candidates or SENSOR_GAIN in candidates:
        own = [k for k in fixed if k.startswith("base:")]
        own_gated = [k for k in gated if k.startswith("base:")]
        shifted = _shifted(model, zs, zds, dt)
        for i, d in enumerate(deltas):
            # the slopes of the force this δ's equation error fits, not of the model's: a
            # base fit bends its k's, α and δ to absorb a gain, and the gain's column from
            # that bent force explained nothing (BIC -4.9, 97 from the generating constants)
            A = np.column_stack([fixed[k] for k in own] + [gated[k][i] for k in own_gated])
            coef = signed_least_squares(A, y, [force_sign(k) for k in own + own_gated])
            at = model.with_parameters(delta=_band(d), **{
                k.split(":", 1)[1]: float(c) for k, c in zip(own + own_gated, coef)})
            Fz, Fzd = _force_slopes(at, shifted, [len(z) for z in zs])
            if SENSOR_DELAY in candidates:
                gated.setdefault(f"cand:{SENSOR_DELAY}", []).append(stack(
                    [-(a * pr[4] + b * pr[5]) for a, b, pr in zip(Fz, Fzd, per_run)]))
            if SENSOR_GAIN in candidates:
                gated.setdefault(f"cand:{SENSOR_GAIN}", []).append(stack(
                    [a * pr[2] + b * pr[3] for a, b, pr in zip(Fz, Fzd, per_run)]))
    return _Columns(y, fixed, {k: np.array(v) for k, v in gated.items()},
                    np.asarray(deltas, float))


def _key(model: IsolatorModel, term: str, models: dict[str, tuple[IsolatorModel, str]]
         ) -> str | None:
    """'base:<term>' for the model's own acting terms, 'cand:<candidate>' for a
    candidate's, None for a term at zero that no candidate names."""
    own = {t.name: t for t in model.terms}
    if term in own and (term in LINEAR or own[term].coef != 0.0):
        return f"base:{term}"
    for name, (_, param) in models.items():
        if param == term:
            return f"cand:{name}"
    return None


OPEN_BAND = 1e-9  # m: the dead band the naming's columns are built at, then closed to each δ


def _band(d: float) -> float:
    """A dead band of the search as its columns are built: at least OPEN_BAND."""
    return max(float(d), OPEN_BAND)


@dataclass(frozen=True)
class _Opened:
    """The regressors at the narrowest dead band, and |z| per row: closed to any wider
    band by zeroing the gated columns' rows inside it (`_closed_to`)."""

    Z: np.ndarray
    abs_z: np.ndarray


def _opened(model: IsolatorModel, z: Sequence[np.ndarray], zd: Sequence[np.ndarray],
            dt: float) -> _Opened:
    return _Opened(campaign_regressors(model.with_parameters(delta=OPEN_BAND), z, zd, dt),
                   np.abs(np.concatenate(z)))


def _closed_to(opened: _Opened, gated: np.ndarray, delta: float) -> np.ndarray:
    """The regressors at dead band `delta` (≥ OPEN_BAND): a gated term's basis is 0 where
    |z| ≤ δ and the same everywhere else, whatever δ is (`regressors._series`), so this
    is `campaign_regressors` at δ to the last bit, without integrating the columns again
    for every δ of the search (41 of them, each with the force's four shifts below:
    about a third of the naming's time)."""
    inside = opened.abs_z <= delta
    return np.where(inside[:, None] & np.asarray(gated, bool)[None, :], 0.0, opened.Z)


SLOPE_STEPS = (1e-4, 1e-3)  # m, m/s: below the motion's scale, above rounding


def _shifted(model: IsolatorModel, z: Sequence[np.ndarray], zd: Sequence[np.ndarray],
             dt: float) -> tuple[_Opened, ...]:
    """The model's regressors at z + hz, z − hz, ż + hv, ż − hv (`_force_slopes`)."""
    hz, hv = SLOPE_STEPS
    return (_opened(model, [v + hz for v in z], zd, dt),
            _opened(model, [v - hz for v in z], zd, dt),
            _opened(model, z, [v + hv for v in zd], dt),
            _opened(model, z, [v - hv for v in zd], dt))


def _force_slopes(model: IsolatorModel, shifted: Sequence[_Opened], sizes: Sequence[int]
                  ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """∂F/∂z and ∂F/∂ż of the model's stateless force along each run (central
    differences of the regressors `_shifted` built, at the model's dead band)."""
    coef = np.array([t.coef for t in model.terms])
    stateless = np.array([not kind(t.kind).has_state for t in model.terms])
    coef = np.where(stateless, coef, 0.0)
    gated = model.structure()[1]
    hz, hv = SLOPE_STEPS
    up_z, down_z, up_zd, down_zd = (_closed_to(o, gated, model.dead_band) @ coef
                                    for o in shifted)
    Fz = (up_z - down_z) / (2 * hz)
    Fzd = (up_zd - down_zd) / (2 * hv)
    edges = np.cumsum([0, *sizes])
    return ([Fz[a:b] for a, b in itertools.pairwise(edges)],
            [Fzd[a:b] for a, b in itertools.pairwise(edges)])
