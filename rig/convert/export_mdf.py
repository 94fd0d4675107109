"""`rig export --mdf`: a run file's channels as ASAM MDF 4, for the engineer's usual viewer.

Each channel of /channels becomes one MDF channel group with its own time master
(the sensors and actuators sample on their own clocks, so no common time base is
invented), named as in the run file, with its units, and its description and source
as the channel comment. The file header carries the run's wall-clock start, so MDF
time 0 is the run's t = 0; its comment names the run file, the profile, the backend
and the exit status. Raw CAN and serial frames and /gaps are not exported: the run
file keeps them. asammdf is imported only here, when an export is asked for.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

from rig.errors import DataError
from rig.runfile import check_readable, open_run
from rig.runfile.reader import RunFile

MDF_VERSION = "4.10"


@dataclass
class ExportResult:
    """What `export_mdf` wrote: the file, samples per channel, channels left out."""

    path: Path
    samples: dict[str, int]
    empty: list[str] = field(default_factory=list)

    def summary(self) -> str:
        lines = [(f"{self.path}: MDF {MDF_VERSION}, {len(self.samples)} channels, "
                  f"{sum(self.samples.values()):,} samples")]
        if self.empty:
            lines.append(f"  left out (no samples): {', '.join(self.empty)}")
        return "\n".join(lines)


def export_mdf(run_path: str | os.PathLike[str], out: str | os.PathLike[str]) -> ExportResult:
    """Write the channels of run file `run_path` to the new MDF 4 file `out`.

    DataError names the file: an unreadable run file, no channel with samples, `out`
    already there (never overwritten) or not writable.
    """
    run_path, out = Path(run_path), Path(out)
    if out.exists():
        raise DataError(f"{out}: already exists; an export never overwrites a file")
    check_readable(run_path, lambda p: open_run(p, raw=False))  # refused, not hung on
    run = open_run(run_path, raw=False)
    from asammdf import MDF, Signal  # a heavy import, for this command only

    samples, empty = {}, []
    mdf = MDF(version=MDF_VERSION)
    try:
        start = _start(run)
        if start is not None:
            mdf.header.start_time = start
        mdf.header.comment = _comment(run)
        for name, ch in run.channels.items():
            if ch.time.size == 0:
                empty.append(name)
                continue
            source = f"{ch.description}; source {ch.source}" if ch.description else ch.source
            mdf.append([Signal(ch.value, ch.time, unit=ch.units, name=name, comment=source)],
                       comment=f"{name} ({ch.units})")
            samples[name] = int(ch.time.size)
        if not samples:
            raise DataError(f"{run_path}: no channel has samples; nothing to export")
        try:
            mdf.save(out, overwrite=False)
        except OSError as e:
            raise DataError(f"{out}: cannot write: {e.strerror or e}") from None
    finally:
        mdf.close()
    return ExportResult(out, samples, empty)


def _start(run: RunFile) -> datetime | None:
    try:
        return datetime.fromisoformat(str(run.meta.get("start_time", "")))
    except ValueError:
        return None


def _comment(run: RunFile) -> str:
    meta = run.meta
    profile = meta.get("profile_name") or "(none)"
    reason = f" ({run.status.reason})" if run.status.reason else ""
    return (f"isolator rig run file {run.path.name}: profile {profile}, backend "
            f"{meta.get('backend', '?')}, {run.status.state}{reason}, software "
            f"{meta.get('software_version', '?')}")
