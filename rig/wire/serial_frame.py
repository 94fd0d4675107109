"""The mass sensor's 16-byte serial frame: encoder and streaming decoder (no I/O).

Layout (little-endian, offsets in bytes; docs/serial_frame.md has the full table):

    0..1   sync          0xA5 0x5A
    2..3   seq           uint16, +1 per sample, wraps 65535 -> 0
    4..7   timestamp_us  uint32, device clock in µs, wraps every 4294.967296 s
    8..11  counts        int32, displacement in counts (NOMINAL_M_PER_COUNT m each)
    12     status        uint8, `Status` bit flags
    13     version       uint8, FORMAT_VERSION
    14..15 crc           uint16, CRC-16/CCITT-FALSE over bytes 2..13

The value is an int32 count, not a float32: the optical sensor reports integer
counts natively, ±0.5 m at 1 µm is only ±500 000 counts (int32 spans ±2.1e9),
the resolution stays uniform over the whole range (float32 spacing grows with
|x|), and there is no NaN or Inf for a reader to special-case.

The decoder resyncs by skipping one byte whenever a sync candidate fails its
CRC, so garbage or a corrupted frame costs exactly the frames it overlaps.
A CRC-16 accepts a random 12-byte window with probability 2**-16; a false frame
needs the sync pattern too, so random garbage yields one about every 2**32 bytes.
"""

from __future__ import annotations

import binascii
import enum
import struct
from dataclasses import dataclass

SYNC = b"\xa5\x5a"
FRAME_SIZE = 16
FORMAT_VERSION = 1
#: m per count of the optical sensor (1 µm); the rig configuration may override it
NOMINAL_M_PER_COUNT = 1e-6

_BODY = struct.Struct("<HIiBB")  # seq, timestamp_us, counts, status, version
_CRC = struct.Struct("<H")
_CRC_INIT = 0xFFFF  # CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, xorout 0
_SEQ_MOD = 1 << 16
_TS_MOD = 1 << 32


class Status(enum.IntFlag):
    """Bits of the status byte; 0 means a valid, in-range reading."""

    OK = 0
    OVER_RANGE = 0x01  # the target is beyond ±range; counts hold the clamped limit
    LOW_SIGNAL = 0x02  # the optical return is weak; counts are the last good value
    HW_FAULT = 0x04  # the sensor head reports a fault; counts are meaningless


@dataclass(frozen=True, slots=True)
class Frame:
    """One decoded sample.

    seq: sample number, uint16 (wraps). timestamp_us: device clock, µs, uint32
    (wraps). counts: displacement, counts. status: `Status` bits.
    """

    seq: int
    timestamp_us: int
    counts: int
    status: int


def crc16_ccitt_false(data: bytes) -> int:
    """CRC-16/CCITT-FALSE of `data` (check value of b"123456789" is 0x29B1)."""
    # binascii.crc_hqx is the non-reflected 0x1021 CRC; init 0xFFFF makes it CCITT-FALSE
    return binascii.crc_hqx(data, _CRC_INIT)


def encode_frame(seq: int, timestamp_us: int, counts: int, status: int = 0) -> bytes:
    """One 16-byte frame. seq and timestamp_us are reduced modulo their wrap.

    counts must fit int32 and status a byte; ValueError otherwise, naming the field.
    """
    if not -(1 << 31) <= counts < (1 << 31):
        raise ValueError(f"serial frame counts {counts} outside int32")
    if not 0 <= status <= 0xFF:
        raise ValueError(f"serial frame status {status} outside 0..255")
    body = _BODY.pack(seq % _SEQ_MOD, timestamp_us % _TS_MOD, counts, status, FORMAT_VERSION)
    return SYNC + body + _CRC.pack(crc16_ccitt_false(body))


@dataclass
class DecoderStats:
    """What a `FrameDecoder` has seen since it was made.

    frames_ok: frames returned. crc_errors: sync candidates whose CRC failed
    (one corrupted frame usually costs one). bytes_discarded: bytes skipped that
    were not part of a valid frame. seq_gaps: frames missing between consecutive
    valid frames, modulo the uint16 wrap. duplicates: valid frames repeating the
    previous sequence number (not returned). bad_version: valid frames of another
    format version (not returned). bytes_in: all bytes fed.
    """

    frames_ok: int = 0
    crc_errors: int = 0
    bytes_discarded: int = 0
    seq_gaps: int = 0
    duplicates: int = 0
    bad_version: int = 0
    bytes_in: int = 0


class FrameDecoder:
    """Turn a byte stream cut at arbitrary points into `Frame`s.

    A forward jump of the sequence number by more than half the wrap (32 768)
    looks the same as a backward jump, so it is taken as a sensor restart and
    counts no gap; outages that long must be judged from the device timestamp.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._last_seq: int | None = None
        self.stats = DecoderStats()

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a possible frame."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[Frame]:
        """Append `data` to the stream and return the frames completed by it, in order."""
        self.stats.bytes_in += len(data)
        buf = self._buf
        buf += data
        frames: list[Frame] = []
        pos = 0
        while True:
            start = buf.find(SYNC, pos)
            if start < 0:
                # keep a trailing first sync byte: its partner may be in the next read
                keep = 1 if buf[-1:] == SYNC[:1] else 0
                end = max(pos, len(buf) - keep)
                self.stats.bytes_discarded += end - pos
                pos = end
                break
            self.stats.bytes_discarded += start - pos
            pos = start
            if len(buf) - start < FRAME_SIZE:
                break
            frame = self._check(buf, start)
            if frame is None:
                self.stats.crc_errors += 1
                self.stats.bytes_discarded += 1
                pos = start + 1  # resync: the real frame may begin inside this window
                continue
            pos = start + FRAME_SIZE
            if self._accept(frame):
                frames.append(frame)
        del buf[:pos]
        return frames

    def _check(self, buf: bytearray, start: int) -> Frame | _Foreign | None:
        """The frame at `start` if its CRC holds (a `_Foreign` if another version), else None."""
        body = bytes(buf[start + 2 : start + 14])
        (crc,) = _CRC.unpack_from(buf, start + 14)
        if crc16_ccitt_false(body) != crc:
            return None
        seq, ts, counts, status, version = _BODY.unpack(body)
        if version != FORMAT_VERSION:
            return _FOREIGN
        return Frame(seq, ts, counts, status)

    def _accept(self, frame: Frame | _Foreign) -> bool:
        """Update the sequence counters; True if the frame is to be returned."""
        if isinstance(frame, _Foreign):
            self.stats.bad_version += 1
            return False
        if self._last_seq is not None:
            step = (frame.seq - self._last_seq) % _SEQ_MOD
            if step == 0:
                self.stats.duplicates += 1
                return False
            if step <= _SEQ_MOD // 2:
                self.stats.seq_gaps += step - 1
        self._last_seq = frame.seq
        self.stats.frames_ok += 1
        return True


class _Foreign:
    """Marker for a CRC-valid frame of another format version."""


_FOREIGN = _Foreign()
