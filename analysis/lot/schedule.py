"""A lot run on a Dask cluster: each unit's fit a task, each result kept as it arrives,
then the family judged and every fitted unit predicted by the lot's average.

Units whose result is kept (`store`) from an earlier, interrupted run are not sent
again. A task that raises (a bug, a worker that died and took its task with it after
Dask's retries) makes its unit `failed` in this run with the reason, not kept: the
next run tries it again.
"""

from __future__ import annotations

import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from analysis.lot.average import predict_unit
from analysis.lot.family import Family, judge_lot
from analysis.lot.store import UnitStore
from analysis.lot.unit import FitOptions, UnitResult, UnitSpec, failed, fit_unit, one_line

if TYPE_CHECKING:
    from dask.distributed import Client, Future


@dataclass(frozen=True)
class Progress:
    """Where a phase of the lot stands; `eta` s, None before anything finished."""

    phase: str  # "fit" or "predict"
    done: int  # fitted (or predicted), kept ones included
    failed: int
    remaining: int
    eta: float | None
    unit: UnitResult | None = None  # the unit that just finished (fit phase)
    message: str = ""  # what just happened, one line


@dataclass(frozen=True)
class LotResult:
    units: dict[str, UnitResult]  # every unit, in the order given
    family: Family
    predictions: dict[str, dict[str, dict[str, float]]]  # unit → run → errors (lot average)
    fitted: tuple[str, ...]  # units fitted in this run (the rest were kept)
    problems: dict[str, str]  # unit → why it has no prediction


def run_lot(client: Client, specs: Sequence[UnitSpec], options: FitOptions, store: UnitStore,
            refit: bool = False, progress: Callable[[Progress], None] = lambda p: None
            ) -> LotResult:
    """Fit every unit (kept results reused unless `refit`), judge the lot, predict."""
    units, fitted = fit_units(client, specs, options, store, refit, progress)
    family = judge_lot(list(units.values()))
    predictions, problems = predict_units(client, [s for s in specs if units[s.name].ok],
                                          options, store, family.average, progress)
    return LotResult(units, family, predictions, fitted, problems)


def fit_units(client: Client, specs: Sequence[UnitSpec], options: FitOptions,
              store: UnitStore, refit: bool = False,
              progress: Callable[[Progress], None] = lambda p: None
              ) -> tuple[dict[str, UnitResult], tuple[str, ...]]:
    """Every unit's result in the order given, and the units fitted now."""
    from dask.distributed import as_completed

    results: dict[str, UnitResult] = {}
    todo = []
    for s in specs:
        kept = None if refit else store.load(s)
        if kept is None:
            todo.append(s)
        else:
            results[s.name] = kept
    if results:
        progress(_progress("fit", results, len(todo), None,
                           message=f"{len(results)} unit(s) kept from an earlier run"))
    futures = {client.submit(fit_unit, s, options, key=f"fit-{s.name}-{uuid.uuid4().hex}"): s
               for s in todo}
    threads = max(1, sum(client.nthreads().values()))
    fitted: list[str] = []
    for future in as_completed(futures):
        spec = futures.pop(future)
        result, keep = _outcome(future, spec)
        if keep:
            store.save(result)
        results[spec.name] = result
        fitted.append(spec.name)
        mean = sum(results[u].seconds for u in fitted) / len(fitted)
        progress(_progress("fit", results, len(futures), len(futures) * mean / threads,
                           result))
    return {s.name: results[s.name] for s in specs}, tuple(fitted)


def _outcome(future: Future, spec: UnitSpec) -> tuple[UnitResult, bool]:
    """The task's result and whether it is the unit's own (kept), or why the task died."""
    try:
        return future.result(), True
    except Exception as e:  # noqa: BLE001 - the task's, not the unit's: tried again next run
        return failed(spec, f"task failed ({type(e).__name__}: "
                            f"{one_line(e, spec.directory)}); not kept, tried again next run"
                      ), False


def _progress(phase: str, results: dict[str, UnitResult], remaining: int, eta: float | None,
              unit: UnitResult | None = None, message: str = "") -> Progress:
    bad = sum(not r.ok for r in results.values())
    return Progress(phase, len(results) - bad, bad, remaining, eta, unit, message)


def predict_units(client: Client, specs: Sequence[UnitSpec], options: FitOptions,
                  store: UnitStore, average: dict[str, float],
                  progress: Callable[[Progress], None] = lambda p: None
                  ) -> tuple[dict[str, dict[str, dict[str, float]]], dict[str, str]]:
    """unit → run → errors under the lot average (kept ones reused); and unit → why not."""
    from dask.distributed import as_completed

    out: dict[str, dict[str, dict[str, float]]] = {}
    problems: dict[str, str] = {}
    todo = []
    for s in specs:
        kept = store.prediction(s, average)
        if kept is None:
            todo.append(s)
        else:
            out[s.name] = kept
    futures = {client.submit(predict_unit, s, options, average,
                             key=f"predict-{s.name}-{uuid.uuid4().hex}"): s for s in todo}
    start = time.perf_counter()
    for k, future in enumerate(as_completed(futures), 1):
        spec = futures.pop(future)
        try:
            out[spec.name] = future.result()
            store.save_prediction(spec, average, out[spec.name])
        except Exception as e:  # noqa: BLE001 - reported beside the unit; the lot goes on
            problems[spec.name] = f"{type(e).__name__}: {one_line(e, spec.directory)}"
        eta = (time.perf_counter() - start) / k * len(futures)
        progress(Progress("predict", len(out), len(problems), len(futures), eta))
    return {s.name: out[s.name] for s in specs if s.name in out}, problems
