"""What the Results screen shows of `analysis fit --json`, read with its version checked.

`rig` never imports `analysis` (import-linter), so the TUI reads the document that
analysis/fit_schema.py writes with this reader of its own: only the keys Results
shows, each named once below. A document of another `schema_version`, or one that
lacks a key read here, is refused with one line (`DataError`) naming the key.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rig.errors import DataError
from rig.json_document import read_document
from rig.units import from_si, us_unit

#: the version of analysis/fit_schema.py this reader knows (tests/test_fit_schema.py)
SCHEMA_VERSION = 1

# the document's keys read here
VERSION = "schema_version"
PARAMETERS, RUNS, ERROR = "parameters", "runs", "error"
LOOP, EFFECTS_ADDED, UNEXPLAINED = "loop", "effects_added", "unexplained"
ERROR_BEFORE, ERROR_AFTER = "error_before", "error_after"
VALUE, UNIT, CI95, HELD = "value", "unit", "ci95", "held"
RESIDUAL_OVER_NOISE = "residual_over_noise"
ADDED, EVIDENCE, EXPLANATION, DESCRIPTION = "added", "evidence", "explanation", "description"


@dataclass(frozen=True)
class Constant:
    """One identified constant, SI (`unit`); half95 (the 95 % interval's half width, as
    `analysis fit` prints it) None where it was held or not estimated."""

    name: str
    value: float
    half95: float | None
    unit: str
    held: bool = False

    def shown(self, units: str) -> tuple[str, str, str]:
        """(value, ± 95 %, unit) as text in "si" or "us"."""
        unit = self.unit if units == "si" else us_unit(self.unit)
        value = float(from_si(self.value, unit))
        ci = "" if self.half95 is None else f"± {float(from_si(self.half95, unit)):.3g}"
        return f"{value:.5g}", ("held" if self.held and not ci else ci), unit


@dataclass(frozen=True)
class LoopStep:
    """A step of closing the loop: the effect added, its evidence, error per run before/after."""

    added: str
    statistic: float  # the score statistic χ²₁
    explanation: str
    before: dict[str, float]  # run -> residual / sensor noise
    after: dict[str, float]


@dataclass(frozen=True)
class FitSummary:
    """What the Results screen shows of a fit's JSON."""

    constants: tuple[Constant, ...]
    runs: tuple[str, ...]
    steps: tuple[LoopStep, ...]
    before: dict[str, float]  # run -> residual / noise, base model
    after: dict[str, float]  # after the loop (= before without one)
    effects_added: tuple[str, ...]
    unexplained: str  # "" if the residual is explained


def read_summary(path: Path) -> FitSummary:
    """`summarize` of the file at `path`; DataError names the file."""
    return read_document(path, summarize)


def summarize(doc: Any) -> FitSummary:
    """The Results screen's view of `analysis fit --json` output; the loop's keys are
    read where the loop ran (the document has `loop`)."""
    if VERSION not in _object(doc, "document"):
        raise DataError(f"fit JSON has no {VERSION} (written before schema version "
                        f"{SCHEMA_VERSION}? run the fit again)")
    version = doc[VERSION]
    if version != SCHEMA_VERSION:
        raise DataError(f"fit JSON is schema version {version!r}, this program reads "
                        f"version {SCHEMA_VERSION}")
    constants = tuple(_constant(n, e) for n, e in
                      _object(_key(doc, PARAMETERS), PARAMETERS).items())
    runs = tuple(_object(_key(doc, RUNS), RUNS))
    before = _rno(_key(doc, ERROR), ERROR)
    after, steps, effects, text = before, (), (), ""
    if LOOP in doc:
        before = _rno(_key(doc, ERROR_BEFORE), ERROR_BEFORE)
        after = _rno(_key(doc, ERROR_AFTER), ERROR_AFTER)
        steps = tuple(_step(s, f"{LOOP}[{i}]") for i, s in enumerate(_key(doc, LOOP)))
        effects = tuple(_key(doc, EFFECTS_ADDED))
        unexplained = _key(doc, UNEXPLAINED)
        text = str(_key(unexplained, DESCRIPTION, UNEXPLAINED)) \
            if _key(unexplained, VALUE, UNEXPLAINED) else ""
    return FitSummary(constants, runs, steps, before, after, effects, text)


def _constant(name: str, entry: Any) -> Constant:
    where = f"{PARAMETERS}.{name}"
    return Constant(name, float(_key(entry, VALUE, where)), _half(entry.get(CI95)),
                    str(_key(entry, UNIT, where)), bool(entry.get(HELD, False)))


def _step(s: Any, where: str) -> LoopStep:
    evidence = _key(s, EVIDENCE, where)
    return LoopStep(str(_key(s, ADDED, where)), float(_key(evidence, VALUE, f"{where}.evidence")),
                    str(_key(evidence, EXPLANATION, f"{where}.evidence")),
                    _rno(_key(s, ERROR_BEFORE, where), f"{where}.{ERROR_BEFORE}"),
                    _rno(_key(s, ERROR_AFTER, where), f"{where}.{ERROR_AFTER}"))


def _object(value: Any, where: str) -> dict:
    if not isinstance(value, dict):
        raise DataError(f"fit JSON {where} is not an object")
    return value


def _key(doc: Any, key: str, where: str = "document") -> Any:
    if key not in _object(doc, where):
        raise DataError(f"fit JSON {where} lacks '{key}'")
    return doc[key]


def _rno(errors: Any, where: str) -> dict[str, float]:
    """run -> residual / sensor noise."""
    return {r: float(_key(e, RESIDUAL_OVER_NOISE, f"{where}.{r}"))
            for r, e in _object(errors, where).items()}


def _half(ci: object) -> float | None:
    """The half width of a [low, high] interval from the JSON, or None."""
    if not isinstance(ci, list | tuple) or len(ci) != 2:
        return None
    low, high = _num(ci[0]), _num(ci[1])
    return None if low is None or high is None else (high - low) / 2.0


def _num(value: object) -> float | None:
    return None if value is None else float(value)  # type: ignore[arg-type]
