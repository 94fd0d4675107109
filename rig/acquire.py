"""Receiving: one thread per bus, each handing what it got to the runner through one queue.

The threads only receive and timestamp; decoding and writing happen on the
runner's thread, because the run file has a single writer (rig.runfile). A
failing receiver puts its exception on the queue, so the run stops with it.

Queue items: ("can", can.Message) with the bus's own timestamp (Unix s);
("serial", host_monotonic_s, [Frame], DecoderStats); ("error", source, exception).
"""

from __future__ import annotations

import dataclasses
import logging
import queue
import threading
import time
from collections.abc import Callable

import can
import serial

from rig.config import RigConfig
from rig.serial_frame import FrameDecoder

# python-can's socketcand client logs a warning whenever one recv ends inside a
# frame and it waits for the rest: routine under load, not a fault
logging.getLogger("can.interfaces.socketcand.socketcand").setLevel(logging.ERROR)

POLL_S = 0.05  # s a receiver blocks before it looks at its stop flag


def open_bus(config: RigConfig) -> can.BusABC:
    """The configured CAN bus (any python-can interface: socketcand, socketcan, pcan, …)."""
    kwargs = config.can.bus_kwargs()
    if config.can.interface == "socketcand":
        kwargs.pop("bitrate", None)  # the daemon's interface sets the bitrate, not the client
    return can.Bus(**kwargs)


class Receivers:
    """The CAN and serial receiver threads; `close()` stops and joins them (idempotent)."""

    def __init__(self, bus: can.BusABC, port: serial.SerialBase) -> None:
        self.queue: queue.SimpleQueue = queue.SimpleQueue()
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
                self.queue.put(("error", name, exc))

    def _can(self) -> None:
        while not self._stop.is_set():
            msg = self._bus.recv(timeout=POLL_S)
            if msg is not None:
                self.queue.put(("can", msg))

    def _serial(self) -> None:
        decoder = FrameDecoder()
        self._port.reset_input_buffer()  # bytes from before the run are not this run's
        while not self._stop.is_set():
            data = self._port.read(max(1, self._port.in_waiting))
            if data:
                frames = decoder.feed(data)
                if frames:
                    stats = dataclasses.replace(decoder.stats)
                    self.queue.put(("serial", time.monotonic(), frames, stats))

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            if t.is_alive():
                t.join()


def open_port(config: RigConfig) -> serial.Serial:
    """The mass sensor's serial port, raw 8N1 at the configured baud."""
    return serial.Serial(config.serial.path, config.serial.baud, timeout=POLL_S)
