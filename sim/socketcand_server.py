"""The simulated CAN bus: a socketcand rawmode server on loopback, with fault injection.

python-can's stock client, `can.Bus(interface="socketcand", host=..., port=...,
channel="can0")`, connects to it exactly as to a real socketcand daemon:

    server: < hi >          client: < open can0 >    server: < ok >
    client: < rawmode >     server: < ok >
    client: < send 123 2 a 1 >  ->  others: < frame 123 1700000000.000123 0A01 >

One selector thread does all socket work, so no lock guards the clients and a
slow reader cannot stall the others: every client has its own output buffer
and non-blocking socket. The thread stamps each frame once, with `clock`, when
the frame reaches the bus; every receiver sees that stamp. In-process devices
(`attach`) see the same frames through `on_frame` and talk with `broadcast`.

Deviations from the real daemon, each because of the python-can client:
- After `< rawmode >` the `< ok >` is sent alone and frames for that client wait
  until it sends a command or `handshake_grace_s` passes: the client compares
  the whole of one `recv` with "< ok >", so a frame glued to it would fail the
  handshake.
- Unknown raw-mode commands are counted, not answered: the client would try
  to parse `< error unknown command >` as an error frame and raise.
- Closing a client (bus-off, shutdown) resets the connection: on a clean EOF the
  client's recv returns None forever without raising, so nobody would notice.
"""

from __future__ import annotations

import ipaddress
import logging
import random
import selectors
import socket
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Protocol

import can

from rig.errors import ConfigError

log = logging.getLogger(__name__)

CAN_ERR_PROT = 0x008  # SocketCAN error class: protocol violation (linux/can/error.h)
CAN_ERR_BUSOFF = 0x040  # SocketCAN error class: bus off
_MAX_COMMAND = 256  # bytes; a longer unterminated command is garbage
_RESET = struct.pack("ii", 1, 0)  # SO_LINGER on, 0 s: close() sends RST
_REORDER_HOLD_S = 0.005  # a held-back frame goes out alone if nothing follows it this soon


class CanDevice(Protocol):
    """A node simulated inside the server process."""

    def on_frame(self, msg: can.Message) -> None:
        """Called on the server thread for every frame on the bus not sent by this device."""


@dataclass(frozen=True)
class BusFaults:
    """Faults applied to every frame reaching the bus, clients' and devices' alike.

    One uniform draw u per frame, in arrival order, from Random(seed):
    u < drop_prob drops it; then the next duplicate_prob duplicates it; then the
    next reorder_prob holds it back until after the following frame.
    error_burst_after / disconnect_after: frames after these faults take effect
    before a burst of error_burst_len error frames (class error_class) /
    before every client is disconnected (bus-off). None: never.
    """

    drop_prob: float = 0.0
    duplicate_prob: float = 0.0
    reorder_prob: float = 0.0
    seed: int = 0
    error_burst_after: int | None = None
    error_burst_len: int = 10
    error_class: int = CAN_ERR_PROT
    disconnect_after: int | None = None


@dataclass
class RelayStats:
    """Counters since start. frames_in: frames offered by clients and devices.
    frames_relayed: frames put on the bus (a duplicate counts twice).
    clients_disconnected: by bus-off or because their output buffer overflowed."""

    frames_in: int = 0
    frames_relayed: int = 0
    frames_dropped: int = 0  # by drop_prob or while the bus was stalled
    frames_duplicated: int = 0
    frames_reordered: int = 0
    error_frames: int = 0
    clients_disconnected: int = 0
    bad_commands: int = 0
    device_errors: int = 0


@dataclass
class _FaultState:
    faults: BusFaults
    rng: random.Random = field(init=False)
    frames_seen: int = 0

    def __post_init__(self) -> None:
        self.rng = random.Random(self.faults.seed)


@dataclass(eq=False)
class _Client:
    sock: socket.socket
    state: str = "nobus"  # -> "bcm" after open -> "raw" after rawmode
    inbuf: bytearray = field(default_factory=bytearray)
    outbuf: bytearray = field(default_factory=bytearray)
    hold_until: float = 0.0  # monotonic s; frames wait while the handshake may be read
    writing: bool = False  # registered for EVENT_WRITE


_Frame = tuple[int, bool, bytes, object]  # can_id, is_extended_id, data, origin


class SocketcandServer:
    """A socketcand rawmode bus on `host`:`port` (loopback only), serving from construction.

    port=0 picks a free port; read it from `.port`. clock: s, stamps frames
    (wall clock, as the real daemon). handshake_grace_s: see module doc.
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
        self._grace = handshake_grace_s
        self._max_buffer = max_client_buffer
        self._fault_state = _FaultState(faults or BusFaults())
        self._stats = RelayStats()
        self._clients: list[_Client] = []
        self._devices: tuple[CanDevice, ...] = ()
        self._inbox: deque[Callable[[], None]] = deque()
        self._held: _Frame | None = None
        self._held_until = 0.0  # monotonic s
        self._stalled_until = 0.0  # monotonic s: no frame reaches the bus before then
        self._stopping = False
        self._closed = False
        self._close_lock = threading.Lock()
        self._sel = selectors.DefaultSelector()
        self._listener = socket.create_server((self.host, port), backlog=16)
        self._listener.setblocking(False)
        self.port: int = self._listener.getsockname()[1]
        self._wake_r, self._wake_w = socket.socketpair()
        for sock in (self._wake_r, self._wake_w):
            sock.setblocking(False)
        self._sel.register(self._listener, selectors.EVENT_READ, self._accept)
        self._sel.register(self._wake_r, selectors.EVENT_READ, self._drain_wake)
        self._thread = threading.Thread(
            target=self._run, name=f"socketcand-server:{self.port}", daemon=True
        )
        self._thread.start()

    # ---- public, callable from any thread ------------------------------------

    @property
    def faults(self) -> BusFaults:
        """The faults in effect; assigning new ones reseeds the RNG and restarts the triggers."""
        return self._fault_state.faults

    @faults.setter
    def faults(self, faults: BusFaults) -> None:
        self._fault_state = _FaultState(faults)  # one reference swap: no lock needed

    @property
    def stats(self) -> RelayStats:
        """A snapshot of the counters."""
        return replace(self._stats)

    @property
    def client_count(self) -> int:
        """Clients that finished the handshake and are in raw mode."""
        return sum(c.state == "raw" for c in list(self._clients))

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
        self._stalled_until = time.monotonic() + seconds

    def disconnect_clients(self) -> None:
        """Bus-off: reset every client connection; clients see a CanError on recv."""
        self._call_soon(self._disconnect_all)

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
                if self._held is not None and time.monotonic() >= self._held_until:
                    self._release_held()
                self._flush_all()
        except Exception:
            log.exception("socketcand server on port %d failed", self.port)
        finally:
            self._close_all()

    def _select_timeout(self) -> float | None:
        now = time.monotonic()
        waits = [c.hold_until - now for c in self._clients if c.outbuf and c.hold_until > now]
        if self._held is not None:
            waits.append(self._held_until - now)
        return max(0.0, min(waits)) if waits else None

    def _accept(self, listener: socket.socket, mask: int) -> None:
        try:
            sock, _ = listener.accept()
        except BlockingIOError:
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        client = _Client(sock)
        self._clients.append(client)
        self._sel.register(sock, selectors.EVENT_READ, lambda s, m: self._on_client(client, m))
        self._reply(client, b"< hi >")

    def _drain_wake(self, sock: socket.socket, mask: int) -> None:
        try:
            while sock.recv(4096):
                pass
        except BlockingIOError:
            pass

    def _on_client(self, client: _Client, mask: int) -> None:
        if mask & selectors.EVENT_READ:
            try:
                data = client.sock.recv(65536)
            except BlockingIOError:
                return
            except OSError:
                data = b""
            if not data:
                self._close_client(client, reset=False)
                return
            _quickack(client.sock)  # as socketcand: the client does not set TCP_NODELAY
            client.inbuf += data
            self._parse_commands(client)

    def _parse_commands(self, client: _Client) -> None:
        buf = client.inbuf
        while client.state != "closed":
            end = buf.find(b">")
            if end < 0:
                if len(buf) > _MAX_COMMAND:
                    self._stats.bad_commands += 1
                    buf.clear()
                return
            start = buf.rfind(b"<", 0, end)
            tokens = bytes(buf[start + 1 : end]).split() if start >= 0 else []
            del buf[: end + 1]
            self._command(client, tokens)

    def _command(self, client: _Client, tokens: list[bytes]) -> None:
        verb = tokens[0] if tokens else b""
        if client.state == "raw" and verb == b"send":
            client.hold_until = 0.0  # it sent after reading "< ok >": the handshake is over
            frame = _parse_send(tokens, client)
            if frame is None:
                self._stats.bad_commands += 1
            else:
                self._offer(frame)
        elif client.state == "nobus" and verb == b"open" and len(tokens) == 2:
            if tokens[1].decode("ascii", "replace") == self.bus_name:
                client.state = "bcm"
                self._reply(client, b"< ok >")
            else:
                self._reply(client, b"< error could not open bus >")
                self._close_client(client, reset=False)
        elif client.state == "bcm" and verb == b"rawmode":
            client.state = "raw"
            client.hold_until = time.monotonic() + self._grace
            self._reply(client, b"< ok >")
        else:
            self._stats.bad_commands += 1
            log.debug("ignored command %r in state %s", tokens, client.state)

    def _reply(self, client: _Client, reply: bytes) -> None:
        # handshake replies go out alone: the client compares each single recv
        try:
            client.sock.send(reply)
        except OSError:
            self._close_client(client, reset=False)

    def _offer(self, frame: _Frame) -> None:
        """A frame reaches the bus: count it, apply the faults, deliver what is left."""
        fs = self._fault_state
        f = fs.faults
        self._stats.frames_in += 1
        fs.frames_seen += 1
        u = fs.rng.random()
        if u < f.drop_prob or self._stalled_until > time.monotonic():
            self._stats.frames_dropped += 1
        elif u < f.drop_prob + f.duplicate_prob:
            self._stats.frames_duplicated += 1
            self._deliver(frame)
            self._deliver(frame)
        elif u < f.drop_prob + f.duplicate_prob + f.reorder_prob and self._held is None:
            self._held = frame
            self._held_until = time.monotonic() + _REORDER_HOLD_S
        else:
            self._deliver(frame)
            if self._held is not None:
                self._stats.frames_reordered += 1
                self._release_held()
        self._fire_triggers(fs)

    def _fire_triggers(self, fs: _FaultState) -> None:
        f = fs.faults
        if fs.frames_seen == f.error_burst_after:
            self._error_burst(f.error_burst_len, f.error_class)
        if fs.frames_seen == f.disconnect_after:
            self._disconnect_all()

    def _release_held(self) -> None:
        frame, self._held = self._held, None
        if frame is not None:
            self._deliver(frame)

    def _deliver(self, frame: _Frame) -> None:
        can_id, is_ext, data, origin = frame
        now = self._clock()
        self._stats.frames_relayed += 1
        ident = f"{can_id:08X}" if is_ext else f"{can_id:03X}"
        line = f"< frame {ident} {_stamp(now)} {data.hex().upper()} >".encode("ascii")
        for client in self._clients:
            if client.state == "raw" and client is not origin:
                client.outbuf += line
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
            line = f"< error {error_class:03X} {_stamp(self._clock())} >".encode("ascii")
            for client in self._clients:
                if client.state == "raw":
                    client.outbuf += line
            self._stats.error_frames += 1

    def _disconnect_all(self) -> None:
        for client in list(self._clients):
            self._stats.clients_disconnected += 1
            self._close_client(client, reset=True)

    def _flush_all(self) -> None:
        now = time.monotonic()
        for client in list(self._clients):
            if not client.outbuf or client.hold_until > now:
                continue
            try:
                sent = client.sock.send(client.outbuf)
            except BlockingIOError:
                sent = 0
            except OSError:
                self._close_client(client, reset=False)
                continue
            del client.outbuf[:sent]
            if len(client.outbuf) > self._max_buffer:
                log.warning("client output exceeds %d bytes: disconnected", self._max_buffer)
                self._stats.clients_disconnected += 1
                self._close_client(client, reset=True)
                continue
            if client.writing != bool(client.outbuf):  # wake on writability only while behind
                client.writing = bool(client.outbuf)
                events = selectors.EVENT_READ | (selectors.EVENT_WRITE if client.writing else 0)
                self._sel.modify(client.sock, events, self._sel.get_key(client.sock).data)

    def _close_client(self, client: _Client, reset: bool) -> None:
        if client.state == "closed":
            return
        client.state = "closed"
        self._clients.remove(client)
        self._sel.unregister(client.sock)
        if reset:
            try:
                client.sock.send(client.outbuf)  # best effort: what was on the bus arrives
                client.sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, _RESET)
            except OSError:
                pass
        client.sock.close()

    def _close_all(self) -> None:
        self._stopping = True
        self._inbox.clear()
        for client in list(self._clients):
            self._close_client(client, reset=True)
        for sock in (self._listener, self._wake_r):
            self._sel.unregister(sock)
            sock.close()
        self._sel.close()
        self._wake_w.close()  # a late _wake() from another thread gets OSError, ignored


def _parse_send(tokens: list[bytes], client: _Client) -> _Frame | None:
    """`send ID LEN B0 B1 ...` (hex) as a frame, or None if malformed; 8 hex digits = extended."""
    try:
        can_id, dlc = int(tokens[1], 16), int(tokens[2], 16)
        data = bytes(int(b, 16) for b in tokens[3:])
    except (IndexError, ValueError):
        return None
    is_ext = len(tokens[1]) == 8
    if dlc > 8 or len(data) != dlc or can_id > (0x1FFFFFFF if is_ext else 0x7FF):
        return None
    return (can_id, is_ext, data, client)


def _stamp(t: float) -> str:
    """socketcand's SEC.USEC."""
    usec = round(t * 1e6)
    return f"{usec // 1_000_000}.{usec % 1_000_000:06d}"


def _quickack(sock: socket.socket) -> None:
    quickack = getattr(socket, "TCP_QUICKACK", None)
    if quickack is not None:
        sock.setsockopt(socket.IPPROTO_TCP, quickack, 1)


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
