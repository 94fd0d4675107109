"""Reading an untrusted run file without hanging or crashing the reader.

The HDF5 C library can loop forever on some damaged files (fuzzing found a zeroed
4 KiB block that makes reading an attribute spin: tests/test_faults_input.py),
and a C library may crash outright. Neither is an exception Python can catch,
and neither can be interrupted: the loop holds the GIL. So the command-line
readers (`rig runs`, `rig recover`, `analysis fit`) first let a forked child
read the file the same way: if the child neither finishes nor fails within a
time that grows with the file's size, or dies of a signal, the file is reported
as damaged on one line instead. An ordinary failure in the child (a DataError)
is left for the parent's own read to report. The child costs a fork (~10 ms)
and one extra read of what the command reads anyway.
"""

from __future__ import annotations

import faulthandler
import os
import signal
import time
from collections.abc import Callable
from pathlib import Path

from rig.errors import DataError

BASE_TIMEOUT_S = 5.0  # s a small file may take, on a loaded machine
READ_RATE = 50e6  # bytes/s at least (measured ~150 MB/s here): more time for bigger files


def check_readable(path: str | os.PathLike[str], read: Callable[[Path], object],
                   timeout: float | None = None) -> None:
    """Raise DataError if `read(path)` hangs or crashes in a forked child; else return.

    timeout: s the child may take; default BASE_TIMEOUT_S plus 1 s per READ_RATE bytes.
    Where fork is missing (not POSIX) nothing is checked.
    """
    path = Path(path)
    if not hasattr(os, "fork") or not path.is_file():
        return  # the real read reports a missing file
    if timeout is None:
        timeout = BASE_TIMEOUT_S + path.stat().st_size / READ_RATE
    pid = os.fork()
    if pid == 0:  # the child: read, then leave without running the parent's cleanup
        faulthandler.disable()  # a crash here is reported by the parent, on one line
        try:
            read(path)
        except BaseException:  # noqa: BLE001 - the parent's own read reports it
            pass
        os._exit(0)
    _wait(pid, path, timeout)


def _wait(pid: int, path: Path, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        if time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            raise DataError(f"{path}: damaged HDF5 file: reading it did not finish in "
                            f"{timeout:.0f} s (the library loops on its metadata)")
        time.sleep(0.005)
    if os.WIFSIGNALED(status):
        raise DataError(f"{path}: damaged HDF5 file: the library crashed reading it "
                        f"(signal {os.WTERMSIG(status)})")
