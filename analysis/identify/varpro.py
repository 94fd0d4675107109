"""Separable least squares (variable projection) over the report's hand-tuned constants.

For fixed shape constants θ = (α, β, δ) Eq 10 is linear in the coefficients,
so the equation-error variance σ²(θ) is a function of θ alone: solve the
linear problem inside, search θ outside. The report tuned θ by trial and error
on σ² and the conditioning of V; this does the same search automatically.

The search starts from a coarse grid (which doubles as the cost profile over
α and β that the report could not show: a saturating tanh makes them weakly
determined) and refines the best grid point with a bounded Nelder–Mead in log
coordinates. Shape constants at which a coefficient turns negative are refused
(cost ∞): there two columns cancel each other, not physics.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize

from analysis.identify.equation_error import LinearFit, fit_coefficients
from analysis.identify.regressors import term_column
from analysis.model.isolator import IsolatorModel

# search bounds in SI; α, β in 1/m and s/m: tanh saturates at z ≈ 3/α, ż ≈ 3/β
BOUNDS = {"alpha": (2.0, 2000.0), "beta": (1.0, 2000.0), "delta": (0.0, 0.05)}


@dataclass(frozen=True)
class Projection:
    """Best shape constants, the linear fit at them, and the cost profile."""

    shapes: dict[str, float]
    fit: LinearFit
    model: IsolatorModel
    profile_alpha: np.ndarray  # grid of α (1/m)
    profile_beta: np.ndarray  # grid of β (s/m)
    profile_cost: np.ndarray  # (len α, len β) σ² minimised over δ and the coefficients, N²
    evaluations: int


@dataclass(frozen=True)
class Data:
    """Stacked samples of one or several runs: z (m), ż (m/s), ẍ (m/s²); and the column
    of each term with a state (Bouc–Wen r, fluid θ), by name: integrated along the whole
    runs before their samples were chosen, so it is no function of these samples alone."""

    z: np.ndarray
    zd: np.ndarray
    xdd: np.ndarray
    columns: Mapping[str, np.ndarray] = field(default_factory=dict)


def _cost(model: IsolatorModel, data: Data, free: Sequence[str], values: dict[str, float],
          signed: Sequence[str] = ()) -> tuple[float, LinearFit, IsolatorModel]:
    m = model.with_parameters(**values)
    fit = fit_coefficients(m, data.z, data.zd, data.xdd, free=free, columns=data.columns)
    # Eq 10's coefficients are all positive (springs and dampers); a negative one means
    # two columns have become look-alikes (tanh(αz) ≈ αz for small α) and cancel
    if np.any((fit.values <= 0) & ~np.isin(list(fit.names), list(signed))):
        return np.inf, fit, m
    return fit.sigma2, fit, m


class Gram:
    """σ²(shapes) from cached columns and their dot products.

    A grid point changes one shape constant at a time, and each constant enters
    one column (α: the tanh spring; β: the tanh damper; δ: the gated terms), so
    most columns, and most of their dot products, were built at an earlier
    point. The normal equations need only those products: with r = y + Z k and
    k = −(ZᵀZ)⁻¹Zᵀy, rᵀr = yᵀy + kᵀZᵀy. The columns are scaled to unit norm
    first, so the Gram matrix's condition is the square of a modest number, and
    the result agrees with the full appendix-A solve (QR, pseudo-inverse) to
    rounding, at ~1/50 of its cost.
    """

    def __init__(self, model: IsolatorModel, data: Data) -> None:
        self.model, self.data = model, data
        self.ids: dict[tuple | str, int] = {"y": 0}  # column key → index into `columns`
        self.columns: list[np.ndarray] = [model.mass * data.xdd]
        self.dots: dict[tuple[int, int], float] = {}
        self.shape_names = [t.shape_names() for t in model.terms]

    def _keys(self, values: dict[str, float]) -> list[tuple]:
        delta = values.get("delta", self.model.dead_band)
        return [(j, tuple(values.get(n, v) for n, v in zip(names, t.shape)),
                 delta if t.is_gated else None)
                for j, (t, names) in enumerate(zip(self.model.terms, self.shape_names))]

    def _dot(self, a: int, b: int) -> float:
        key = (a, b) if a <= b else (b, a)
        d = self.dots.get(key)
        if d is None:
            d = self.dots[key] = float(self.columns[a] @ self.columns[b])
        return d

    def _ids(self, values: dict[str, float]) -> list[int]:
        """Each term's column index at these shape constants, building missing columns."""
        keys = self._keys(values)
        missing = [key for key in keys if key not in self.ids]
        if missing:
            m = self.model.with_parameters(**values)
            given = self.data.columns
            for key in missing:
                self.ids[key] = len(self.columns)
                name = self.model.terms[key[0]].name
                self.columns.append(given[name] if name in given else
                                    term_column(m, key[0], self.data.z, self.data.zd))
        return [self.ids[key] for key in keys]

    def sigma2_many(self, free: Sequence[str], points: Sequence[dict[str, float]],
                    signed: Sequence[str] = ()) -> np.ndarray:
        """`sigma2` at many points at once (the grid), each ≤ 1e-12 relative of it.

        Every dot product comes from one matrix product of all the columns, and
        the small normal equations are solved as one stack: the grid's 729
        points cost ~1/10 of solving them one by one in Python.
        """
        ids = np.array([self._ids(v) for v in points])  # (P, J)
        C = np.array(self.columns)
        D = C @ C.T
        terms = self.model.terms
        is_free = np.array([t.name in free for t in terms])
        c = np.array([t.coef for t in terms])[~is_free]
        fi, xi = ids[:, is_free], ids[:, ~is_free]
        G = D[fi[:, :, None], fi[:, None, :]]  # (P, F, F)
        # y' = y + Σ_fixed c_f z_f, as in `sigma2`
        b = D[fi, 0] + np.einsum("pfg,g->pf", D[fi[:, :, None], xi[:, None, :]], c)
        yy = (D[0, 0] + 2.0 * D[0, xi] @ c
              + np.einsum("f,pfg,g->p", c, D[xi[:, :, None], xi[:, None, :]], c))
        scale = np.sqrt(np.diagonal(G, axis1=1, axis2=2))
        dead = np.any(scale == 0, axis=1)  # a column that never acts
        scale[dead] = 1.0
        Gs = G / (scale[:, :, None] * scale[:, None, :])
        Gs[dead] = np.eye(G.shape[1])
        try:
            k = np.linalg.solve(Gs, (-b / scale)[..., None])[..., 0]
        except np.linalg.LinAlgError:  # one singular point: solve them one by one
            return np.array([self.sigma2(free, v) for v in points])
        rr = np.maximum(yy + np.sum(k * (b / scale), axis=1), 0.0)
        out = rr / (self.data.z.size - fi.shape[1])
        positive = np.array([t.name not in signed for t in terms])[is_free]
        out[dead | np.any((k <= 0) & positive, axis=1)] = np.inf
        return out

    def sigma2(self, free: Sequence[str], values: dict[str, float],
               signed: Sequence[str] = ()) -> float:
        """Equation-error σ² (N²) at these shape constants; ∞ where a coefficient is ≤ 0
        (but those named in `signed`: an effect either sign of which is physical)."""
        ids = self._ids(values)
        terms = self.model.terms
        cols = [i for i, t in zip(ids, terms) if t.name in free]
        fixed = [(i, t.coef) for i, t in zip(ids, terms) if t.name not in free]
        # y' = y + Σ_fixed c_f z_f: fixed terms move to the measured side
        yy = self._dot(0, 0) + sum(2 * c * self._dot(0, f) for f, c in fixed) + sum(
            c * d * self._dot(f, g) for f, c in fixed for g, d in fixed)
        b = np.array([self._dot(i, 0) + sum(c * self._dot(i, f) for f, c in fixed)
                      for i in cols])
        G = np.array([[self._dot(i, j) for j in cols] for i in cols])
        scale = np.sqrt(np.diag(G))
        if np.any(scale == 0):
            return np.inf  # a column that never acts (all samples in the dead band)
        try:
            k = np.linalg.solve(G / np.outer(scale, scale), -b / scale)
        except np.linalg.LinAlgError:
            return np.inf
        positive = np.array([t.name not in signed for t in terms if t.name in free])
        if np.any((k <= 0) & positive):  # as `_cost`: a look-alike, not physics
            return np.inf
        rr = max(yy + float(k @ (b / scale)), 0.0)
        return rr / (self.data.z.size - len(cols))


def project(model: IsolatorModel, data: Data, shape_names: Sequence[str] = ("alpha", "beta",
            "delta"), free: Sequence[str] | None = None, grid: int = 9,
            grid_delta: int = 9, signed: Sequence[str] = ()) -> Projection:
    """Minimise σ² over the shape constants `shape_names`; coefficients solved inside.

    Every free coefficient must come out positive but those in `signed`."""
    names = [n for n in shape_names if n in model.parameters()]
    free = [t.name for t in model.terms if t.coef != 0.0] if free is None else list(free)
    evaluations = 0
    gram = Gram(model, data)

    def cost(values: dict[str, float]) -> float:
        nonlocal evaluations
        evaluations += 1
        return gram.sigma2(free, values, signed)

    a_grid = np.geomspace(*BOUNDS["alpha"], grid)
    b_grid = np.geomspace(*BOUNDS["beta"], grid)
    # δ only needs a start for the simplex: the profile shown is over α and β
    d_grid = (np.linspace(*BOUNDS["delta"], grid_delta) if "delta" in names
              else [model.dead_band])
    profile = np.full((grid, grid), np.inf)
    best = (np.inf, {})
    cells, points = [], []
    for i, a in enumerate(a_grid if "alpha" in names else [None]):
        for j, b in enumerate(b_grid if "beta" in names else [None]):
            for d in d_grid:
                cells.append((i, j))
                points.append({k: val for k, val in (("alpha", a), ("beta", b), ("delta", d))
                               if val is not None and k in names})
    costs = gram.sigma2_many(free, points, signed)
    evaluations += len(points)
    for (i, j), v, c in zip(cells, points, costs.tolist()):
        profile[i, j] = min(profile[i, j], c)
        if c < best[0]:
            best = (c, v)
    if not best[1]:
        # no shape keeps every coefficient positive (too little motion in these samples
        # to separate the terms): stay at the start's shapes rather than invent some
        shapes = {n: model.parameters()[n] for n in names}
    else:
        x0 = _to_unit(best[1], names)
        res = minimize(lambda u: cost(_from_unit(u, names)), x0, method="Nelder-Mead",
                       bounds=[(0.0, 1.0)] * len(names),
                       options={"xatol": 1e-4, "fatol": 1e-10 * best[0], "maxiter": 400})
        shapes = _from_unit(res.x, names) if res.fun <= best[0] else best[1]
    _, fit, m = _cost(model, data, free, shapes, signed)
    if best[1]:  # else the coefficients came out negative: keep the start's
        m = m.with_parameters(**fit.as_dict())
    return Projection(shapes=shapes, fit=fit, model=m, profile_alpha=a_grid, profile_beta=b_grid,
                      profile_cost=profile, evaluations=evaluations)


def _to_unit(values: dict[str, float], names: Sequence[str]) -> np.ndarray:
    """Map shape constants into [0, 1]: log scale for α, β; linear for δ."""
    out = []
    for n in names:
        lo, hi = BOUNDS[n]
        v = values[n]
        out.append((np.log(v / lo) / np.log(hi / lo)) if n != "delta" else (v - lo) / (hi - lo))
    return np.array(out)


def _from_unit(u: np.ndarray, names: Sequence[str]) -> dict[str, float]:
    out = {}
    for n, x in zip(names, np.clip(u, 0.0, 1.0)):
        lo, hi = BOUNDS[n]
        out[n] = float(lo * (hi / lo) ** x) if n != "delta" else float(lo + x * (hi - lo))
    return out
