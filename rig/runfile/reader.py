"""Reading run files into plain frozen dataclasses and numpy arrays.

Every failure to read (not HDF5, truncated, missing groups, other schema)
raises DataError with one line naming the file; h5py exceptions never escape.
Files are opened, read completely and closed, so nothing holds them open.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import h5py
import numpy as np

from rig.errors import DataError
from rig.runfile.io import one_line, open_for_read, writer_alive
from rig.runfile.probe import check_readable
from rig.runfile.schema import (
    CAN_FLAG_ERROR,
    CAN_FLAG_EXTENDED,
    CAN_FLAG_REMOTE,
    COUNTER_DTYPE,
    COUNTER_KINDS,
    COUNTERS_PATH,
    FIXED_DATASETS,
    GROUPS,
    META_ATTRS,
    ROOT_ATTRS,
    RUNNING,
    SCHEMA_VERSION,
)

_SPECS = {spec.path: spec for spec in FIXED_DATASETS}
# What h5py and numpy raise on a damaged file (fuzzed: tests/test_faults_input.py). A
# corrupt object header can make h5py hand back None for a dataset, hence AttributeError;
# a corrupt dataspace can claim more rows than memory holds.
_CORRUPT = (OSError, KeyError, ValueError, TypeError, RuntimeError, AttributeError, IndexError,
            OverflowError, MemoryError)
_SLACK_BYTES = 1 << 20  # a table's rows may exceed the file size by its open chunk, no more


@dataclass(frozen=True)
class Channel:
    """A decoded channel: time (n,) s on the run's host time base, value (n,) in `units`."""

    name: str
    time: np.ndarray
    value: np.ndarray
    units: str
    source: str
    description: str
    dtype: str


@dataclass(frozen=True)
class CanFrames:
    """Raw CAN frames (n rows): time s, arbitration_id, dlc, data (n, 8) uint8, flags."""

    time: np.ndarray
    arbitration_id: np.ndarray
    dlc: np.ndarray
    data: np.ndarray
    flags: np.ndarray

    @property
    def is_error(self) -> np.ndarray:
        return (self.flags & CAN_FLAG_ERROR) != 0

    @property
    def is_extended(self) -> np.ndarray:
        return (self.flags & CAN_FLAG_EXTENDED) != 0

    @property
    def is_remote(self) -> np.ndarray:
        return (self.flags & CAN_FLAG_REMOTE) != 0


@dataclass(frozen=True)
class SerialFrames:
    """Raw serial frames (n rows): time s and data (n, 16) uint8 exactly as received."""

    time: np.ndarray
    data: np.ndarray


@dataclass(frozen=True)
class Gap:
    """`count` samples missing from `channel` between samples start_sample and end_sample."""

    channel: str
    start_sample: int
    end_sample: int
    start_time: float
    end_time: float
    count: int


@dataclass(frozen=True)
class RunStatus:
    """How the run ended. `state` is exit_status, or "crashed" for a dead "running" writer."""

    exit_status: str
    reason: str
    complete: bool
    samples: Mapping[str, int]
    writer_alive: bool

    @property
    def state(self) -> str:
        """success | abort | fail | running (writer alive) | crashed (writer gone)."""
        if self.exit_status == RUNNING and not self.writer_alive:
            return "crashed"
        return self.exit_status


@dataclass(frozen=True)
class RunFile:
    """Everything in one run file. `meta` holds the /meta attributes (see META_ATTRS)."""

    path: Path
    meta: Mapping[str, object]
    status: RunStatus
    channels: Mapping[str, Channel]
    can: CanFrames | None
    serial: SerialFrames | None
    counters: Mapping[str, Mapping[str, int]]
    gaps: tuple[Gap, ...]

    @property
    def calibration(self) -> dict[str, object]:
        return json.loads(str(self.meta["calibration_json"]))


@dataclass(frozen=True)
class RunSummary:
    """One row of `list_runs`: duration s (last host timestamp), decoded samples, lost frames."""

    name: str
    status: str
    duration: float
    samples: int
    losses: int
    reason: str


def open_run(path: str | os.PathLike[str], *, raw: bool = True) -> RunFile:
    """Read a run file (live, finished, crashed or recovered); raw=False skips /raw frames."""
    path = Path(path)
    with _reading(path) as (f, meta, alive):
        tables = _tables(f)  # each object opened once: opens cost ~0.2 ms under a SWMR read
        return RunFile(
            path=path,
            meta=MappingProxyType(meta),
            status=_status(f, tables, alive),
            channels=MappingProxyType(
                {name[9:]: _channel(ds) for name, ds in tables.items() if name[:9] == "channels/"}
            ),
            can=_can(tables["raw/can"][...]) if raw else None,
            serial=SerialFrames(*_columns(tables["raw/serial"][...], ("time", "data")))
            if raw
            else None,
            counters=MappingProxyType(_counters(f[COUNTERS_PATH][...])),
            gaps=tuple(_gaps(tables["gaps"][...])),
        )


def read_status(path: str | os.PathLike[str]) -> RunStatus:
    """Only the run status, cheaply (no datasets read)."""
    with _reading(Path(path)) as (f, _, alive):
        return _status(f, _tables(f), alive)


def list_runs(directory: str | os.PathLike[str], *, probe: bool = False) -> list[RunSummary]:
    """A summary row per *.h5 file in `directory`, by name; broken files show as "unreadable".

    probe: read each file in a forked child first (rig.runfile.probe), so that a file
    on which HDF5 hangs or crashes is reported too; for command-line use.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise DataError(f"{directory}: no such directory of run files")
    rows = []
    for path in sorted(directory.glob("*.h5")):
        try:
            if probe:
                check_readable(path, _summary)
            rows.append(_summary(path))
        except DataError as exc:
            rows.append(RunSummary(path.name, "unreadable", 0.0, 0, 0, str(exc)))
    return rows


@contextlib.contextmanager
def _reading(path: Path) -> Iterator[tuple[h5py.File, dict[str, object], bool]]:
    """Open, check the layout, yield (file, meta, writer_alive); h5py errors become DataError."""
    f, _ = open_for_read(path)
    try:
        meta = check_layout(path, f)
        yield f, meta, writer_alive(path)
    except DataError:
        raise
    except _CORRUPT as exc:
        raise DataError(f"{path}: unreadable run file: {one_line(exc)}") from None
    finally:
        f.close()


def check_layout(path: Path, f: h5py.File) -> dict[str, object]:
    """Raise DataError unless `f` has every group, table, attribute and the schema version.

    Returns the /meta attributes as Python values.
    """
    missing = [g for g in (*GROUPS, COUNTERS_PATH, *_SPECS) if g not in f]
    if missing:
        raise DataError(f"{path}: not a run file: missing /{', /'.join(missing)}")
    meta = {name: _text(value) for name, value in f["meta"].attrs.items()}
    version = meta.get("schema_version")
    if version != SCHEMA_VERSION:
        raise DataError(f"{path}: schema version {version}, this reader reads {SCHEMA_VERSION}")
    absent = [a for a in ROOT_ATTRS if a not in f.attrs] + [
        f"meta.{a}" for a in META_ATTRS if a not in meta
    ]
    if absent:
        raise DataError(f"{path}: missing attributes {', '.join(absent)}")
    for name, spec in _SPECS.items():
        if f[name].dtype.names != spec.dtype.names:
            raise DataError(f"{path}: /{name} has fields {f[name].dtype.names}, "
                            f"expected {spec.dtype.names}")
    if f[COUNTERS_PATH].dtype.names != COUNTER_DTYPE.names:
        raise DataError(f"{path}: /{COUNTERS_PATH} has unexpected fields")
    return {name: meta[name] for name in META_ATTRS}


def _text(value: object) -> object:
    if isinstance(value, bytes):
        return value.decode()
    return value.item() if isinstance(value, np.generic) else value


def _tables(f: h5py.File) -> dict[str, h5py.Dataset]:
    """Every table by path: "raw/can", "raw/serial", "gaps", "channels/<name>".

    Each must be a 1-D dataset whose rows the file can hold: a damaged header claiming
    billions of rows is refused here rather than allocated when read.
    """
    tables = {name: f.get(name) for name in _SPECS}
    tables |= {f"channels/{name}": f["channels"].get(name) for name in f["channels"]}
    size = os.path.getsize(f.filename)
    for name, ds in tables.items():
        if not isinstance(ds, h5py.Dataset) or ds.ndim != 1:
            raise DataError(f"{f.filename}: not a run file: /{name} is not a 1-D table")
        if ds.shape[0] * ds.dtype.itemsize > size + _SLACK_BYTES:
            raise DataError(f"{f.filename}: /{name} claims {ds.shape[0]} rows, more than "
                            f"its {size}-byte file can hold")
    return tables


def _status(f: h5py.File, tables: Mapping[str, h5py.Dataset], alive: bool) -> RunStatus:
    """Samples come from dataset lengths, which are right even while the run is live."""
    attrs = {name: _text(f.attrs[name]) for name in ROOT_ATTRS}
    samples = {name.removeprefix("channels/"): ds.shape[0] for name, ds in tables.items()}
    del samples["gaps"]
    return RunStatus(
        exit_status=str(attrs["exit_status"]),
        reason=str(attrs["reason"]),
        complete=bool(attrs["complete"]),
        samples=MappingProxyType(samples),
        writer_alive=alive,
    )


def _columns(table: np.ndarray, names: Iterable[str]) -> list[np.ndarray]:
    return [np.ascontiguousarray(table[name]) for name in names]


def _channel(ds: h5py.Dataset) -> Channel:
    if ds.dtype.names != ("time", "value"):
        raise DataError(f"{ds.file.filename}: {ds.name} is not a (time, value) table")
    table = ds[...]
    time, value = _columns(table, ("time", "value"))
    stored = ds.attrs
    attrs = {k: str(_text(stored.get(k, ""))) for k in ("units", "source", "description")}
    return Channel(ds.name.rsplit("/", 1)[-1], time, value, dtype=str(value.dtype), **attrs)


def _can(table: np.ndarray) -> CanFrames:
    return CanFrames(*_columns(table, ("time", "arbitration_id", "dlc", "data", "flags")))


def _counters(table: np.ndarray) -> dict[str, Mapping[str, int]]:
    return {
        row["source"].decode(): MappingProxyType({k: int(row[k]) for k in COUNTER_KINDS})
        for row in table
    }


def _gaps(table: np.ndarray) -> Iterator[Gap]:
    for row in table:
        yield Gap(row["channel"].decode(), int(row["start_sample"]), int(row["end_sample"]),
                  float(row["start_time"]), float(row["end_time"]), int(row["count"]))


def _summary(path: Path) -> RunSummary:
    with _reading(path) as (f, _, alive):
        tables = _tables(f)
        status = _status(f, tables, alive)
        ends = [_last_time(ds) for name, ds in tables.items() if name != "gaps"]
        lost = int(f[COUNTERS_PATH]["lost"].sum())
    channel_samples = sum(n for k, n in status.samples.items() if not k.startswith("raw/"))
    return RunSummary(path.name, status.state, max(ends, default=0.0), channel_samples, lost,
                      status.reason)


def _last_time(ds: h5py.Dataset) -> float:
    return float(ds[-1]["time"]) if ds.shape[0] else 0.0
