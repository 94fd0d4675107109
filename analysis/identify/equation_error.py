"""Appendix A of the report: Eq 10 by linear least squares, with σ², V and conditioning.

    m ẍ_i + Σ_j z_ij k_j = 0        (Eq A1)
    A = ZᵀZ,  b = Zᵀy,  y = m ẍ     (Eq A9, A10)
    A k = −b                         (Eq A8, A11)
    σ² = εᵀε / (I − J)               (Eq A14),   A V = σ² I   (Eq A15)

Solved here through the QR factorisation of Z (numerically kinder than forming
A), which gives the same k; A itself is kept so the report's numbers can be
reproduced. Only the terms named in `free` are estimated: the others keep
their model value and move to the known side.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from analysis.identify.regressors import regressor_matrix, term_column
from analysis.model.isolator import IsolatorModel


@dataclass(frozen=True)
class LinearFit:
    """Result of one equation-error least-squares solve; SI."""

    names: tuple[str, ...]  # estimated coefficients, in column order
    values: np.ndarray  # (J,) estimates
    covariance: np.ndarray  # (J, J) V = σ² A⁻¹
    sigma2: float  # unbiased residual variance of the force equation, N²
    residual: np.ndarray  # (I,) m ẍ + Z k, N
    A: np.ndarray  # (J, J) ZᵀZ
    b: np.ndarray  # (J,) Zᵀy
    condition: float  # 2-norm condition number of A
    samples: int

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))

    @property
    def correlation(self) -> np.ndarray:
        s = self.std
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.covariance / np.outer(s, s)

    @property
    def rms_force(self) -> float:
        """RMS of the equation residual (N)."""
        return float(np.sqrt(np.mean(self.residual**2)))

    def as_dict(self) -> dict[str, float]:
        return dict(zip(self.names, self.values.tolist()))


def fit_coefficients(model: IsolatorModel, z: np.ndarray, zd: np.ndarray, xdd: np.ndarray,
                     free: Sequence[str] | None = None,
                     weights: np.ndarray | None = None,
                     columns: Mapping[str, np.ndarray] | None = None) -> LinearFit:
    """Least-squares coefficients of the terms in `free` (default: every term).

    `columns`: terms whose column along these samples is given (a term with a state,
    integrated along the runs it came from), by name."""
    names = tuple(t.name for t in model.terms) if free is None else tuple(free)
    if columns:
        Z_all = np.column_stack([columns[t.name] if t.name in columns else
                                 term_column(model, j, z, zd)
                                 for j, t in enumerate(model.terms)])
    else:
        Z_all = regressor_matrix(model, z, zd)
    cols = [i for i, t in enumerate(model.terms) if t.name in names]
    if len(cols) != len(names):
        raise KeyError(f"unknown terms in {names}: model has {[t.name for t in model.terms]}")
    fixed = [i for i in range(len(model.terms)) if i not in cols]
    y = model.mass * np.asarray(xdd, float)
    if fixed:  # known forces move to the measured side
        y = y + Z_all[:, fixed] @ np.array([model.terms[i].coef for i in fixed])
    Z = Z_all[:, cols]
    order = [names.index(model.terms[i].name) for i in cols]
    Z = Z[:, np.argsort(order)]
    return solve(Z, y, names, weights)


def solve(Z: np.ndarray, y: np.ndarray, names: tuple[str, ...],
          weights: np.ndarray | None = None) -> LinearFit:
    """Solve Z k = −y in the least-squares sense, with appendix A's statistics."""
    n, J = Z.shape
    if n <= J:
        raise ValueError(f"{n} samples cannot determine {J} coefficients")
    w = np.ones(n) if weights is None else np.sqrt(np.asarray(weights, float))
    Zw, yw = Z * w[:, None], y * w
    A, b = Zw.T @ Zw, Zw.T @ yw
    k, *_ = np.linalg.lstsq(Zw, -yw, rcond=None)
    residual = y + Z @ k
    sigma2 = float(np.sum((residual * w) ** 2) / (n - J))
    covariance = sigma2 * np.linalg.pinv(A)
    return LinearFit(names=names, values=k, covariance=covariance, sigma2=sigma2,
                     residual=residual, A=A, b=b, condition=float(np.linalg.cond(A)),
                     samples=n)
