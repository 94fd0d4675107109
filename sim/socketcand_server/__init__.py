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

Modules: `protocol` (the ASCII codec), `clients` (connections, handshake,
commands, output buffers), `bus_faults` (the faults, counters and the relay that
applies them), `server` (`SocketcandServer`: the thread and the public calls).
"""

from __future__ import annotations

from sim.socketcand_server.bus_faults import BusFaults, RelayStats
from sim.socketcand_server.protocol import CAN_ERR_BUSOFF, CAN_ERR_PROT
from sim.socketcand_server.server import CanDevice, SocketcandServer

__all__ = [
    "CAN_ERR_BUSOFF", "CAN_ERR_PROT", "BusFaults", "CanDevice", "RelayStats", "SocketcandServer",
]
