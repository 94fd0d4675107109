"""`sim serve` for a TUI session, started from a small process in a session of its own.

Why not `rig.run.sim_process.SimProcess` straight from the TUI: Linux groups processes
by session for CPU fairness (autogroup, on here), so a `sim serve` started by
the TUI shares one group's CPU share with the display. Measured on the two
shared cores: at a 12 Hz display, run A aborted (actuators' WATCHDOG_HOLD) in
most tries; with the same sim in its own session, or the display at 2 Hz, every
run passed. `SimProcess` cannot be asked for a new session (rig/run/sim_process.py is
not the TUI's), so this host process, in its own session, owns one: the sim
gets the host's (idle) group. The host stops the sim on "stop" or when the
TUI's end of the pipe closes (the TUI gone); the sim stops if the host dies.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from multiprocessing.connection import Connection

from rig.config import RigConfig
from rig.errors import RigError
from rig.tui.child import spawn_child
from rig.tui.run_process import from_wire, to_wire

STOP = "stop"
STOP_WAIT_S = 20.0  # the host's SimProcess.stop waits up to 10 s for the sim


class SimHost:
    """`sim serve` running for the session; `config` points at it; `stop()` ends both."""

    def __init__(self, config: RigConfig, sim_args: tuple[str, ...] = ()) -> None:
        self._stderr = tempfile.TemporaryFile()  # noqa: SIM115 - closed in stop()
        try:
            self._proc, self._conn = spawn_child("rig.tui.sim_host", self._stderr)
        except BaseException:
            self._stderr.close()
            raise
        try:
            self._conn.send((to_wire(config), sim_args))
            kind, payload = self._conn.recv()
        except (EOFError, OSError):
            kind, payload = "error", "the sim host ended before the sim was ready"
        if kind != "ready":
            self.stop()
            raise RigError(str(payload))
        wire, self.pid = payload
        self.config: RigConfig = from_wire(wire)

    def stop(self) -> None:
        """Stop the sim and its host; idempotent."""
        try:
            self._conn.send(STOP)
        except (OSError, ValueError):
            pass
        try:
            self._proc.wait(STOP_WAIT_S)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        self._conn.close()
        self._stderr.close()


def main(fd: int) -> None:
    from rig.run.sim_process import SimProcess

    conn = Connection(fd)
    wire, sim_args = conn.recv()
    try:
        sim = SimProcess(from_wire(wire), extra_args=sim_args)
    except (RigError, OSError) as exc:
        conn.send(("error", str(exc)))
        return
    try:
        conn.send(("ready", (to_wire(sim.config), sim.pid)))
        while conn.recv() != STOP:
            pass
    except (EOFError, OSError):
        pass  # the TUI is gone: stop the sim
    finally:
        sim.stop()


if __name__ == "__main__":
    main(int(sys.argv[1]))
