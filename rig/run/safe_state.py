"""SAFE_STATE at the end of every run, even when the run's own bus has died.

The runner's `finally` calls `send_safe_state` first, before anything else is
closed. Commands go out COMMAND_REPEATS times: the nodes obey a repeated command
as a no-op, and a single frame lost on the bus must not leave the table moving.
If the run's connection is dead (bus-off, a reset connection), one fresh
connection is tried; python-can's socketcand client would retry a refused
connection for 10 s and wait for the greeting with no timeout, so the daemon is
probed first with a short timeout. If nothing gets through, the actuators' own
index watchdog holds them once the setpoints they need are 0.1 s late
(sim.devices; docs/reliability.md).
"""

from __future__ import annotations

import logging
import socket

import can

from rig.config import RigConfig
from rig.errors import RigError
from rig.run.receive import open_bus
from rig.run.schedule import safe_state
from rig.wire import can_messages as cm

log = logging.getLogger(__name__)

COMMAND_REPEATS = 3  # copies of each command frame: at 5 % frame loss, 1.25e-4 lose all three
RECONNECT_TIMEOUT_S = 0.3  # s to reach the bus again once the run's bus died


def send_safe_state(bus: can.BusABC, config: RigConfig, bus_dead: bool = False) -> bool:
    """SAFE_STATE to every node, over a fresh connection if the run's bus is dead.

    bus_dead: the run's connection is known to have failed (a send into a reset
    socket may still "succeed" into the kernel's buffer), so go straight to a new one.
    Best effort: True if it went out. If it cannot, the actuators' own index
    watchdog holds them once the setpoints they need are 0.1 s late.
    """
    frame = cm.to_can(safe_state())
    if not bus_dead:
        try:
            _send_repeated(bus, frame)
            return True
        except (can.CanError, OSError, ValueError) as exc:
            log.warning("could not send SAFE_STATE on the run's bus: %s", one_line(exc))
    try:
        fresh = _reconnect(config)
    except (can.CanError, OSError, ValueError, RigError) as exc:
        log.warning("could not reach the bus again for SAFE_STATE: %s", one_line(exc))
        return False
    try:
        _send_repeated(fresh, frame)
        return True
    except (can.CanError, OSError, ValueError) as exc:
        log.warning("could not send SAFE_STATE on a fresh connection: %s", one_line(exc))
        return False
    finally:
        fresh.shutdown()


def _reconnect(config: RigConfig) -> can.BusABC:
    """A new connection to the configured bus, refused quickly if nobody answers.

    python-can's socketcand client retries a refused connection for 10 s and waits
    for the greeting without a timeout, so the daemon is probed first.
    """
    if config.can.interface == "socketcand":
        host, port = config.can.extra["host"], int(config.can.extra["port"])
        with socket.create_connection((host, port), timeout=RECONNECT_TIMEOUT_S) as probe:
            if not probe.recv(16).startswith(b"< hi >"):
                raise RigError(f"{host}:{port} does not greet as socketcand")
    return open_bus(config)


def one_line(exc: BaseException, limit: int = 200) -> str:
    """An exception's message on one line (python-can embeds a traceback in some)."""
    text = " ".join(str(exc).split("Traceback")[0].split()) or type(exc).__name__
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _send_repeated(bus: can.BusABC, frame: can.Message) -> None:
    """COMMAND_REPEATS copies: a frame lost on a faulty bus must not leave a node moving."""
    for _ in range(COMMAND_REPEATS):
        bus.send(frame)
