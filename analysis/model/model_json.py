"""The identified model as JSON: one block that rebuilds the `IsolatorModel` exactly.

`analysis fit --json` writes the block under `MODEL_KEY`; `sim response --model`
reads it back. The schema lives here, next to `IsolatorModel`, and nowhere else:

    "identified_model": {
      "schema_version": 1,
      "units": "SI",
      "source": "joint output error, closed loop: coulomb_friction",
      "mass": 2721.55, "dead_band": 0.0185, "breakaway": 91.6, "stop_velocity": 0.0153,
      "terms": [{"name": "k2", "kind": "tanh_spring", "coef": 953.1, "unit": "N",
                 "shape": {"alpha": 78.7}, "shape_units": {"alpha": "1/m"},
                 "gated_by_dead_band": true}, …],
      "sensor": {"gain": 0.0, "delay": 0.0},
      "covariance": {"names": ["k1", "c3", …], "matrix": [[…], …]}
    }

`mass` kg, `dead_band` m, `breakaway` N, `stop_velocity` m/s; each term's
coefficient in its kind's unit, its shape constants keyed by the kind's own
names. `covariance` is over the constants the fit estimated (names as
`IsolatorModel.parameters()` has them, plus the mass sensor's `sensor_gain` and
`sensor_delay` where the loop fitted them); every other number was held and
carries no uncertainty here. `sensor` is the mass sensor's output map
x_meas(t) = (1 + gain) x(t − delay): it is not part of the isolator, so a
prediction of the mass's motion leaves it out.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from analysis.model.isolator import IsolatorModel, Term
from analysis.model.terms import kind
from rig.errors import DataError
from rig.json_document import read_document

SCHEMA_VERSION = 1
MODEL_KEY = "identified_model"
SENSOR_NAMES = ("sensor_gain", "sensor_delay")  # the loop's mass-sensor map (loop.candidates)
# the block's keys for the model's four global numbers, and their `parameters()` names
GLOBALS = {"mass": "m", "dead_band": "delta", "breakaway": "F_break", "stop_velocity": "epsilon"}
TERM_KEYS = ("name", "kind", "coef", "shape", "gated_by_dead_band")


@dataclass(frozen=True)
class IdentifiedModel:
    """An identified isolator and the covariance of the constants the fit estimated (SI)."""

    model: IsolatorModel
    names: tuple[str, ...] = ()  # the estimated constants, in covariance order
    covariance: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)),
                                   compare=False)  # (J, J), SI
    sensor_gain: float = 0.0  # g of x_meas = (1 + g) x(t − d), 1
    sensor_delay: float = 0.0  # d, s
    source: str = ""
    # the runs were fitted with each starting from zero internal state (Bouc–Wen r,
    # fluid θ) rather than the state the run before left
    states_reset_each_run: bool = False

    def __post_init__(self) -> None:
        n = len(self.names)
        if np.shape(self.covariance) != (n, n):
            raise ValueError(f"covariance is {np.shape(self.covariance)}, need ({n}, {n}) "
                             f"for {list(self.names)}")
        unknown = set(self.names) - set(self.model.parameters()) - set(SENSOR_NAMES)
        if unknown:
            raise ValueError(f"covariance names {sorted(unknown)}, not constants of the model")

    def std(self) -> dict[str, float]:
        """Standard error of each estimated constant, SI."""
        return dict(zip(self.names, np.sqrt(np.diag(self.covariance)).tolist()))


def covariance_from(std: ArrayLike, correlation: ArrayLike) -> np.ndarray:
    """Covariance from standard errors and correlations; an undefined correlation is 0.

    A constant whose standard error is not finite (the data did not determine it) keeps
    it on the diagonal and nothing off it, which `model_json` then leaves out; inf times
    a correlation of 0 would be NaN, with a RuntimeWarning on the user's terminal.
    """
    s = np.asarray(std, float)
    rho = np.nan_to_num(np.asarray(correlation, float), nan=0.0)
    np.fill_diagonal(rho, 1.0)
    determined = np.isfinite(s)
    finite = np.where(determined, s, 0.0)
    cov = rho * np.outer(finite, finite)
    undetermined = np.flatnonzero(~determined)
    cov[undetermined, undetermined] = s[undetermined] ** 2
    return cov


def model_json(model: IsolatorModel, names: Sequence[str] = (),
               covariance: ArrayLike | None = None, sensor_gain: float = 0.0,
               sensor_delay: float = 0.0, source: str = "",
               states_reset_each_run: bool = False) -> dict:
    """The block for `model`; `covariance` (J, J) SI over `names`.

    A constant whose variance is not finite (the data did not determine it) is left
    out of the covariance: it is as held as a constant the fit never freed.
    """
    names = list(names)
    cov = np.zeros((0, 0)) if covariance is None else np.asarray(covariance, float)
    if cov.shape != (len(names), len(names)):
        raise ValueError(f"covariance is {cov.shape}, need ({len(names)}, {len(names)})")
    keep = [i for i in range(len(names)) if np.isfinite(cov[i, i]) and cov[i, i] >= 0]
    cov = np.nan_to_num(cov[np.ix_(keep, keep)], nan=0.0)
    cov = 0.5 * (cov + cov.T)  # a product of scaled factors is symmetric to rounding only
    units = model.units()
    block = {"schema_version": SCHEMA_VERSION, "units": "SI", "source": source}
    block.update({key: float(model.parameters()[name]) for key, name in GLOBALS.items()})
    block["terms"] = [{
        "name": t.name, "kind": t.kind, "coef": float(t.coef), "unit": units[t.name],
        "shape": dict(zip(kind(t.kind).shape_names, map(float, t.shape))),
        "shape_units": dict(zip(kind(t.kind).shape_names, kind(t.kind).shape_units)),
        "gated_by_dead_band": t.is_gated} for t in model.terms]
    block["sensor"] = {"gain": float(sensor_gain), "delay": float(sensor_delay)}
    block["states_reset_each_run"] = bool(states_reset_each_run)
    block["covariance"] = {"names": [names[i] for i in keep], "matrix": cov.tolist()}
    return block


def model_from_json(doc: dict) -> IdentifiedModel:
    """The model of a fit document (or of its block alone); DataError names what is wrong."""
    if not isinstance(doc, dict):
        raise DataError(f"fit JSON is a {type(doc).__name__}, not an object")
    block = doc.get(MODEL_KEY, doc)
    if not isinstance(block, dict) or "schema_version" not in block:
        raise DataError(f"fit JSON has no '{MODEL_KEY}' block with a schema_version "
                        f"(written before schema {SCHEMA_VERSION}? run analysis fit again)")
    if block["schema_version"] != SCHEMA_VERSION:
        raise DataError(f"fit JSON is schema version {block['schema_version']!r}, this "
                        f"program reads version {SCHEMA_VERSION}")
    _require(block, ("units", *GLOBALS, "terms", "sensor", "covariance"), MODEL_KEY)
    if block["units"] != "SI":
        raise DataError(f"fit JSON {MODEL_KEY}.units is {block['units']!r}, need 'SI'")
    terms = tuple(_term(t, i) for i, t in enumerate(_list(block, "terms")))
    numbers = {key: _number(block, key) for key in GLOBALS}
    try:
        model = IsolatorModel(terms=terms, description=str(block.get("source", "")), **numbers)
    except ValueError as e:  # a negative dead band, two terms of one name …
        raise DataError(f"fit JSON {MODEL_KEY}: {e}") from None
    _require(block["sensor"], ("gain", "delay"), f"{MODEL_KEY}.sensor")
    names, cov = _covariance(block["covariance"], model)
    reset = block.get("states_reset_each_run", False)  # absent: written before it was
    if not isinstance(reset, bool):
        raise DataError(f"fit JSON {MODEL_KEY}.states_reset_each_run is {reset!r}, "
                        "not true/false")
    return IdentifiedModel(model, names, cov, _number(block["sensor"], "gain"),
                           _number(block["sensor"], "delay"), str(block.get("source", "")),
                           reset)


def _term(t: object, i: int) -> Term:
    where = f"{MODEL_KEY}.terms[{i}]"
    if not isinstance(t, dict):
        raise DataError(f"fit JSON {where} is not an object")
    _require(t, TERM_KEYS, where)
    try:
        k = kind(t["kind"])
    except KeyError as e:
        raise DataError(f"fit JSON {where}: {e.args[0]}") from None
    shape = t["shape"]
    if isinstance(shape, dict):
        shape = k.completed_shape(shape)
    if not isinstance(shape, dict) or set(shape) != set(k.shape_names):
        raise DataError(f"fit JSON {where}.shape is {shape!r}, kind {k.name} needs "
                        f"{list(k.shape_names)}")
    gated = t["gated_by_dead_band"]
    if not isinstance(gated, bool):
        raise DataError(f"fit JSON {where}.gated_by_dead_band is {gated!r}, not true/false")
    # the kind's default reads back as None, so a model reads back equal to itself
    return Term(k.name, str(t["name"]), _number(t, "coef", where),
                tuple(_number(shape, s, where + ".shape") for s in k.shape_names),
                None if gated == k.gated_by_dead_band else gated)


def _covariance(c: object, model: IsolatorModel) -> tuple[tuple[str, ...], np.ndarray]:
    where = f"{MODEL_KEY}.covariance"
    if not isinstance(c, dict):
        raise DataError(f"fit JSON {where} is not an object")
    _require(c, ("names", "matrix"), where)
    names = tuple(str(n) for n in _list(c, "names", where))
    known = set(model.parameters()) | set(SENSOR_NAMES)
    unknown = [n for n in names if n not in known]
    if unknown:
        raise DataError(f"fit JSON {where} names {unknown}, not constants of the model")
    try:
        cov = np.array(c["matrix"], dtype=float).reshape(len(names), len(names))
    except (TypeError, ValueError):
        raise DataError(f"fit JSON {where}.matrix is not a {len(names)} x {len(names)} "
                        "matrix of numbers") from None
    if not np.all(np.isfinite(cov)) or not np.allclose(cov, cov.T, rtol=1e-9, atol=0.0) \
            or np.any(np.diag(cov) < 0):
        raise DataError(f"fit JSON {where}.matrix is not a finite symmetric covariance")
    return names, cov


def _require(d: dict, keys: Sequence[str], where: str) -> None:
    missing = [k for k in keys if k not in d]
    if missing:
        raise DataError(f"fit JSON {where} lacks {', '.join(missing)}")


def _list(d: dict, key: str, where: str = MODEL_KEY) -> list:
    if not isinstance(d[key], list):
        raise DataError(f"fit JSON {where}.{key} is not a list")
    return d[key]


def _number(d: dict, key: str, where: str = MODEL_KEY) -> float:
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
        raise DataError(f"fit JSON {where}.{key} is {v!r}, not a finite number")
    return float(v)


def read_model(path: str | os.PathLike[str]) -> IdentifiedModel:
    """The identified model of an `analysis fit --json` file; DataError names the file."""
    return read_document(path, model_from_json)
