"""The simulated mass sensor, read through pyserial exactly as the rig reads /dev/ttyUSB0."""

from __future__ import annotations

import time

import pytest
import serial

from rig.errors import ConfigError
from rig.wire.serial_frame import Frame, FrameDecoder, Status
from sim.pty_sensor import PtySensor, SerialFaults

LIVENESS_S = 5.0  # generous: only a hung sensor takes this long


pytestmark = pytest.mark.usefixtures("no_leaks")  # every bus, port and thread closes


def _read(port: serial.Serial, decoder: FrameDecoder, seconds: float) -> list[Frame]:
    frames: list[Frame] = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        frames += decoder.feed(port.read(port.in_waiting or 1))
    return frames


def _read_all(port: serial.Serial, decoder: FrameDecoder, sensor: PtySensor) -> list[Frame]:
    """Every byte a sensor with `stop_after_frames` sends, then nothing more for 0.1 s."""
    frames: list[Frame] = []
    deadline = time.monotonic() + LIVENESS_S
    while time.monotonic() < deadline:
        sent = sensor.stats
        done = sent.frames_sent == sensor.faults.stop_after_frames
        if done and decoder.stats.bytes_in == sent.bytes_written:
            break
        frames += decoder.feed(port.read(port.in_waiting or 1))
    frames += decoder.feed(_read_raw(port, 0.1))
    return frames


def _read_raw(port: serial.Serial, seconds: float) -> bytes:
    data = bytearray()
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        data += port.read(port.in_waiting or 1)
    return bytes(data)


def _listening(sensor: PtySensor, baud: int = 921_600) -> serial.Serial:
    """Open the port first, then power the sensor: no frame is sent to nobody."""
    port = serial.Serial(sensor.path, baud, timeout=0.05)
    sensor.start()
    return port


def test_frames_arrive_in_sequence_with_device_clock_offset_and_drift() -> None:
    t0 = time.monotonic()
    offset_s = 2**32 / 1e6 - 0.1  # the µs timestamp wraps 0.1 s into the run
    sensor = PtySensor(
        lambda t: (t - t0) * 1e5,  # counts = host time in 10 µs steps
        rate_hz=1000, drift_ppm=2000, offset_s=offset_s, start=False,
    )  # fmt: skip
    with sensor, _listening(sensor) as port:
        decoder = FrameDecoder()
        frames = _read(port, decoder, 0.5)
    assert len(frames) > 100  # ~500 expected; only liveness is asserted
    assert decoder.stats.crc_errors == 0 and decoder.stats.seq_gaps == 0
    assert decoder.stats.bytes_discarded == 0
    assert [f.seq for f in frames] == list(range(len(frames)))
    # the device ticks 1 ms of its own clock per sample, across the uint32 wrap
    assert {(b.timestamp_us - a.timestamp_us) % 2**32 for a, b in zip(frames, frames[1:])} == {1000}
    assert frames[0].timestamp_us == round(offset_s * 1e6)
    # ...which is 1/1.002 ms of host time: 99.80 counts per sample, not 100
    slope = (frames[-1].counts - frames[0].counts) / (len(frames) - 1)
    assert slope == pytest.approx(100 / 1.002, abs=0.05)
    assert all(f.status == Status.OK for f in frames)


def test_garbage_and_bit_flips_lose_exactly_the_corrupted_frames() -> None:
    faults = SerialFaults(garbage_prob=0.3, bitflip_prob=0.05, stop_after_frames=400, seed=3)
    sensor = PtySensor(lambda t: 1234, rate_hz=2000, faults=faults, start=False)
    with sensor, _listening(sensor) as port:
        decoder = FrameDecoder()
        frames = _read_all(port, decoder, sensor)
        sent = sensor.stats
    assert sent.frames_sent == 400 and sent.frames_corrupted > 0 and sent.garbage_bytes > 0
    assert decoder.stats.frames_ok == sent.frames_sent - sent.frames_corrupted
    assert decoder.stats.crc_errors >= 1 and decoder.stats.bytes_discarded >= sent.garbage_bytes
    seqs = [f.seq for f in frames]
    assert seqs == sorted(seqs) and all(f.counts == 1234 for f in frames)
    # every missing sequence number is a corrupted frame, seen as a gap or at an end
    assert decoder.stats.seq_gaps + seqs[0] + (399 - seqs[-1]) == sent.frames_corrupted
    assert sent.bytes_dropped == 0


def test_truncated_frames_cost_only_themselves() -> None:
    faults = SerialFaults(truncate_prob=0.05, stop_after_frames=300, seed=5)
    sensor = PtySensor(lambda t: -7, rate_hz=2000, faults=faults, start=False)
    with sensor, _listening(sensor) as port:
        decoder = FrameDecoder()
        frames = _read_all(port, decoder, sensor)
        sent = sensor.stats
    # a false frame needs a 2**-16 CRC match on a truncated frame and costs one intact frame
    genuine = [f for f in frames if f.timestamp_us == f.seq * 500 and f.counts == -7]
    false_frames = len(frames) - len(genuine)
    assert sent.frames_corrupted > 0 and false_frames <= 1
    assert len(genuine) >= sent.frames_sent - sent.frames_corrupted - false_frames


def test_writes_are_paced_to_the_baud_even_with_garbage() -> None:
    # 600 Hz x 16 bytes fits 115200 baud, but 8 garbage bytes per frame do not:
    # the sensor must slow down rather than beat 11 520 bytes/s
    faults = SerialFaults(garbage_prob=1.0, garbage_len=(8, 8))
    sensor = PtySensor(lambda t: 0, rate_hz=600, baud=115_200, faults=faults, start=False)
    start = time.monotonic()
    with sensor, _listening(sensor, 115_200) as port:
        received = 0
        while time.monotonic() - start < 0.5:
            received += len(port.read(port.in_waiting or 1))
        elapsed = time.monotonic() - start
    assert received > 1000  # liveness
    assert received <= elapsed * 115_200 / 10 + 24  # never faster than the line, +1 write


def test_over_range_readings_are_clamped_and_flagged() -> None:
    sensor = PtySensor(lambda t: -600_000.4, faults=SerialFaults(stop_after_frames=3), start=False)
    with sensor, _listening(sensor) as port:
        frames = _read_all(port, FrameDecoder(), sensor)
    assert [(f.counts, f.status) for f in frames] == [(-500_000, Status.OVER_RANGE)] * 3


def test_stop_sending_goes_silent_but_keeps_the_port_open() -> None:
    sensor = PtySensor(lambda t: 0, faults=SerialFaults(stop_after_frames=20), start=False)
    with sensor, _listening(sensor) as port:
        decoder = FrameDecoder()
        assert len(_read_all(port, decoder, sensor)) == 20
        assert _read_raw(port, 0.2) == b""  # silent, and the port still reads: not closed


def test_closing_the_pty_mid_run_makes_the_reader_fail() -> None:
    sensor = PtySensor(lambda t: 0, faults=SerialFaults(close_after_frames=50), start=False)
    with sensor, _listening(sensor) as port:
        decoder = FrameDecoder()
        with pytest.raises(OSError):  # SerialException from read, or EIO from in_waiting
            _read(port, decoder, LIVENESS_S)
    # a hangup discards what the reader had not read yet, so some may be missing
    assert 0 < decoder.stats.frames_ok <= sensor.stats.frames_sent == 50


def test_close_is_idempotent_and_hangs_up_the_reader() -> None:
    sensor = PtySensor(lambda t: 0, start=False)
    with _listening(sensor) as port:
        sensor.close()
        sensor.close()
        with pytest.raises(OSError):  # SerialException from read, or EIO from in_waiting
            _read(port, FrameDecoder(), LIVENESS_S)


def test_a_sample_rate_beyond_the_baud_is_refused() -> None:
    with pytest.raises(ConfigError, match="160000 baud"):
        PtySensor(lambda t: 0, rate_hz=1000, baud=115_200)
