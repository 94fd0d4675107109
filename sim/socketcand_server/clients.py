"""The TCP side of the simulated bus: each client's connection, handshake, commands and output.

Served from the server's selector thread only, so no lock guards the clients.
Every client has its own non-blocking socket and output buffer: a slow reader
cannot stall the others.
"""

from __future__ import annotations

import logging
import selectors
import socket
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from sim.socketcand_server.bus_faults import RelayStats
from sim.socketcand_server.protocol import MAX_COMMAND, Frame, parse_send, take_command

log = logging.getLogger(__name__)

_RESET = struct.pack("ii", 1, 0)  # SO_LINGER on, 0 s: close() sends RST


@dataclass(eq=False)
class Client:
    """One connection and where it is in the socketcand handshake."""

    sock: socket.socket
    state: str = "nobus"  # -> "bcm" after open -> "raw" after rawmode
    inbuf: bytearray = field(default_factory=bytearray)
    outbuf: bytearray = field(default_factory=bytearray)
    hold_until: float = 0.0  # monotonic s; frames wait while the handshake may be read
    writing: bool = False  # registered for EVENT_WRITE


class Clients:
    """The clients of one listener: accepted, read and flushed through `sel`.

    bus_name: the one bus `< open >` accepts. grace: s, handshake_grace_s (see
    the package doc). max_buffer: bytes queued for one client before it is
    disconnected. offer: puts a client's frame on the bus.
    """

    def __init__(
        self,
        sel: selectors.BaseSelector,
        stats: RelayStats,
        bus_name: str,
        grace: float,
        max_buffer: int,
        offer: Callable[[Frame], None],
    ) -> None:
        self.all: list[Client] = []
        self._sel = sel
        self._stats = stats
        self._bus_name = bus_name
        self._grace = grace
        self._max_buffer = max_buffer
        self._offer = offer

    def accept(self, listener: socket.socket, mask: int) -> None:
        """Selector callback of the listener: take one connection and greet it."""
        try:
            sock, _ = listener.accept()
        except BlockingIOError:
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        client = Client(sock)
        self.all.append(client)
        self._sel.register(sock, selectors.EVENT_READ, lambda s, m: self._on_client(client, m))
        self._reply(client, b"< hi >")

    def queue(self, line: bytes, origin: object | None = None) -> None:
        """Queue `line` for every client in raw mode except `origin`."""
        for client in self.all:
            if client.state == "raw" and client is not origin:
                client.outbuf += line

    def hold_waits(self, now: float) -> list[float]:
        """Seconds until each client holding output (during its handshake) may be sent to."""
        return [c.hold_until - now for c in self.all if c.outbuf and c.hold_until > now]

    def _on_client(self, client: Client, mask: int) -> None:
        if mask & selectors.EVENT_READ:
            try:
                data = client.sock.recv(65536)
            except BlockingIOError:
                return
            except OSError:
                data = b""
            if not data:
                self.close(client, reset=False)
                return
            _quickack(client.sock)  # as socketcand: the client does not set TCP_NODELAY
            client.inbuf += data
            self._parse_commands(client)

    def _parse_commands(self, client: Client) -> None:
        buf = client.inbuf
        while client.state != "closed":
            tokens = take_command(buf)
            if tokens is None:
                if len(buf) > MAX_COMMAND:
                    self._stats.bad_commands += 1
                    buf.clear()
                return
            self._command(client, tokens)

    def _command(self, client: Client, tokens: list[bytes]) -> None:
        verb = tokens[0] if tokens else b""
        if client.state == "raw" and verb == b"send":
            client.hold_until = 0.0  # it sent after reading "< ok >": the handshake is over
            frame = parse_send(tokens, client)
            if frame is None:
                self._stats.bad_commands += 1
            else:
                self._offer(frame)
        elif client.state == "nobus" and verb == b"open" and len(tokens) == 2:
            if tokens[1].decode("ascii", "replace") == self._bus_name:
                client.state = "bcm"
                self._reply(client, b"< ok >")
            else:
                self._reply(client, b"< error could not open bus >")
                self.close(client, reset=False)
        elif client.state == "bcm" and verb == b"rawmode":
            client.state = "raw"
            client.hold_until = time.monotonic() + self._grace
            self._reply(client, b"< ok >")
        else:
            self._stats.bad_commands += 1
            log.debug("ignored command %r in state %s", tokens, client.state)

    def _reply(self, client: Client, reply: bytes) -> None:
        # handshake replies go out alone: the client compares each single recv
        try:
            client.sock.send(reply)
        except OSError:
            self.close(client, reset=False)

    def flush(self) -> None:
        """Send what each client's socket takes, except to clients still in their handshake."""
        now = time.monotonic()
        for client in list(self.all):
            if not client.outbuf or client.hold_until > now:
                continue
            try:
                sent = client.sock.send(client.outbuf)
            except BlockingIOError:
                sent = 0
            except OSError:
                self.close(client, reset=False)
                continue
            del client.outbuf[:sent]
            if len(client.outbuf) > self._max_buffer:
                log.warning("client output exceeds %d bytes: disconnected", self._max_buffer)
                self._stats.clients_disconnected += 1
                self.close(client, reset=True)
                continue
            if client.writing != bool(client.outbuf):  # wake on writability only while behind
                client.writing = bool(client.outbuf)
                events = selectors.EVENT_READ | (selectors.EVENT_WRITE if client.writing else 0)
                self._sel.modify(client.sock, events, self._sel.get_key(client.sock).data)

    def disconnect_all(self) -> None:
        """Bus-off: reset every client, counting each as disconnected."""
        for client in list(self.all):
            self._stats.clients_disconnected += 1
            self.close(client, reset=True)

    def close_all(self) -> None:
        """Reset every client (shutdown)."""
        for client in list(self.all):
            self.close(client, reset=True)

    def close(self, client: Client, reset: bool) -> None:
        """Close `client` once; reset: send what is queued, then RST instead of FIN."""
        if client.state == "closed":
            return
        client.state = "closed"
        self.all.remove(client)
        self._sel.unregister(client.sock)
        if reset:
            try:
                client.sock.send(client.outbuf)  # best effort: what was on the bus arrives
                client.sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, _RESET)
            except OSError:
                pass
        client.sock.close()


def _quickack(sock: socket.socket) -> None:
    quickack = getattr(socket, "TCP_QUICKACK", None)
    if quickack is not None:
        sock.setsockopt(socket.IPPROTO_TCP, quickack, 1)
