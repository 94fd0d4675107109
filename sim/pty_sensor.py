"""The simulated mass sensor: framed samples on a pty, paced to a real baud rate.

The sensor owns both ends of `os.openpty()`; the rig opens `.path` with pyserial
exactly as it would open /dev/ttyUSB0. A pty moves bytes ~40x faster than
921600 baud and blocks instead of overrunning, so the writer paces itself: each
write occupies the line for 10 bit times per byte (8N1) on the line's schedule,
and nothing is written before the line is free by that schedule (a writer woken
late catches up, as a transmit FIFO allows; the average never beats the baud).
Writes are non-blocking: when nobody reads and the pty buffer is full, bytes are
dropped like a UART overrun instead of stalling.

Device clock: at host time t (seconds, `clock`), the device reads
offset_s + (t - t_start) * (1 + drift_ppm * 1e-6) seconds. Sample k is taken at
device time offset_s + k / rate_hz, so it carries timestamp_us exactly
round(1e6 * (offset_s + k / rate_hz)) mod 2**32, and its value is
sample(host time of that instant).
"""

from __future__ import annotations

import logging
import os
import random
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, replace

from rig.errors import ConfigError
from rig.wire.serial_frame import FRAME_SIZE, Status, encode_frame

log = logging.getLogger(__name__)

BITS_PER_BYTE = 10  # 8N1: start + 8 data + stop


@dataclass(frozen=True)
class SerialFaults:
    """Faults the sensor injects, decided per frame by a RNG seeded with `seed`.

    garbage_prob: chance of random bytes (garbage_len, inclusive range) before a
    frame. bitflip_prob: chance one random bit of a frame is flipped.
    truncate_prob: chance only the first 1..15 bytes of a frame are sent.
    stop_after_frames: go silent (pty stays open) after this many frames.
    close_after_frames: close the pty after this many frames; readers then fail.
    """

    garbage_prob: float = 0.0
    garbage_len: tuple[int, int] = (1, 24)
    bitflip_prob: float = 0.0
    truncate_prob: float = 0.0
    stop_after_frames: int | None = None
    close_after_frames: int | None = None
    seed: int = 0


@dataclass
class SensorStats:
    """What the sensor has sent. frames_sent counts every sample, damaged or not;
    frames_corrupted those bit-flipped or truncated; bytes_dropped bytes lost
    because the pty buffer was full (nobody reading)."""

    frames_sent: int = 0
    frames_corrupted: int = 0
    garbage_bytes: int = 0
    bytes_written: int = 0
    bytes_dropped: int = 0


class PtySensor:
    """A serial displacement sensor on a pty; `close()` it (or use `with`) exactly once.

    sample: host time (s, on `clock`) -> displacement in counts. rate_hz: samples
    per second of device time. baud: line rate the writes are paced to.
    range_counts: readings beyond ±range are clamped and flagged OVER_RANGE.
    offset_s, drift_ppm: device clock relative to the host clock (module doc).
    start: begin sending now; pass False to open a reader on `.path` first and
    then call `start()`, so no frame goes out before anyone listens.
    """

    def __init__(
        self,
        sample: Callable[[float], float],
        rate_hz: float = 1000.0,
        baud: int = 921_600,
        faults: SerialFaults | None = None,
        offset_s: float = 0.0,
        drift_ppm: float = 0.0,
        range_counts: int = 500_000,
        clock: Callable[[], float] = time.monotonic,
        start: bool = True,
    ) -> None:
        _check_line(rate_hz, baud)
        self._sample = sample
        self.rate_hz = rate_hz
        self.baud = baud
        self.faults = faults or SerialFaults()
        self.offset_s = offset_s
        self.drift_ppm = drift_ppm
        self.range_counts = range_counts
        self._clock = clock
        self._stats = SensorStats()
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._close_lock = threading.Lock()
        self._fds_open = True
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no CR/LF or ^C translation of binary data
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)
        self.t_start = clock()
        # daemon: a sensor somebody forgot to close must not hang interpreter exit
        self._thread = threading.Thread(
            target=self._run, name=f"pty-sensor {self.path}", daemon=True
        )
        if start:
            self.start()

    def start(self) -> None:
        """Power the sensor on: sample 0 is taken now (host time `t_start`)."""
        if self._stop.is_set():
            raise RuntimeError(f"pty sensor {self.path} is closed")
        self.t_start = self._clock()
        self._thread.start()

    @property
    def stats(self) -> SensorStats:
        """A snapshot of the counters."""
        return replace(self._stats)

    def device_time(self, host_t: float) -> float:
        """Device clock reading (s, unwrapped) at host time `host_t` (s)."""
        return self.offset_s + (host_t - self.t_start) * (1.0 + self.drift_ppm * 1e-6)

    def host_time(self, device_t: float) -> float:
        """Host time (s) at which the device clock reads `device_t` (s, unwrapped)."""
        return self.t_start + (device_t - self.offset_s) / (1.0 + self.drift_ppm * 1e-6)

    def close(self) -> None:
        """Stop the writer and close the pty; safe to call more than once."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join()
        self._close_fds()

    def __enter__(self) -> PtySensor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _close_fds(self) -> None:
        with self._close_lock:
            if self._fds_open:
                self._fds_open = False
                os.close(self._master)
                os.close(self._slave)

    def _run(self) -> None:
        rng = random.Random(self.faults.seed)
        byte_time = BITS_PER_BYTE / self.baud
        line_free = self.t_start
        k = 0
        try:
            while not self._stop.is_set():
                t_k = self.host_time(self.offset_s + k / self.rate_hz)
                if self._stop.wait(max(0.0, max(t_k, line_free) - self._clock())):
                    return
                faults = self.faults
                if faults.close_after_frames is not None and k >= faults.close_after_frames:
                    self._close_fds()  # unplugged: bytes still in the pty are lost with it
                    return
                if faults.stop_after_frames is not None and k >= faults.stop_after_frames:
                    self._stop.wait()
                    return
                data = self._frame(k, t_k, rng, faults)
                self._write(data)
                # the line stays busy for the bytes just sent, on the line's own schedule: a
                # writer woken late catches up back to back, as a UART's transmit FIFO lets
                # it (else at 5,760 frames/s, a full 921,600-baud line, every late wake-up
                # was lost for good); from the start the line never carries more than the baud
                line_free = max(t_k, line_free) + len(data) * byte_time
                k += 1
        except Exception as exc:  # a broken sample() must not vanish with the thread
            self.error = exc
            log.exception("pty sensor %s stopped", self.path)

    def _frame(self, k: int, t_k: float, rng: random.Random, faults: SerialFaults) -> bytes:
        """Frame k as it goes on the wire, with garbage and damage applied."""
        counts = round(self._sample(t_k))
        status = Status.OK
        if abs(counts) > self.range_counts:
            counts = self.range_counts if counts > 0 else -self.range_counts
            status |= Status.OVER_RANGE
        timestamp_us = round(1e6 * (self.offset_s + k / self.rate_hz))
        raw = bytearray(encode_frame(k, timestamp_us, counts, status))
        self._stats.frames_sent += 1
        if rng.random() < faults.bitflip_prob:
            bit = rng.randrange(8 * FRAME_SIZE)
            raw[bit // 8] ^= 1 << (bit % 8)
            self._stats.frames_corrupted += 1
        elif rng.random() < faults.truncate_prob:
            del raw[rng.randint(1, FRAME_SIZE - 1) :]
            self._stats.frames_corrupted += 1
        if rng.random() < faults.garbage_prob:
            garbage = rng.randbytes(rng.randint(*faults.garbage_len))
            self._stats.garbage_bytes += len(garbage)
            raw[:0] = garbage
        return bytes(raw)

    def _write(self, data: bytes) -> None:
        try:
            written = os.write(self._master, data)
        except BlockingIOError:
            written = 0
        self._stats.bytes_written += written
        self._stats.bytes_dropped += len(data) - written


def _check_line(rate_hz: float, baud: int) -> None:
    """Refuse a sample rate whose frames alone would exceed the line rate."""
    if rate_hz <= 0:
        raise ConfigError("PtySensor", "rate_hz", f"{rate_hz} Hz must be positive")
    need = rate_hz * FRAME_SIZE * BITS_PER_BYTE
    if need > baud:
        raise ConfigError(
            "PtySensor",
            "rate_hz",
            f"{rate_hz:g} Hz x {FRAME_SIZE}-byte frames needs {need:.0f} baud; line is {baud} baud",
        )
