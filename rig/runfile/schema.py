"""The run-file layout as data: every dataset, field, unit and attribute in one table.

`rig.runfile` re-exports this; the writer creates datasets from these tables and
the reader validates against the same tables, so the two cannot drift apart.
See docs/runfile.md for the layout drawn out and the crash-safety choice.
"""

from __future__ import annotations

import json
import re
import socket
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from rig import __version__

SCHEMA_VERSION = 1
TIME_BASE = "host time.monotonic() seconds since run start; wall-clock start in /meta start_time"

SERIAL_FRAME_BYTES = 16
CAN_DATA_BYTES = 8

# CAN flags bit field, so a frame can be re-decoded exactly as received
CAN_FLAG_ERROR = 0x01
CAN_FLAG_EXTENDED = 0x02
CAN_FLAG_REMOTE = 0x04

CAN_DTYPE = np.dtype(
    [
        ("time", "<f8"),
        ("arbitration_id", "<u4"),
        ("dlc", "u1"),
        ("data", "u1", (CAN_DATA_BYTES,)),
        ("flags", "u1"),
    ]
)
SERIAL_DTYPE = np.dtype([("time", "<f8"), ("data", "u1", (SERIAL_FRAME_BYTES,))])
NAME_BYTES = 64  # fixed-length names: variable-length strings are not SWMR-safe in datasets
GAP_DTYPE = np.dtype(
    [
        ("channel", f"S{NAME_BYTES}"),
        ("start_sample", "<i8"),
        ("end_sample", "<i8"),
        ("start_time", "<f8"),
        ("end_time", "<f8"),
        ("count", "<i8"),
    ]
)
COUNTER_KINDS = ("lost", "crc_errors", "duplicates", "reordered", "bytes_discarded")
COUNTER_DTYPE = np.dtype([("source", "S32")] + [(kind, "<i8") for kind in COUNTER_KINDS])
DEFAULT_SOURCES = ("can", "serial")

VALUE_DTYPES = frozenset(
    ["float64", "float32", "int64", "int32", "int16", "int8",
     "uint64", "uint32", "uint16", "uint8", "bool"]
)
EXIT_STATUSES = ("success", "abort", "fail")
RUNNING = "running"
# what `recover` writes over RUNNING: the file says what every reader says of it
CRASHED = "crashed"
#: "import": a log of another tool's made into a run file (rig.convert.import_log)
BACKENDS = ("sim", "hardware", "import")
_NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_.\-]{0,63}$")


@dataclass(frozen=True)
class DatasetSpec:
    """One growable table in the file: a 1-D compound dataset of `dtype` rows.

    `chunk_rows` is sized so a chunk is ~16-32 KiB: big enough that the chunk
    index stays small, small enough that a SWMR flush rewriting the open chunk
    10 times a second stays cheap.
    """

    path: str
    dtype: np.dtype
    units: str
    source: str
    description: str
    chunk_rows: int = 1024


FIXED_DATASETS: tuple[DatasetSpec, ...] = (
    DatasetSpec(
        path="raw/can",
        dtype=CAN_DTYPE,
        units="s",
        source="can",
        description="every CAN frame as received: time (s), arbitration_id, dlc, data[8], "
        "flags (1 error, 2 extended id, 4 remote)",
    ),
    DatasetSpec(
        path="raw/serial",
        dtype=SERIAL_DTYPE,
        units="s",
        source="serial",
        description="every serial frame as received: time (s), data[16] "
        "(sync, sequence, device time, CRC)",
    ),
    DatasetSpec(
        path="gaps",
        dtype=GAP_DTYPE,
        units="s",
        source="writer",
        description="`count` samples missing from `channel` between sample indices "
        "start_sample and end_sample (times start_time..end_time, s); never interpolate",
        chunk_rows=256,
    ),
)
COUNTERS_PATH = "counters"  # fixed shape (n_sources,), rewritten at every flush
GROUPS = ("raw", "channels", "meta")

#: /meta attributes and their Python type; text attributes hold TOML or JSON as written
META_ATTRS: Mapping[str, type] = MappingProxyType(
    {
        "schema_version": int,
        "profile_name": str,
        "profile_toml": str,
        "configuration_toml": str,
        "calibration_json": str,
        "software_version": str,
        "backend": str,
        "host": str,
        "start_time": str,
        "start_unix": float,
        "end_time": str,
        "time_base": str,
    }
)
#: root attributes: the run status
ROOT_ATTRS = ("exit_status", "reason", "complete", "samples_json")


@dataclass(frozen=True)
class ChannelSpec:
    """A decoded channel, stored at /channels/<name> as rows of (time s, value `dtype`).

    `source` says where the value came from, e.g. "can:0x120 TableSensor.position"
    or "serial:/dev/pts/3"; `units` is a rig.units name ("m", "1", ...).
    """

    name: str
    units: str
    source: str
    description: str = ""
    dtype: str = "float64"

    def __post_init__(self) -> None:
        if not _NAME_RE.match(self.name):
            raise ValueError(f"channel name {self.name!r} must match {_NAME_RE.pattern}")
        if self.dtype not in VALUE_DTYPES:
            known = sorted(VALUE_DTYPES)
            raise ValueError(f"channel {self.name} dtype {self.dtype!r} not in {known}")

    def dataset(self) -> DatasetSpec:
        """The table this channel is stored in."""
        dtype = np.dtype([("time", "<f8"), ("value", np.dtype(self.dtype).newbyteorder("<"))])
        path = f"channels/{self.name}"
        return DatasetSpec(path, dtype, self.units, self.source, self.description)


def standard_channels(sources: Mapping[str, str] | None = None) -> tuple[ChannelSpec, ...]:
    """The rig's channels: table_u, mass_x and, per actuator 1..6, setpoint, feedback, status.

    `sources` overrides the default source string of any channel by name.
    """
    given = dict(sources or {})
    specs = [
        ChannelSpec("table_u", "m", "can:TableSensor.position", "table displacement u"),
        ChannelSpec("mass_x", "m", "serial:MassSensor.x", "absolute mass displacement x"),
    ]
    for i in range(1, 7):
        specs += [
            ChannelSpec(
                f"actuator_setpoint_{i}", "m", f"can:ActuatorSetpoint{i}.position",
                f"position commanded to actuator {i}",
            ),
            ChannelSpec(
                f"actuator_feedback_{i}", "m", f"can:ActuatorFeedback{i}.position",
                f"position measured by actuator {i}",
            ),
            ChannelSpec(
                f"actuator_status_{i}", "1", f"can:ActuatorFeedback{i}.status",
                f"status word of actuator {i} controller (bit field)", "uint16",
            ),
        ]
    unknown = set(given) - {s.name for s in specs}
    if unknown:
        raise ValueError(f"sources given for unknown channels: {sorted(unknown)}")
    return tuple(
        ChannelSpec(s.name, s.units, given.get(s.name, s.source), s.description, s.dtype)
        for s in specs
    )


@dataclass(frozen=True)
class RunInfo:
    """What the writer records in /meta at the start of a run.

    Texts are stored verbatim (TOML as read from disk); `calibration` is stored
    as JSON, so keep its values JSON-serialisable (numbers, strings, lists).
    """

    profile_name: str
    profile_toml: str
    backend: str
    configuration_toml: str = ""
    calibration: Mapping[str, object] = field(default_factory=dict)
    software_version: str = __version__
    host: str = field(default_factory=socket.gethostname)

    def __post_init__(self) -> None:
        if self.backend not in BACKENDS:
            raise ValueError(f"backend {self.backend!r} must be one of {BACKENDS}")
        try:
            json.dumps(dict(self.calibration))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"calibration is not JSON-serialisable: {exc}") from None

