"""One unit of a lot: its run files found and fingerprinted, and the unit fitted as
`analysis fit` fits it.

`fit_unit` is the task a lot sends to a Dask worker: a plain function of picklable
arguments that returns a JSON-serialisable `UnitResult`. It runs `analysis fit`'s own
steps (`load_runs` → `identify` → `close_loop` → `fit_document`), so a
unit fitted in a lot and the same files fitted with `analysis fit --json` give the same
document. A unit whose files are bad or whose fit fails (`DataError`, `ValueError`)
comes back `failed` with its one-line reason instead of raising: one unit cannot sink
the lot. Anything else (a bug, a worker that died) is the lot's business, not the
unit's, and is never kept (`analysis.lot.store`).
"""

from __future__ import annotations

import hashlib
import os
import socket
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

from analysis.fit_schema import FitResult
from analysis.identify.loading import load_runs
from analysis.identify.pipeline import REFINED, identify
from analysis.loop import close_identified
from analysis.loop.report import fit_document
from rig.errors import DataError

RUN_SUFFIXES = (".h5", ".hdf5", ".csv")  # what `analysis fit` reads: run files and CSV
OK, FAILED = "ok", "failed"


@dataclass(frozen=True)
class FitOptions:
    """How every unit of the lot is fitted: `analysis fit`'s options (SI)."""

    mass: float | None = None  # kg; None: each unit's run files' payload mass
    units: str | None = None  # CSV displacement units; None: from the header
    include_aborted: bool = False


@dataclass(frozen=True)
class UnitSpec:
    """One unit: its directory, its run files and a fingerprint of them and the options."""

    name: str
    directory: str  # absolute
    files: tuple[str, ...]  # absolute, sorted
    fingerprint: str  # sha256 hex: a kept result is reused only for the same one


@dataclass(frozen=True)
class Estimate:
    """One constant of a unit (SI): std None where the fit did not estimate it."""

    value: float
    std: float | None
    unit: str
    held: bool = False

    @property
    def estimated(self) -> bool:
        """Estimated by the fit: a standard error of 0 comes from a column the fit could not
        move (a saturated tanh), and says as little as none."""
        return self.std is not None and self.std > 0 and not self.held


@dataclass(frozen=True)
class UnitResult:
    """A unit's outcome: its constants ± std, the effects the loop named, its residual
    over the sensor noise per run after the loop, or why it failed.

    `fit` is the whole `analysis fit --json` document (None for a failed unit).
    """

    unit: str
    directory: str
    fingerprint: str
    status: str  # OK or FAILED
    reason: str = ""  # one line, for a failed unit
    files: tuple[str, ...] = ()
    constants: dict[str, Estimate] = field(default_factory=dict)  # REFINED + the mass "m"
    effects: dict[str, Estimate] = field(default_factory=dict)  # effect → its parameter
    residual_over_noise: dict[str, float] = field(default_factory=dict)  # run → after loop
    unexplained: str = ""  # the loop's description where it found structure it cannot name
    warnings: tuple[str, ...] = ()
    seconds: float = 0.0  # wall time of the fit
    worker: str = ""  # host:pid that fitted it
    fit: dict | None = None

    @property
    def ok(self) -> bool:
        return self.status == OK

    @property
    def mass(self) -> float:
        return self.constants["m"].value

    def to_json(self) -> dict:
        return asdict(self)

    @classmethod
    def from_json(cls, doc: dict) -> UnitResult:
        d = dict(doc)
        d["files"] = tuple(d.get("files", ()))
        d["warnings"] = tuple(d.get("warnings", ()))
        for key in ("constants", "effects"):
            d[key] = {n: Estimate(**e) for n, e in d.get(key, {}).items()}
        return cls(**d)


def find_units(directories: Sequence[Path], options: FitOptions) -> list[UnitSpec]:
    """Each directory one unit; a directory with no run files of its own whose
    subdirectories hold some is a lot, and those subdirectories are its units."""
    dirs: list[Path] = []
    for d in map(Path, directories):
        if not d.is_dir():
            raise DataError(f"{d}: not a directory (each unit is a directory of run files)")
        subs = sorted(s for s in d.iterdir() if s.is_dir() and _run_files(s))
        dirs.extend(subs if not _run_files(d) and subs else [d])
    taken: set[str] = set()
    out = []
    for d in dirs:
        d = d.resolve()
        name, k = d.name, 2
        while name in taken:  # the same name in two places: both kept, told apart
            name, k = f"{d.name}-{k}", k + 1
        taken.add(name)
        files = tuple(str(f) for f in _run_files(d))
        out.append(UnitSpec(name, str(d), files, fingerprint(files, options)))
    return out


def _run_files(d: Path) -> list[Path]:
    return sorted(f for f in d.iterdir() if f.is_file() and f.suffix.lower() in RUN_SUFFIXES)


def fingerprint(files: Sequence[str], options: FitOptions) -> str:
    """sha256 over the files' names and contents and the fit options: a unit whose files
    were replaced (a corrupt one fixed) is fitted again, an unchanged one is not."""
    h = hashlib.sha256(repr(sorted(asdict(options).items())).encode())
    for f in files:
        h.update(Path(f).name.encode() + b"\0")
        try:
            h.update(hashlib.sha256(Path(f).read_bytes()).digest())
        except OSError as e:  # unreadable: the fit will say so; the fingerprint notes it
            h.update(f"unreadable: {e.strerror}".encode())
    return h.hexdigest()


def fit_unit(spec: UnitSpec, options: FitOptions) -> UnitResult:
    """Identify one unit and close the loop, as `analysis fit --json` does.

    Runs on one core: the lot's parallelism is across units (one task per worker
    thread), and a task that also spread its simulations over every core would fight
    the other workers for them.
    """
    one_core()
    start = time.perf_counter()
    try:
        if not spec.files:
            raise DataError(f"no run files ({', '.join('*' + s for s in RUN_SUFFIXES)}) "
                            f"in {spec.directory}")
        loaded = load_runs([Path(f) for f in spec.files], options.mass, options.units,
                           options.include_aborted)
        fit = identify(loaded.runs)
        loop = close_identified(fit)
    except (DataError, ValueError) as e:  # the unit's data, not the lot's: one line
        return failed(spec, one_line(e, spec.directory), time.perf_counter() - start)
    return from_fit(spec, fit_document(fit, loop), loaded.warnings, time.perf_counter() - start)


def failed(spec: UnitSpec, reason: str, seconds: float = 0.0) -> UnitResult:
    return UnitResult(spec.name, spec.directory, spec.fingerprint, FAILED, reason,
                      files=_names(spec), seconds=seconds, worker=worker_name())


def from_fit(spec: UnitSpec, result: FitResult, warnings: Sequence[str] = (),
             seconds: float = 0.0) -> UnitResult:
    """The unit's summary from its `analysis fit --json` document (with the loop's keys)."""
    params = result.parameters

    def estimate(name: str) -> Estimate:
        e = params[name]
        return Estimate(float(e.value), None if e.std is None else float(e.std), e.unit,
                        bool(e.held))

    loop = result.loop
    effects = {s.added: estimate(s.parameter) if s.parameter in params
               else Estimate(s.value.value, s.value.std, s.value.unit)
               for s in (loop.steps if loop else ())}
    after = loop.error_after if loop else result.error
    return UnitResult(
        spec.name, spec.directory, spec.fingerprint, OK, files=_names(spec),
        constants={n: estimate(n) for n in ("m", *REFINED) if n in params},
        effects=effects,
        residual_over_noise={r: float(e.residual_over_noise) for r, e in after.items()},
        unexplained=loop.unexplained.description if loop and loop.unexplained.value else "",
        warnings=tuple(one_line(w, spec.directory) for w in warnings), seconds=seconds,
        worker=worker_name(), fit=result.to_json_dict())


def _names(spec: UnitSpec) -> tuple[str, ...]:
    return tuple(Path(f).name for f in spec.files)


def one_line(message: object, directory: str) -> str:
    """A message on one line, with the unit's directory left out of its file names (the
    unit is named beside it)."""
    text = " ".join(str(message).split())
    return text.replace(directory.rstrip(os.sep) + os.sep, "")


def worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def one_core() -> None:
    """numba's parallel simulations on this thread use one core (thread-local setting)."""
    import numba

    numba.set_num_threads(1)
