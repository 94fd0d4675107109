"""Creating the run-file layout from the schema tables, and the writer's per-table buffers."""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable, Iterable, Sequence
from datetime import UTC, datetime
from pathlib import Path

import h5py
import numpy as np
from h5py import h5s, h5t

from rig.errors import DataError
from rig.runfile.io import one_line
from rig.runfile.schema import (
    CAN_DATA_BYTES,
    CAN_DTYPE,
    COUNTER_DTYPE,
    COUNTERS_PATH,
    FIXED_DATASETS,
    GAP_DTYPE,
    GROUPS,
    RUNNING,
    SCHEMA_VERSION,
    SERIAL_DTYPE,
    SERIAL_FRAME_BYTES,
    TIME_BASE,
    ChannelSpec,
    DatasetSpec,
    RunInfo,
)

Rows = list[tuple]


class Table:
    """One growable 1-D compound dataset, its rows waiting in memory and its flushed length."""

    __slots__ = ("path", "ds", "rows", "written", "_convert", "_mtype")

    def __init__(self, path: str, ds: h5py.Dataset, convert: Callable[[Rows], np.ndarray]) -> None:
        self.path = path
        self.ds: h5py.Dataset | None = ds
        self.rows: Rows = []
        self.written = 0
        self._convert = convert
        self._mtype = h5t.py_create(ds.dtype)  # made once: h5py would rebuild it per write

    def to_array(self) -> np.ndarray:
        """The pending rows as one structured block (n,) of the table's dtype."""
        return self._convert(self.rows)

    def append(self, block: np.ndarray) -> None:
        """Resize, write and SWMR-flush one block; `written` moves only once it is on disk."""
        # h5py's low-level calls with a cached memory type: ~70 us a block instead of ~240
        n, k = self.written, len(block)
        dsid = self.ds.id
        dsid.set_extent((n + k,))
        file_space = dsid.get_space()
        file_space.select_hyperslab((n,), (k,))
        dsid.write(h5s.create_simple((k,)), file_space, block, mtype=self._mtype)
        dsid.flush()
        self.written = n + k

    def truncate(self) -> None:
        """Shrink back to the flushed length, after a failed write."""
        with contextlib.suppress(OSError, RuntimeError):
            self.ds.id.set_extent((self.written,))


def _can_block(rows: Rows) -> np.ndarray:
    t, ids, dlc, data, flags = zip(*rows)
    block = np.empty(len(rows), CAN_DTYPE)
    block["time"], block["arbitration_id"], block["dlc"], block["flags"] = t, ids, dlc, flags
    payload = b"".join(bytes(d).ljust(CAN_DATA_BYTES, b"\0") for d in data)
    block["data"] = np.frombuffer(payload, np.uint8).reshape(-1, CAN_DATA_BYTES)
    return block


def _serial_block(rows: Rows) -> np.ndarray:
    t, data = zip(*rows)
    block = np.empty(len(rows), SERIAL_DTYPE)
    block["time"] = t
    block["data"] = np.frombuffer(b"".join(data), np.uint8).reshape(-1, SERIAL_FRAME_BYTES)
    return block


def _rows_as(dtype: np.dtype) -> Callable[[Rows], np.ndarray]:
    return lambda rows: np.array(rows, dtype=dtype)


_CONVERTERS = {"raw/can": _can_block, "raw/serial": _serial_block, "gaps": _rows_as(GAP_DTYPE)}


def utc_now() -> str:
    """Wall-clock time now, ISO 8601 UTC."""
    return datetime.now(UTC).isoformat()


def create_layout(
    path: Path,
    info: RunInfo,
    channels: Sequence[ChannelSpec],
    sources: Sequence[str],
    start: datetime,
) -> tuple[h5py.File, dict[str, Table], h5py.Dataset]:
    """Create the file with every group, table and attribute, then switch it to SWMR.

    `start` is the wall-clock time (UTC) of host time 0 of the run.

    Returns the open file, the tables by path ("raw/can", "channels/table_u",
    ...) and the /counters dataset. Raises DataError if the file cannot be made.
    """
    _check_names(channels, sources)
    try:
        f = h5py.File(path, "w-", libver="latest")
    except (OSError, RuntimeError) as exc:
        raise DataError(f"{path}: cannot create run file: {one_line(exc)}") from None
    try:
        tables = _create_tables(f, channels)
        counters = f.create_dataset(COUNTERS_PATH, data=_zero_counters(sources))
        counters.attrs["description"] = "per source: frames lost (sequence gaps), CRC errors, ..."
        _write_meta(f["meta"], info, start)
        final_status_attrs(f, RUNNING, "", False, _zero_samples(tables), end_time="")
        f.swmr_mode = True  # SWMR cannot create objects: everything above exists from here on
    except BaseException as exc:
        f.close()
        path.unlink(missing_ok=True)
        if isinstance(exc, (OSError, RuntimeError)):
            raise DataError(f"{path}: cannot create run file: {one_line(exc)}") from None
        raise
    return f, tables, counters


def _create_tables(f: h5py.File, channels: Sequence[ChannelSpec]) -> dict[str, Table]:
    for group in GROUPS:
        f.create_group(group)
    tables = {}
    for spec in FIXED_DATASETS:
        tables[spec.path] = Table(spec.path, _create_table(f, spec), _CONVERTERS[spec.path])
    for channel in channels:
        spec = channel.dataset()
        ds = _create_table(f, spec)
        ds.attrs["dtype"] = channel.dtype
        ds.attrs["shape"] = "()"  # one scalar per sample
        tables[spec.path] = Table(spec.path, ds, _rows_as(spec.dtype))
    return tables


def _create_table(f: h5py.File, spec: DatasetSpec) -> h5py.Dataset:
    ds = f.create_dataset(
        spec.path, shape=(0,), maxshape=(None,), dtype=spec.dtype, chunks=(spec.chunk_rows,)
    )
    ds.attrs["units"] = spec.units
    ds.attrs["time_units"] = "s"
    ds.attrs["source"] = spec.source
    ds.attrs["description"] = spec.description
    return ds


def _zero_counters(sources: Sequence[str]) -> np.ndarray:
    counters = np.zeros(len(sources), COUNTER_DTYPE)
    counters["source"] = [s.encode() for s in sources]
    return counters


def _write_meta(meta: h5py.Group, info: RunInfo, start: datetime) -> None:
    meta.attrs["schema_version"] = SCHEMA_VERSION
    meta.attrs["profile_name"] = info.profile_name
    meta.attrs["profile_toml"] = info.profile_toml
    meta.attrs["configuration_toml"] = info.configuration_toml
    meta.attrs["calibration_json"] = json.dumps(dict(info.calibration), sort_keys=True)
    meta.attrs["software_version"] = info.software_version
    meta.attrs["backend"] = info.backend
    meta.attrs["host"] = info.host
    meta.attrs["start_time"] = start.isoformat()
    meta.attrs["start_unix"] = start.timestamp()
    meta.attrs["time_base"] = TIME_BASE


def final_status_attrs(
    f: h5py.File,
    exit_status: str,
    reason: str,
    complete: bool,
    samples: dict[str, int],
    end_time: str | None = None,
) -> None:
    """Write the root status attributes and /meta end_time (now, unless given)."""
    f.attrs["exit_status"] = exit_status
    f.attrs["reason"] = reason
    f.attrs["complete"] = bool(complete)
    f.attrs["samples_json"] = json.dumps(
        {name.removeprefix("channels/"): int(n) for name, n in samples.items()}
    )
    f["meta"].attrs["end_time"] = utc_now() if end_time is None else end_time


def _check_names(channels: Sequence[ChannelSpec], sources: Sequence[str]) -> None:
    names = [c.name for c in channels]
    duplicated = sorted({n for n in names if names.count(n) > 1})
    if duplicated:
        raise ValueError(f"channels declared twice: {duplicated}")
    too_long = [s for s in sources if not s or len(s.encode()) > COUNTER_DTYPE["source"].itemsize]
    if too_long or len(set(sources)) != len(sources):
        raise ValueError(f"counter sources must be unique, 1-32 bytes: {list(sources)}")


def _zero_samples(tables: dict[str, Table]) -> dict[str, int]:
    return {path: 0 for path in tables if path != "gaps"}


def reserve_size(channels: Iterable[ChannelSpec]) -> int:
    """Room to finish after ENOSPC: two chunks per table plus metadata, ~1 MiB for the rig."""
    tables = (*FIXED_DATASETS, *(c.dataset() for c in channels))
    return 256 * 1024 + 2 * sum(t.dtype.itemsize * t.chunk_rows for t in tables)
