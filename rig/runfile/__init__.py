"""The HDF5 run file: one file per run, owned by this package (its public names are here).

Layout (schema version 1; tables in rig.runfile.schema, drawn out in docs/runfile.md)::

    /                 exit_status ("running" | success | abort | fail), reason,
                      complete (bool), samples_json {table: rows}
    /meta             schema_version, profile_name, profile_toml, configuration_toml,
                      calibration_json, software_version, backend, host,
                      start_time, end_time (ISO 8601 UTC), start_unix, time_base
    /raw/can          (time f8 s, arbitration_id u4, dlc u1, data u1[8], flags u1)
    /raw/serial       (time f8 s, data u1[16])
    /channels/<name>  (time f8 s, value) + units, source, description, dtype
    /counters         per source: lost, crc_errors, duplicates, reordered, bytes_discarded
    /gaps             (channel, start_sample, end_sample, start_time, end_time, count)

Every table is a 1-D chunked compound dataset growing without limit. The file
is written in SWMR mode so another process can read it while it grows, and
after a kill -9 it holds every flushed block; `recover` makes such a file
plainly readable, `open_run` reads it either way.

Writing::

    with RunWriter(path, RunInfo("A", profile_text, "sim")) as run:
        run.can_frame(run.elapsed(), 0x120, payload)
        run.sample("table_u", t, u)

Reading: `open_run(path)` -> RunFile (a snapshot, live or not); `LiveRun(path).poll()`
-> the rows added since the last poll (for live views); `list_runs(directory)` ->
[RunSummary]; `recover(path)` makes a crashed run plainly readable.
"""

from __future__ import annotations

from rig.runfile.follow import LiveRun
from rig.runfile.io import check_output_dir
from rig.runfile.probe import check_readable
from rig.runfile.reader import (
    CanFrames,
    Channel,
    Gap,
    RunFile,
    RunStatus,
    RunSummary,
    SerialFrames,
    list_runs,
    open_run,
    read_status,
)
from rig.runfile.recover import recover
from rig.runfile.schema import (
    CAN_DTYPE,
    CAN_FLAG_ERROR,
    CAN_FLAG_EXTENDED,
    CAN_FLAG_REMOTE,
    COUNTER_KINDS,
    FIXED_DATASETS,
    SCHEMA_VERSION,
    SERIAL_DTYPE,
    SERIAL_FRAME_BYTES,
    ChannelSpec,
    DatasetSpec,
    RunInfo,
    standard_channels,
)
from rig.runfile.writer import RunWriter

__all__ = [
    "CAN_DTYPE", "CAN_FLAG_ERROR", "CAN_FLAG_EXTENDED", "CAN_FLAG_REMOTE", "COUNTER_KINDS",
    "FIXED_DATASETS", "SCHEMA_VERSION", "SERIAL_DTYPE", "SERIAL_FRAME_BYTES",
    "CanFrames", "Channel", "ChannelSpec", "DatasetSpec", "Gap", "LiveRun", "RunFile", "RunInfo",
    "RunStatus", "RunSummary", "RunWriter", "SerialFrames",
    "check_output_dir", "check_readable", "list_runs", "open_run", "read_status", "recover",
    "standard_channels",
]
