"""Receiving: one thread per bus, each handing what it got to the runner through one queue.

The threads only receive and timestamp; decoding and writing happen on the
runner's thread, because the run file has a single writer (rig.runfile). A
failing receiver puts its exception on the queue, so the run stops with it.

Queue items, one small frozen dataclass per kind (`Received`): `CanReceived`, a frame
with the bus's own timestamp (Unix s); `SerialReceived`, what one read of the port
decoded, also with no frames when it brought only garbage; `Idle`, when the bus
had nothing for POLL_S; `ReceiverFailed`, the exception that ended a receiver.
Items of one source keep their order, so the runner knows up to when each stream
is complete (its *horizon*, which the liveness rules of rig.run.interlocks
measure silence against).
"""

from __future__ import annotations

import dataclasses
import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import can
import serial

from rig.config import RigConfig
from rig.wire.serial_frame import DecoderStats, Frame, FrameDecoder

# python-can's socketcand client logs a warning whenever one recv ends inside a
# frame and it waits for the rest (routine under load, not a fault), and an error
# with a whole traceback when the connection is lost, which the receiver reports
# itself as the run's one-line abort reason
logging.getLogger("can.interfaces.socketcand.socketcand").setLevel(logging.CRITICAL)

POLL_S = 0.05  # s a receiver blocks before it looks at its stop flag
IDLE_EVERY_S = 0.01  # s between two "nothing new" items of the serial receiver


@dataclass(frozen=True)
class CanReceived:
    """A frame off the bus; `frame.timestamp` is the bus's own stamp (Unix s)."""

    frame: can.Message


@dataclass(frozen=True)
class SerialReceived:
    """What one read of the port decoded (maybe nothing: garbage or silence), when it
    returned (host monotonic s), and the decoder's totals then."""

    host_s: float
    frames: list[Frame]
    stats: DecoderStats


@dataclass(frozen=True)
class Idle:
    """Receiver `source` found nothing new since `since` (Unix s for CAN)."""

    source: str
    since: float


@dataclass(frozen=True)
class ReceiverFailed:
    """Receiver `source` ("can" or "serial") ended with `error`."""

    source: str
    error: BaseException


Received = CanReceived | SerialReceived | Idle | ReceiverFailed


def open_bus(config: RigConfig) -> can.BusABC:
    """The configured CAN bus (any python-can interface: socketcand, socketcan, pcan, …)."""
    kwargs = config.can.bus_kwargs()
    if config.can.interface == "socketcand":
        kwargs.pop("bitrate", None)  # the daemon's interface sets the bitrate, not the client
    return can.Bus(**kwargs)


class Receivers:
    """The CAN and serial receiver threads; `close()` stops and joins them (idempotent)."""

    def __init__(self, bus: can.BusABC, port: serial.SerialBase) -> None:
        self.queue: queue.SimpleQueue[Received] = queue.SimpleQueue()
        self._bus, self._port = bus, port
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._guard, args=(name, fn), name=f"rig-{name}")
                         for name, fn in (("can", self._can), ("serial", self._serial))]
        for t in self._threads:
            t.start()

    def _guard(self, name: str, loop: Callable[[], None]) -> None:
        try:
            loop()
        except Exception as exc:  # noqa: BLE001 - any failure goes to the runner, which stops
            if not self._stop.is_set():
                self.queue.put(ReceiverFailed(name, exc))

    def _can(self) -> None:
        while not self._stop.is_set():
            asked = time.time()
            msg = self._bus.recv(timeout=POLL_S)
            if msg is not None:
                self.queue.put(CanReceived(msg))
            else:  # nothing since `asked`: the stream is complete up to then
                self.queue.put(Idle("can", asked))

    def _serial(self) -> None:
        decoder = FrameDecoder()
        self._port.reset_input_buffer()  # bytes from before the run are not this run's
        last_put = 0.0
        while not self._stop.is_set():
            data = self._port.read(max(1, self._port.in_waiting))
            now = time.monotonic()
            frames = decoder.feed(data) if data else []
            # an empty item too (rate-limited): garbage or silence still moves the horizon
            if frames or now - last_put >= IDLE_EVERY_S:
                self.queue.put(SerialReceived(now, frames, dataclasses.replace(decoder.stats)))
                last_put = now

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            if t.is_alive():
                t.join()


def open_port(config: RigConfig) -> serial.Serial:
    """The mass sensor's serial port, raw 8N1 at the configured baud."""
    return serial.Serial(config.serial.path, config.serial.baud, timeout=POLL_S)
