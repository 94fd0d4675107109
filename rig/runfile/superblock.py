"""The HDF5 superblock's consistency flags: read them, and clear them like `h5clear -s -i`.

A writer sets flags in the superblock (version 2/3, at offset 0) when it opens
a file for writing and clears them when it closes it; HDF5 refuses to open a
flagged file except through a SWMR read, and only if the SWMR bit is set. A
writer killed while closing (plain read-write mode) leaves bit 0 alone set, so
nothing opens it. Clearing the flags, and making the end-of-allocation address
cover the bytes actually on disk (the SWMR writer does not update it), is what
h5clear does; this module does it without hdf5-tools. The superblock is
protected by Bob Jenkins' lookup3 hash, reimplemented here.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

SIGNATURE = b"\x89HDF\r\n\x1a\n"
_M32 = 0xFFFFFFFF
_HEADER = 12  # signature, version, size of offsets, size of lengths, flags


def status_flags(path: Path) -> int | None:
    """The consistency flags (0 = closed cleanly), None for superblock versions without them.

    Raises ValueError if `path` does not start with an HDF5 signature.
    """
    with open(path, "rb") as f:
        head = f.read(_HEADER)
    if len(head) < _HEADER or not head.startswith(SIGNATURE):
        raise ValueError("no HDF5 signature at the start of the file")
    return head[11] if head[8] >= 2 else None


def clear_status_flags(path: Path) -> None:
    """Clear the flags of `path` in place and make its end address cover the whole file."""
    size = os.path.getsize(path)
    with open(path, "r+b") as f:
        block = bytearray(f.read(_HEADER + 4 * 8 + 4))
        offsets = block[9]
        if block[8] < 2 or offsets not in (4, 8):
            raise ValueError(f"superblock version {block[8]} / {offsets}-byte offsets not handled")
        fmt = "<Q" if offsets == 8 else "<I"
        eoa_at = _HEADER + 2 * offsets  # after base address and superblock-extension address
        eoa = struct.unpack_from(fmt, block, eoa_at)[0]
        block[11] = 0
        struct.pack_into(fmt, block, eoa_at, max(eoa, size))
        end = _HEADER + 4 * offsets
        struct.pack_into("<I", block, end, lookup3(bytes(block[:end])))
        f.seek(0)
        f.write(block[: end + 4])
        if eoa > size:
            f.truncate(eoa)  # space allocated but never written: HDF5 wants it to exist


def _rot(x: int, k: int) -> int:
    return ((x << k) | (x >> (32 - k))) & _M32


def lookup3(data: bytes, initval: int = 0) -> int:
    """Jenkins' lookup3 `hashlittle`, as HDF5's H5_checksum_lookup3 computes metadata checksums."""
    a = b = c = (0xDEADBEEF + len(data) + initval) & _M32
    words = data
    while len(words) > 12:
        x, y, z = struct.unpack_from("<III", words)
        a, b, c = (a + x) & _M32, (b + y) & _M32, (c + z) & _M32
        a, b, c = _mix(a, b, c)
        words = words[12:]
    if not words:
        return c
    x, y, z = struct.unpack("<III", words.ljust(12, b"\0"))
    return _final((a + x) & _M32, (b + y) & _M32, (c + z) & _M32)


def _mix(a: int, b: int, c: int) -> tuple[int, int, int]:
    a = ((a - c) & _M32) ^ _rot(c, 4)
    c = (c + b) & _M32
    b = ((b - a) & _M32) ^ _rot(a, 6)
    a = (a + c) & _M32
    c = ((c - b) & _M32) ^ _rot(b, 8)
    b = (b + a) & _M32
    a = ((a - c) & _M32) ^ _rot(c, 16)
    c = (c + b) & _M32
    b = ((b - a) & _M32) ^ _rot(a, 19)
    a = (a + c) & _M32
    c = ((c - b) & _M32) ^ _rot(b, 4)
    b = (b + a) & _M32
    return a, b, c


def _final(a: int, b: int, c: int) -> int:
    c = ((c ^ b) - _rot(b, 14)) & _M32
    a = ((a ^ c) - _rot(c, 11)) & _M32
    b = ((b ^ a) - _rot(a, 25)) & _M32
    c = ((c ^ b) - _rot(b, 16)) & _M32
    a = ((a ^ c) - _rot(c, 4)) & _M32
    b = ((b ^ a) - _rot(a, 14)) & _M32
    c = ((c ^ b) - _rot(b, 24)) & _M32
    return c
