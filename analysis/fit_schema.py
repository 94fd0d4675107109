"""The document `analysis fit --json` writes, as frozen dataclasses: its one schema.

`FitResult.to_json_dict()` is how the document is written (`analysis fit --json`
and each unit of a lot) and `FitResult.from_json_dict()` reads it back; the two
round-trip. A field is named as its key (`LoopOutcome.steps` is the key `loop`) and
every number is SI, each docstring naming its units. The identified model's block
(`identified_model`) has its own schema and version, in
analysis/model/model_json.py, and is carried here as that block.

`rig` never imports `analysis` (import-linter), so the TUI reads the document with
a reader of its own (rig/tui/fit_summary.py) that checks the same `schema_version`.

One module past the house's ~300 lines, on purpose: the schema is one source of
truth, read top to bottom as the document is, and a record split from its
neighbours would hide which keys a version holds.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from typing import Any, ClassVar, Self

from analysis.model.model_json import MODEL_KEY, model_from_json
from rig.errors import DataError

SCHEMA_VERSION = 1
VERSION_KEY = "schema_version"

#: reads one JSON value found at `where` (a path such as "loop[0].evidence")
Read = Callable[[Any, str], Any]


def _at(where: str, key: str | int) -> str:
    if isinstance(key, int):
        return f"{where}[{key}]"
    return f"{where}.{key}" if where else key


def _object(doc: Any, keys: Sequence[str], where: str, optional: Sequence[str] = ()) -> dict:
    """`doc` as an object with exactly `keys` (those in `optional` may be absent)."""
    if not isinstance(doc, dict):
        raise DataError(f"fit JSON {where or 'document'} is not an object")
    missing = [k for k in keys if k not in doc and k not in optional]
    if missing:
        raise DataError(f"fit JSON {where or 'document'} lacks {', '.join(missing)}")
    unknown = [str(k) for k in doc if k not in keys]
    if unknown:  # a key this version does not know would not survive the round trip
        raise DataError(f"fit JSON {where or 'document'} has {', '.join(unknown)}, not in "
                        f"schema version {SCHEMA_VERSION}")
    return doc


def _as_is(value: Any, where: str) -> Any:
    return value


def _tuple(value: Any, where: str) -> tuple:
    if not isinstance(value, list):
        raise DataError(f"fit JSON {where} is not a list")
    return tuple(value)


def _matrix(value: Any, where: str) -> tuple[tuple[float, ...], ...]:
    return tuple(_tuple(row, _at(where, i)) for i, row in enumerate(_tuple(value, where)))


def _each(read: Read) -> Read:
    """An object of `read`s keyed by name (a run, a constant)."""
    def each(value: Any, where: str) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise DataError(f"fit JSON {where} is not an object")
        return {k: read(v, _at(where, k)) for k, v in value.items()}
    return each


def _many(read: Read) -> Read:
    """A list of `read`s."""
    def many(value: Any, where: str) -> tuple:
        return tuple(read(v, _at(where, i)) for i, v in enumerate(_tuple(value, where)))
    return many


def _optional(read: Read) -> Read:
    """`read`, or null."""
    def optional(value: Any, where: str) -> Any:
        return None if value is None else read(value, where)
    return optional


def _plain(value: Any) -> Any:
    """Records, tuples and dicts of them as JSON's objects and lists."""
    if hasattr(value, "to_json_dict"):  # a record of this schema
        return value.to_json_dict()
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


class _Record:
    """A dataclass written as a JSON object of its fields, in order; `_read` names how
    a field that is not a plain value (a list, a record, an object of records) is read,
    `_keys` a field whose key is not its name."""

    _read: ClassVar[dict[str, Read]] = {}
    _keys: ClassVar[dict[str, str]] = {}

    def to_json_dict(self) -> dict[str, Any]:
        return {self._keys.get(f.name, f.name): _plain(getattr(self, f.name))
                for f in fields(self)}

    @classmethod
    def from_json_dict(cls, doc: Any, where: str = "") -> Self:
        names = [f.name for f in fields(cls)]
        keys = [cls._keys.get(n, n) for n in names]
        d = _object(doc, keys, where)
        return cls(**{n: cls._read.get(n, _as_is)(d[k], _at(where, k))
                      for n, k in zip(names, keys)})


@dataclass(frozen=True)
class Estimate:
    """One constant: `value` and its standard error `std` in `unit` (SI), std None where
    it was held or not estimated; `ci95` the 95 % interval value ± 1.96 std, written only
    with a std; `held` written only where it is said: true for a constant held at its
    start value, false for one the loop added but could not estimate."""

    value: float
    std: float | None
    unit: str
    ci95: tuple[float, float] | None = None
    held: bool | None = None

    def to_json_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"value": self.value, "std": self.std, "unit": self.unit}
        if self.ci95 is not None:
            out["ci95"] = list(self.ci95)
        if self.held is not None:
            out["held"] = self.held
        return out

    @classmethod
    def from_json_dict(cls, doc: Any, where: str = "") -> Self:
        d = _object(doc, ("value", "std", "unit", "ci95", "held"), where, ("ci95", "held"))
        ci95 = _optional(_tuple)(d.get("ci95"), _at(where, "ci95"))
        return cls(d["value"], d["std"], d["unit"], ci95, d.get("held"))


# the fit table's keys (`error`) for a run's errors; the loop's are the field names
TABLE_KEYS = {"z": "nrmse_z", "zd": "nrmse_zd", "xdd": "nrmse_xdd", "force_rms": "force_rms_N",
              "residual_over_noise": "residual_over_noise"}
OPTIONAL_ERRORS = ("zd", "xdd", "force_rms")


@dataclass(frozen=True)
class RunError:
    """How well a model reproduces one run (analysis/identify/run_errors.py): NRMSE of
    z, ż and ẍ as fractions, RMS(model − measured) / RMS(measured), None where the run
    has no smoothed derivatives; `force_rms` the inertial force the model leaves
    unexplained, m · RMS(ẍ_model − ẍ_measured), N; `residual_over_noise`
    RMS(x_model − x_measured) / the sensor noise, 1 for a right model.

    Written two ways: the fit's table (`error`) as nrmse_z, nrmse_zd, nrmse_xdd,
    force_rms_N, residual_over_noise with null for None (`table_json`); the loop's
    (`error_before`, `error_after`, a step's) under the field names with a None left
    out (`to_json_dict`).
    """

    z: float
    zd: float | None
    xdd: float | None
    force_rms: float | None
    residual_over_noise: float

    def to_json_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in TABLE_KEYS if getattr(self, k) is not None}

    def table_json(self) -> dict[str, Any]:
        return {key: getattr(self, k) for k, key in TABLE_KEYS.items()}

    @classmethod
    def from_json_dict(cls, doc: Any, where: str = "") -> Self:
        d = _object(doc, tuple(TABLE_KEYS), where, OPTIONAL_ERRORS)
        return cls(**{k: d.get(k) for k in TABLE_KEYS})

    @classmethod
    def from_table_json(cls, doc: Any, where: str = "") -> Self:
        d = _object(doc, tuple(TABLE_KEYS.values()), where)
        return cls(**{k: d[key] for k, key in TABLE_KEYS.items()})


@dataclass(frozen=True)
class ModelTerm(_Record):
    """A term of the fitted model: its name (the coefficient's), kind
    (analysis/model/terms.py), formula, and whether it acts only outside the dead band."""

    name: str
    kind: str
    formula: str
    gated_by_dead_band: bool


@dataclass(frozen=True)
class ChannelSkew(_Record):
    """The table channel's fitted time offset at the table motion's centroid, s, its
    standard error, s, and its rate, s/s, with its standard error."""

    value: float
    std: float
    rate: float
    rate_std: float


@dataclass(frozen=True)
class AppendixA(_Record):
    """The report's appendix A least squares at its α, β, δ (SI): the coefficients
    `names` with `values` and `std` (each in its constant's unit), σ² of the force
    equation, N², A = ZᵀZ and b = Zᵀy (y = m ẍ, N), the covariance V = σ² A⁻¹, the
    2-norm condition number of A, the correlations (0 where undefined) and the number
    of samples with relative motion."""

    names: tuple[str, ...]
    values: dict[str, float]
    std: dict[str, float]
    sigma2_N2: float
    A: tuple[tuple[float, ...], ...]
    b: tuple[float, ...]
    covariance: tuple[tuple[float, ...], ...]
    condition: float
    correlation: tuple[tuple[float, ...], ...]
    samples: int

    _read: ClassVar[dict[str, Read]] = {"names": _tuple, "A": _matrix, "b": _tuple,
                                        "covariance": _matrix, "correlation": _matrix}


@dataclass(frozen=True)
class VariableProjection(_Record):
    """Equation error with α (1/m), β (s/m) and δ (m) searched: the shape constants
    found, the linear coefficients at them (SI), σ² of the force equation, N², and the
    number of σ² evaluations the search made."""

    shapes: dict[str, float]
    values: dict[str, float]
    sigma2_N2: float
    evaluations: int


@dataclass(frozen=True)
class Preparation(_Record):
    """How one run was prepared: the differentiation method and its cutoff, Hz (None
    where the method has none), the mass and table sensors' noise σ, m, how the table
    motion was estimated, and the fraction of samples with relative motion."""

    differentiation: str
    cutoff_hz: float | None
    sigma_x_m: float
    sigma_u_m: float
    table_motion: str
    moving_fraction: float


@dataclass(frozen=True)
class ResidualTests(_Record):
    """Tests of a fit's residual x_model − x_measured (analysis/loop/evidence.py): its
    RMS over the sensor noise, the Ljung–Box Q and p-value, whether it is white, the 95 %
    bound of its autocorrelation, its largest cross-correlations (`u_e` with the table
    velocity, `u2_e` with its square, `u2_e2` of its own square with that), where in
    z, ż it concentrates, the band holding most of its power, and the fraction of its
    power per band."""

    residual_over_noise: float
    ljung_box_Q: float
    ljung_box_p: float
    white: bool
    correlation_bound_95: float
    cross_correlation: dict[str, float]
    concentrates_in: str
    band: str
    band_power: dict[str, float]


@dataclass(frozen=True)
class Evidence(_Record):
    """Why the loop added an effect: the score statistic's name and value (χ²₁), the
    fraction of the residual sum of squares it cut, the F statistic, |value| / std (None
    where the std is 0), the variable the residual was plotted against (z, zd, t, x, xd),
    the effect's physical explanation, the held-out runs' verdict, and the residual's
    tests before the step."""

    statistic: str
    value: float
    rss_drop: float
    F: float
    t: float | None
    signature: str
    explanation: str
    heldout: str
    residual_before: ResidualTests

    _read: ClassVar[dict[str, Read]] = {"residual_before": ResidualTests.from_json_dict}


@dataclass(frozen=True)
class LoopStep(_Record):
    """One effect the loop added: its name, its parameter's estimate as the final model
    has it (no `ci95`), the evidence, and each run's errors before and after the step."""

    added: str
    parameter: str
    value: Estimate
    evidence: Evidence
    error_before: dict[str, RunError]
    error_after: dict[str, RunError]

    _read: ClassVar[dict[str, Read]] = {
        "value": Estimate.from_json_dict, "evidence": Evidence.from_json_dict,
        "error_before": _each(RunError.from_json_dict),
        "error_after": _each(RunError.from_json_dict)}


@dataclass(frozen=True)
class Refusal(_Record):
    """A candidate effect the loop did not add, and why (one line)."""

    candidate: str
    reason: str


@dataclass(frozen=True)
class Unexplained(_Record):
    """Whether the residual keeps structure no effect in the library accounts for, and
    the loop's description of the final residual."""

    value: bool
    description: str


@dataclass(frozen=True)
class Conditioning(_Record):
    """A force candidate not added, against the final model's terms
    (analysis/loop/conditioning.py): its parameter, the fraction of its force pattern
    the terms do not reproduce, the variance inflation (None where infinite), the terms
    it looks like, and whether the runs cannot tell it from them."""

    candidate: str
    parameter: str
    unique_fraction: float
    variance_inflation: float | None
    like: tuple[str, ...]
    indistinguishable: bool

    _read: ClassVar[dict[str, Read]] = {"like": _tuple}


@dataclass(frozen=True)
class LoopOutcome(_Record):
    """Closing the loop: each step (key `loop`), the effects added, each run's errors
    and the residual's tests before and after the whole loop, what stayed unexplained,
    the candidates refused, and the conditioning of those not added."""

    steps: tuple[LoopStep, ...]
    effects_added: tuple[str, ...]
    error_before: dict[str, RunError]
    error_after: dict[str, RunError]
    residual_before: ResidualTests
    residual_after: ResidualTests
    unexplained: Unexplained
    refused: tuple[Refusal, ...]
    conditioning: tuple[Conditioning, ...]

    _keys: ClassVar[dict[str, str]] = {"steps": "loop"}
    _read: ClassVar[dict[str, Read]] = {
        "steps": _many(LoopStep.from_json_dict), "effects_added": _tuple,
        "error_before": _each(RunError.from_json_dict),
        "error_after": _each(RunError.from_json_dict),
        "residual_before": ResidualTests.from_json_dict,
        "residual_after": ResidualTests.from_json_dict,
        "unexplained": Unexplained.from_json_dict,
        "refused": _many(Refusal.from_json_dict),
        "conditioning": _many(Conditioning.from_json_dict)}


# the document's keys in the order written; the loop's only where it ran
BASE_KEYS = ("parameters", "runs", "error", "model", MODEL_KEY, "estimate", "held",
             "flagged_runs", "consistent_range", "channel_skew_s", "appendix_a",
             "variable_projection", "preparation")
OUTCOME_KEYS = tuple(LoopOutcome._keys.get(f.name, f.name) for f in fields(LoopOutcome))
LOOP_KEYS = (*OUTCOME_KEYS, "parameters_base_model")


@dataclass(frozen=True)
class FitResult:
    """The whole document (SI).

    - `parameters`: every constant of the final model (the loop's refit where it ran;
      `parameters_base_model` then keeps the fit's own);
    - `runs`: run → the constants fitted to that run alone;
    - `error`: run → the identification's errors, before the loop (the fit table's
      form of `RunError`);
    - `model`: the terms; `identified_model`: the model to predict with, the block of
      analysis/model/model_json.py (its own `schema_version`);
    - `estimate`: which estimate `parameters` reports ("joint output error", …);
      `held`: the constants held at their start value; `flagged_runs`: run → the
      constants in which it differs significantly from the other runs;
    - `consistent_range`: held constant → [low, high], the values the runs cannot tell
      apart, in its unit; `channel_skew_s`: run → the table channel's offset, None
      where not fitted;
    - `appendix_a`, `variable_projection`, `preparation` (run →): the steps before the
      output error;
    - `loop`: closing the loop, None where it did not run (`--no-loop`, `--no-refine`).
    """

    parameters: dict[str, Estimate]
    runs: dict[str, dict[str, Estimate]]
    error: dict[str, RunError]
    model: tuple[ModelTerm, ...]
    identified_model: dict[str, Any]
    estimate: str
    held: tuple[str, ...]
    flagged_runs: dict[str, tuple[str, ...]]
    consistent_range: dict[str, tuple[float, float]]
    channel_skew_s: dict[str, ChannelSkew] | None
    appendix_a: AppendixA
    variable_projection: VariableProjection
    preparation: dict[str, Preparation]
    loop: LoopOutcome | None = None
    parameters_base_model: dict[str, Estimate] | None = None
    schema_version: int = SCHEMA_VERSION

    def __post_init__(self) -> None:
        if (self.loop is None) != (self.parameters_base_model is None):
            raise ValueError("the loop's outcome and the base model's parameters come "
                             "together")

    def to_json_dict(self) -> dict[str, Any]:
        """The document, keys in the order written; NaN stays NaN (json writes NaN)."""
        doc: dict[str, Any] = {VERSION_KEY: self.schema_version}
        for key in BASE_KEYS:
            value = self.identified_model if key == MODEL_KEY else getattr(self, key)
            doc[key] = ({r: e.table_json() for r, e in value.items()} if key == "error"
                        else _plain(value))
        if self.loop is not None:
            doc.update(self.loop.to_json_dict())
            doc["parameters_base_model"] = _plain(self.parameters_base_model)
        return doc

    @classmethod
    def from_json_dict(cls, doc: Any) -> FitResult:
        """The document read back; DataError, one line, names what is wrong."""
        if not isinstance(doc, dict):
            raise DataError(f"fit JSON is a {type(doc).__name__}, not an object")
        if VERSION_KEY not in doc:
            raise DataError(f"fit JSON has no {VERSION_KEY} (written before schema version "
                            f"{SCHEMA_VERSION}? run analysis fit again)")
        if doc[VERSION_KEY] != SCHEMA_VERSION:
            raise DataError(f"fit JSON is schema version {doc[VERSION_KEY]!r}, this program "
                            f"reads version {SCHEMA_VERSION}")
        looped = any(k in doc for k in LOOP_KEYS)
        d = _object(doc, (VERSION_KEY, *BASE_KEYS, *(LOOP_KEYS if looped else ())), "")
        model_from_json(d[MODEL_KEY])  # its own schema: refused here, not at prediction
        estimates = _each(Estimate.from_json_dict)
        return cls(
            parameters=estimates(d["parameters"], "parameters"),
            runs=_each(estimates)(d["runs"], "runs"),
            error=_each(RunError.from_table_json)(d["error"], "error"),
            model=_many(ModelTerm.from_json_dict)(d["model"], "model"),
            identified_model=d[MODEL_KEY], estimate=d["estimate"],
            held=_tuple(d["held"], "held"),
            flagged_runs=_each(_tuple)(d["flagged_runs"], "flagged_runs"),
            consistent_range=_each(_tuple)(d["consistent_range"], "consistent_range"),
            channel_skew_s=_optional(_each(ChannelSkew.from_json_dict))(
                d["channel_skew_s"], "channel_skew_s"),
            appendix_a=AppendixA.from_json_dict(d["appendix_a"], "appendix_a"),
            variable_projection=VariableProjection.from_json_dict(
                d["variable_projection"], "variable_projection"),
            preparation=_each(Preparation.from_json_dict)(d["preparation"], "preparation"),
            loop=(LoopOutcome.from_json_dict({k: d[k] for k in OUTCOME_KEYS})
                  if looped else None),
            parameters_base_model=(estimates(d["parameters_base_model"],
                                             "parameters_base_model") if looped else None))
