"""File-level plumbing shared by the run-file writer, reader and recovery.

- The writer-alive lock: the writer holds an open-file-description (OFD) write
  lock on one byte far past the end of the run file. HDF5 drops its own flock
  in SWMR mode, and a kill -9 releases an OFD lock with the process, so "lock
  held" means exactly "a writer process is still running". OFD locks (unlike
  classic POSIX locks) survive another open/close of the same file in the
  writer process, e.g. a live view reading it.
- Opening for reading: a file still flagged as open for writing (live, or its
  writer died) is opened through a SWMR read, which ignores the flags.
- h5py errors become one-line DataErrors naming the file.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import struct
import tempfile
import time
from pathlib import Path

import h5py

from rig.errors import DataError

_LOCK_OFFSET = 2**62  # far past any real file size: nothing else ever locks it
_FLOCK = "hhqqi4x"  # struct flock on Linux 64-bit: type, whence, start, len, pid
_HAVE_OFD = hasattr(fcntl, "F_OFD_SETLK")
_LOCK_RETRIES = 20  # opening races the few ms the writer holds HDF5's own lock at close
_LOCK_RETRY_S = 0.025


def one_line(exc: BaseException) -> str:
    """The exception's message on one line (HDF5 messages embed newlines)."""
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def describe(exc: BaseException) -> str:
    """`Type: message` on one line, or just `Type` when there is no message."""
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def is_disk_full(exc: BaseException) -> bool:
    """True for ENOSPC/EDQUOT, whether raised by the OS or wrapped in an h5py error text."""
    codes = (errno.ENOSPC, errno.EDQUOT)
    return getattr(exc, "errno", None) in codes or any(
        f"errno = {code}," in str(exc) for code in codes
    )


def hold_writer_lock(path: Path) -> int:
    """Open `path` and take the writer-alive lock; returns the fd to close at the end."""
    fd = os.open(path, os.O_RDWR | os.O_CLOEXEC)
    if _HAVE_OFD:
        try:
            request = struct.pack(_FLOCK, fcntl.F_WRLCK, os.SEEK_SET, _LOCK_OFFSET, 1, 0)
            fcntl.fcntl(fd, fcntl.F_OFD_SETLK, request)
        except OSError as exc:
            os.close(fd)
            raise DataError(
                f"{path}: another writer holds this run file ({one_line(exc)})") from None
    return fd


def writer_alive(path: Path) -> bool:
    """True if a live process holds `path`'s writer lock (False where OFD locks don't exist)."""
    if not _HAVE_OFD:
        return False
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return False
    try:
        probe = struct.pack(_FLOCK, fcntl.F_RDLCK, os.SEEK_SET, _LOCK_OFFSET, 1, 0)
        reply = fcntl.fcntl(fd, fcntl.F_OFD_GETLK, probe)
        return struct.unpack(_FLOCK, reply)[0] != fcntl.F_UNLCK
    finally:
        os.close(fd)


def reserve_path(path: Path) -> Path:
    """The writer's disk-space reserve file beside `path` (deleted at close or by recover)."""
    return path.with_name(f".{path.name}.reserve")


def open_for_read(path: Path, *, locking: bool = True) -> tuple[h5py.File, bool]:
    """Open a run file read-only; returns (file, opened_via_swmr). Raises DataError.

    locking=False takes no HDF5 file lock, so a reader that stays open never
    delays the writer's final status write.
    """
    if not path.is_file():
        raise DataError(f"{path}: no such run file")
    for _ in range(_LOCK_RETRIES):
        try:
            return h5py.File(path, "r", **_lock_kw(locking)), False
        except BlockingIOError:
            time.sleep(_LOCK_RETRY_S)  # the writer is writing the final status right now
        except OSError as exc:
            if "already open for write" not in str(exc):
                raise DataError(f"{path}: {_describe_open_error(exc)}") from None
            return _open_swmr(path, locking), True
    raise DataError(f"{path}: locked by another process for {_LOCK_RETRIES * _LOCK_RETRY_S:.1f} s")


def _lock_kw(locking: bool) -> dict[str, bool]:
    # HDF5 refuses a second open in one process whose locking settings differ from
    # the first, so keep h5py's default unless asked not to lock
    return {} if locking else {"locking": False}


def _open_swmr(path: Path, locking: bool) -> h5py.File:
    try:
        return h5py.File(path, "r", swmr=True, **_lock_kw(locking))
    except OSError as exc:
        raise DataError(f"{path}: {_describe_open_error(exc)}") from None


def _describe_open_error(exc: OSError) -> str:
    text = one_line(exc)
    if "file signature not found" in text:
        return "not an HDF5 file"
    if "not already open for SWMR writing" in text:
        return "its writer died while closing it; rig.runfile.recover() makes it readable"
    if "truncated file" in text:
        return f"truncated HDF5 file ({text})"
    return f"cannot open as HDF5 ({text})"


def refuse_unless_writable(path: Path, reserve_bytes: int) -> Path:
    """Refuse before the run starts (no directory, not writable, file exists, no space).

    Creates and returns the disk-space reserve: `reserve_bytes` really
    allocated beside `path`, deleted to give HDF5 room to close after ENOSPC.
    """
    if not path.parent.is_dir():
        raise DataError(f"{path}: directory {path.parent} does not exist or is not a directory")
    if path.exists():
        raise DataError(f"{path}: already exists; refusing to overwrite a run file")
    reserve = reserve_path(path)
    try:
        fd = os.open(reserve, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o644)
        try:
            os.posix_fallocate(fd, 0, reserve_bytes)
        finally:
            os.close(fd)
    except OSError as exc:
        with contextlib.suppress(OSError):
            reserve.unlink(missing_ok=True)
        raise DataError(f"{path}: cannot write in {path.parent}: {exc.strerror}") from None
    return reserve


DEFAULT_MIN_FREE_BYTES = 16 << 20  # RunWriter's default: stop logging below this


def check_output_dir(directory: Path, min_free_bytes: int = DEFAULT_MIN_FREE_BYTES) -> None:
    """Refuse a run directory that is missing, not a directory, not writable or nearly full.

    Called before a run opens anything, so a refused run moves nothing. Writability is
    tried, not inferred from permission bits (root ignores them; a read-only mount does
    not): a probe file is created and removed.
    """
    if not directory.exists():
        raise DataError(f"{directory}: output directory does not exist")
    if not directory.is_dir():
        raise DataError(f"{directory}: output path is not a directory")
    try:
        fd, probe = tempfile.mkstemp(prefix=".rig-probe-", dir=directory)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise DataError(f"{directory}: output directory not writable: {exc.strerror}") from None
    free = free_bytes(directory)
    if free < min_free_bytes:
        raise DataError(f"{directory}: only {free / 2**20:.1f} MiB free, a run needs at least "
                        f"{min_free_bytes / 2**20:.0f} MiB")


def reopen_for_status(path: Path) -> h5py.File:
    """Open the closed SWMR file read-write to set its final status.

    Plain readers hold HDF5's shared lock while they read; wait for them (a
    live view reads for milliseconds), then write without the lock rather than
    leave the run without its status: only such a reader risks a torn read.
    """
    for _ in range(_LOCK_RETRIES):
        try:
            return h5py.File(path, "r+")
        except BlockingIOError:
            time.sleep(_LOCK_RETRY_S)
    return h5py.File(path, "r+", locking=False)


def free_bytes(directory: Path) -> int:
    """Bytes an unprivileged writer may still use on `directory`'s file system."""
    st = os.statvfs(directory)
    return st.f_bavail * st.f_frsize

