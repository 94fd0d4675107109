"""`SocketcandServer`: the simulated bus's selector thread, its public calls and its devices.

One thread does all socket work (`Clients`) and applies the faults
(`FaultyRelay`); other threads hand it work through an inbox and a wake-up
socket. The thread stamps each frame once, with `clock`, when the frame
reaches the bus; every receiver, client or device, sees that stamp.
"""

from __future__ import annotations

import ipaddress
import logging
import selectors
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import replace
from typing import Protocol

import can

from rig.errors import ConfigError
from sim.socketcand_server.bus_faults import BusFaults, FaultyRelay, RelayStats
from sim.socketcand_server.clients import Clients
from sim.socketcand_server.protocol import CAN_ERR_PROT, Frame, error_line, frame_line

log = logging.getLogger(__name__)


class CanDevice(Protocol):
    """A node simulated inside the server process."""

    def on_frame(self, msg: can.Message) -> None:
        """Called on the server thread for every frame on the bus not sent by this device."""


class SocketcandServer:
    """A socketcand rawmode bus on `host`:`port` (loopback only), serving from construction.

    port=0 picks a free port; read it from `.port`. clock: s, stamps frames
    (wall clock, as the real daemon). handshake_grace_s: see the package doc.
    max_client_buffer: bytes queued for one client before it is disconnected.
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 0,
        bus_name: str = "can0",
        faults: BusFaults | None = None,
        clock: Callable[[], float] = time.time,
        handshake_grace_s: float = 0.2,
        max_client_buffer: int = 8 << 20,
    ) -> None:
        self.host = _loopback_host(host)
        self.bus_name = bus_name
        self._clock = clock
        self._stats = RelayStats()
        self._sel = selectors.DefaultSelector()
        self._clients = Clients(
            self._sel, self._stats, bus_name, handshake_grace_s, max_client_buffer, self._offer
        )
        self._relay = FaultyRelay(
            faults or BusFaults(), self._stats, self._deliver, self._error_burst,
            self._clients.disconnect_all,
        )  # fmt: skip
        self._devices: tuple[CanDevice, ...] = ()
        self._inbox: deque[Callable[[], None]] = deque()
        self._stopping = False
        self._closed = False
        self._close_lock = threading.Lock()
        self._listener = socket.create_server((self.host, port), backlog=16)
        self._listener.setblocking(False)
        self.port: int = self._listener.getsockname()[1]
        self._wake_r, self._wake_w = socket.socketpair()
        for sock in (self._wake_r, self._wake_w):
            sock.setblocking(False)
        self._sel.register(self._listener, selectors.EVENT_READ, self._clients.accept)
        self._sel.register(self._wake_r, selectors.EVENT_READ, self._drain_wake)
        self._thread = threading.Thread(
            target=self._run, name=f"socketcand-server:{self.port}", daemon=True
        )
        self._thread.start()

    # ---- public, callable from any thread ------------------------------------

    @property
    def faults(self) -> BusFaults:
        """The faults in effect; assigning new ones reseeds the RNG and restarts the triggers."""
        return self._relay.faults

    @faults.setter
    def faults(self, faults: BusFaults) -> None:
        self._relay.faults = faults

    @property
    def stats(self) -> RelayStats:
        """A snapshot of the counters."""
        return replace(self._stats)

    @property
    def client_count(self) -> int:
        """Clients that finished the handshake and are in raw mode."""
        return sum(c.state == "raw" for c in list(self._clients.all))

    def attach(self, device: CanDevice) -> None:
        """Put `device` on the bus: it sees every later frame it did not send."""
        self._devices = (*self._devices, device)

    def detach(self, device: CanDevice) -> None:
        """Take `device` off the bus."""
        self._devices = tuple(d for d in self._devices if d is not device)

    def broadcast(self, msg: can.Message, origin: object | None = None) -> None:
        """Put `msg` on the bus for every client and every device except `origin`.

        The server stamps it when it reaches the bus; msg.timestamp is ignored.
        Ignored after shutdown, so device threads may stop in any order.
        """
        frame = (msg.arbitration_id, msg.is_extended_id, bytes(msg.data), origin)
        self._call_soon(lambda: self._offer(frame))

    def broadcast_many(self, msgs: list[can.Message], origin: object | None = None) -> None:
        """`broadcast` each of `msgs` in order, with one wake-up of the server thread.

        A device sending several frames per tick uses this: the wake-up is a socket
        write, the dearest part of a broadcast under GIL contention.
        """
        frames = [(m.arbitration_id, m.is_extended_id, bytes(m.data), origin) for m in msgs]

        def offer_all() -> None:
            for frame in frames:
                self._offer(frame)

        self._call_soon(offer_all)

    def inject_error_burst(self, count: int = 10, error_class: int = CAN_ERR_PROT) -> None:
        """Send `count` error frames of SocketCAN class `error_class` to every client."""
        self._call_soon(lambda: self._error_burst(count, error_class))

    def stall(self, seconds: float) -> None:
        """A stalled bus: every frame offered in the next `seconds` is lost, nobody is
        disconnected (a babbling node, a controller in error-passive, a frozen gateway)."""
        self._relay.stalled_until = time.monotonic() + seconds

    def disconnect_clients(self) -> None:
        """Bus-off: reset every client connection; clients see a CanError on recv."""
        self._call_soon(self._clients.disconnect_all)

    def shutdown(self) -> None:
        """Reset every client, close every socket and stop the thread; idempotent."""
        with self._close_lock:
            if self._closed:
                return
            self._closed = True
        self._stopping = True
        self._wake()
        if threading.current_thread() is not self._thread:
            self._thread.join()

    def __enter__(self) -> SocketcandServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()

    def _call_soon(self, fn: Callable[[], None]) -> None:
        if self._stopping:
            return
        self._inbox.append(fn)
        if threading.current_thread() is not self._thread:
            self._wake()

    def _wake(self) -> None:
        try:
            self._wake_w.send(b"\0")
        except OSError:  # full (a wake is pending anyway) or already closed
            pass

    # ---- the server thread ---------------------------------------------------

    def _run(self) -> None:
        try:
            while not self._stopping:
                for key, mask in self._sel.select(self._select_timeout()):
                    key.data(key.fileobj, mask)
                while self._inbox:
                    self._inbox.popleft()()
                if self._relay.held is not None and time.monotonic() >= self._relay.held_until:
                    self._relay.release_held()
                self._clients.flush()
        except Exception:
            log.exception("socketcand server on port %d failed", self.port)
        finally:
            self._close_all()

    def _select_timeout(self) -> float | None:
        now = time.monotonic()
        waits = self._clients.hold_waits(now)
        if self._relay.held is not None:
            waits.append(self._relay.held_until - now)
        return max(0.0, min(waits)) if waits else None

    def _drain_wake(self, sock: socket.socket, mask: int) -> None:
        try:
            while sock.recv(4096):
                pass
        except BlockingIOError:
            pass

    def _offer(self, frame: Frame) -> None:
        self._relay.offer(frame)

    def _deliver(self, frame: Frame) -> None:
        can_id, is_ext, data, origin = frame
        now = self._clock()
        self._stats.frames_relayed += 1
        self._clients.queue(frame_line(can_id, is_ext, data, now), origin)
        devices = self._devices
        if not devices:
            return
        msg = can.Message(
            timestamp=now, arbitration_id=can_id, is_extended_id=is_ext, data=data,
            is_rx=True, channel=self.bus_name,
        )  # fmt: skip
        for device in devices:
            if device is not origin:
                try:
                    device.on_frame(msg)
                except Exception:  # a broken device must not take the bus down
                    self._stats.device_errors += 1
                    log.exception("device %r failed on frame %s", device, msg)

    def _error_burst(self, count: int, error_class: int) -> None:
        for _ in range(count):
            self._clients.queue(error_line(error_class, self._clock()))
            self._stats.error_frames += 1

    def _close_all(self) -> None:
        self._stopping = True
        self._inbox.clear()
        self._clients.close_all()
        for sock in (self._listener, self._wake_r):
            self._sel.unregister(sock)
            sock.close()
        self._sel.close()
        self._wake_w.close()  # a late _wake() from another thread gets OSError, ignored


def _loopback_host(host: str) -> str:
    """`host` as an IPv4 loopback address, or ConfigError (a ValueError)."""
    address = "127.0.0.1" if host == "localhost" else host
    try:
        ip = ipaddress.ip_address(address)
        ok = ip.version == 4 and ip.is_loopback
    except ValueError:
        ok = False
    if not ok:
        raise ConfigError(
            "SocketcandServer", "host",
            f"{host!r} is not an IPv4 loopback address; the simulated bus serves 127.0.0.0/8 only",
        )  # fmt: skip
    return address
