"""recover(): make a run file whose writer died plainly readable, without h5clear.

A writer killed in SWMR mode leaves "open for write" flags in the superblock:
plain HDF5 readers (h5py without swmr=True, HDFView, h5dump) refuse the file,
though `open_run` reads it through a SWMR read. A writer killed during the
few milliseconds in which `close` reopens the file plainly to write the final
status leaves a flag that even a SWMR read refuses. Either way the data on
disk is consistent (SWMR orders its writes so that it always is), so we copy
the file, clear the flags on the copy (what `h5clear -s -i` does), check it
opens plainly as a run file, and swap it in atomically (in place, unless a
destination is given). A run that died running gets exit_status "crashed" and
complete False: the file then says what `rig runs` and every reader say of it.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from pathlib import Path

import h5py

from rig.errors import DataError
from rig.runfile.io import one_line, reserve_path, writer_alive
from rig.runfile.reader import check_layout, read_status
from rig.runfile.schema import CRASHED, RUNNING
from rig.runfile.superblock import clear_status_flags, status_flags
from rig.runfile.tables import utc_now


def recover(path: str | os.PathLike[str], dest: str | os.PathLike[str] | None = None) -> Path:
    """Make the run file at `path` plainly readable, at `dest` (default: in place); return it.

    A file that was closed properly is left alone (copied if `dest` is given).
    Raises DataError if its writer is still running or it is not a run file.
    """
    path = Path(path)
    target = path if dest is None else Path(dest)
    if not path.is_file():
        raise DataError(f"{path}: no such file" if not path.exists() else
                        f"{path}: not a file")
    if writer_alive(path):
        raise DataError(f"{path}: its writer is still running; recover only after it has died")
    try:
        flags = status_flags(path)
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: cannot recover: {one_line(exc)}") from None
    if not flags:
        read_status(path)  # raises DataError unless it is a readable run file
        if target != path:
            shutil.copyfile(path, target)
        return target
    scratch = target.with_name(f".{target.name}.recovering")
    try:
        shutil.copyfile(path, scratch)
        clear_status_flags(scratch)
        _mark_incomplete(path, scratch)
        os.replace(scratch, target)
    except DataError:
        raise
    except (OSError, ValueError, KeyError, RuntimeError) as exc:
        raise DataError(f"{path}: cannot recover: {one_line(exc)}") from None
    finally:
        scratch.unlink(missing_ok=True)  # nothing left once replaced
    with contextlib.suppress(OSError):
        reserve_path(path).unlink(missing_ok=True)  # the dead writer's disk-space reserve
    return target


def _mark_incomplete(original: Path, copy: Path) -> None:
    """Check the flag-free copy opens plainly as a run file; mark a "running" run incomplete."""
    with h5py.File(copy, "r+") as f:
        check_layout(original, f)
        if str(f.attrs["exit_status"]) != RUNNING:
            return  # died after writing its final status: nothing to add
        samples = {f"raw/{name}": ds.shape[0] for name, ds in f["raw"].items()}
        samples |= {name: ds.shape[0] for name, ds in f["channels"].items()}
        f.attrs["exit_status"] = CRASHED
        f.attrs["complete"] = False
        f.attrs["reason"] = (
            "writer stopped without closing the file (crash or kill); "
            f"recovered {utc_now()} with the rows flushed before it stopped"
        )
        f.attrs["samples_json"] = json.dumps(samples)
