"""A run in its own process, talking to the TUI over a pipe.

Why not a thread of the TUI process (design.md §4.13 suggests one): measured here,
the display's Python work and its garbage collector (gen-2 collections of
Textual's many small objects took 90–120 ms, holding every thread) starved the
runner in the same interpreter; `rig tui` aborted run A twice with the
actuators' WATCHDOG_HOLD while `rig run` passed. In a process of its own the
runner keeps its own GIL and heap, exactly as `rig run` has them.

Child (this module, no Textual): `run_profile(..., control=RunControl())`; its
listener keeps the newest LiveStatus, a sender thread ships it (and progress
lines, then the RunResult) so a slow reader never blocks the runner; a command
thread turns "estop" into `control.emergency_stop()`, and so does the pipe's end
(the TUI gone): nobody may be left without an e-stop while the table moves.
"""

from __future__ import annotations

import queue
import subprocess
import sys
import tempfile
import threading
from collections.abc import Iterator
from dataclasses import replace
from multiprocessing.connection import Connection
from pathlib import Path
from types import MappingProxyType

from rig.config import RigConfig
from rig.profile import Profile
from rig.run.status import LiveStatus, RunControl
from rig.tui.child import spawn_child

ESTOP = "estop"
JOIN_S = 30.0  # the child ends within ms of the run; a sim start is not done here


class RunProcess:
    """Start the child; `messages()` yields (kind, payload) until it exits; `stop()` e-stops.

    kinds: "status" (LiveStatus), "progress" (str), "result" (RunResult), "error" (str).
    The child is `python -m rig.tui.run_process FD` in a session of its own (a Ctrl-C in
    the terminal is the TUI's to handle), its stderr kept in a file for the error message.
    """

    def __init__(self, config: RigConfig, profile: Profile, text: str, out_dir: Path) -> None:
        self._lock = threading.Lock()
        self._stderr = tempfile.TemporaryFile()  # noqa: SIM115 - closed in join()
        self.stderr_tail = ""  # the child's last stderr line, once joined
        try:
            self._proc, self._conn = spawn_child("rig.tui.run_process", self._stderr)
        except BaseException:
            self._stderr.close()
            raise
        self._conn.send((to_wire(config), profile, text, str(out_dir)))

    @property
    def pid(self) -> int:
        return self._proc.pid

    def messages(self) -> Iterator[tuple[str, object]]:
        while True:
            try:
                yield self._conn.recv()
            except (EOFError, OSError):
                return

    def stop(self) -> None:
        """E-stop: any thread; a closed pipe means the run has already ended."""
        with self._lock:
            try:
                self._conn.send(ESTOP)
            except (OSError, ValueError):
                pass

    def join(self) -> int:
        """Wait for the child (JOIN_S at most, then kill it); its exit code."""
        try:
            code = self._proc.wait(JOIN_S)
        except subprocess.TimeoutExpired:  # never seen; do not leave a runner behind
            self._proc.kill()
            code = self._proc.wait()
        with self._lock:
            self._conn.close()
        self._stderr.seek(0)
        lines = self._stderr.read().decode(errors="replace").strip().splitlines()
        self._stderr.close()
        self.stderr_tail = lines[-1] if lines else ""
        return code


def to_wire(config: RigConfig) -> RigConfig:
    """`config` picklable: its can.extra a dict (a mappingproxy does not pickle)."""
    return replace(config, can=replace(config.can, extra=dict(config.can.extra)))


def from_wire(config: RigConfig) -> RigConfig:
    return replace(config, can=replace(config.can, extra=MappingProxyType(config.can.extra)))


def main(fd: int) -> None:
    """The child: read the run's arguments from the TUI, run it, report back."""
    conn = Connection(fd)
    config, profile, text, out_dir = conn.recv()
    _child(config, profile, text, out_dir, conn)
    conn.close()


def _child(config: RigConfig, profile: Profile, text: str, out_dir: str,
           conn: Connection) -> None:
    from rig.run.runner import run_profile  # only the child needs the runner

    config = from_wire(config)
    control = RunControl()
    outbox = _Outbox(conn, control)
    control.listeners.append(outbox.status)
    threading.Thread(target=_commands, args=(conn, control), daemon=True,
                     name="estop").start()
    try:
        result = run_profile(config, profile, text, Path(out_dir), confirm=lambda: True,
                             progress=outbox.progress, start_sim=False, control=control)
        outbox.put(("result", result))
    except BaseException as exc:  # noqa: BLE001 - reported to the TUI; the runner ended safe
        outbox.put(("error", f"{type(exc).__name__}: {exc}".splitlines()[0]))
    finally:
        outbox.close()


def _commands(conn: Connection, control: RunControl) -> None:
    """E-stop on "estop", and when the TUI's end of the pipe closes."""
    try:
        while conn.recv() != ESTOP:
            pass
    except (EOFError, OSError):
        pass
    control.emergency_stop()


class _Outbox:
    """What the runner hands over, shipped by one sender thread; the runner never blocks."""

    def __init__(self, conn: Connection, control: RunControl) -> None:
        self._conn, self._control = conn, control
        self._queue: queue.SimpleQueue[tuple[str, object] | None] = queue.SimpleQueue()
        self._latest: LiveStatus | None = None
        self._wake = threading.Event()
        self._thread = threading.Thread(target=self._send, daemon=True, name="live sender")
        self._thread.start()

    def status(self, status: LiveStatus) -> None:  # the runner's listener: O(1)
        self._latest = status
        self._wake.set()

    def progress(self, text: str) -> None:
        self.put(("progress", text))

    def put(self, message: tuple[str, object] | None) -> None:
        self._queue.put(message)
        self._wake.set()

    def close(self) -> None:
        self.put(None)
        self._thread.join()

    def _send(self) -> None:
        while True:
            self._wake.wait()
            self._wake.clear()
            latest, self._latest = self._latest, None
            try:
                if latest is not None:
                    self._conn.send(("status", latest))
                while not self._queue.empty():
                    message = self._queue.get()
                    if message is None:  # the end: the last status too, if it came late
                        if self._latest is not None:
                            self._conn.send(("status", self._latest))
                        return
                    self._conn.send(message)
            except (OSError, ValueError):  # the TUI is gone: nobody can see or stop this run
                self._control.emergency_stop()
                return


if __name__ == "__main__":
    main(int(sys.argv[1]))
