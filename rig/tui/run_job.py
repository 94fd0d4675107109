"""One run, driven from a Textual thread worker; the UI reads the newest status on a timer.

`execute()` (the worker) gets the configuration (starting `sim serve` on the
first run), starts the run in its own process (rig.tui.run_process) and relays
what comes back: the newest LiveStatus is only *stored* (an atomic reference
swap), progress lines go into a bounded deque, so a slow or failing display can
never back up the run. `stop()` is the e-stop, from any thread, at any moment:
before the run process exists it is remembered and sent the instant it does.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from typing import TypeVar

from rig.run.runner import RunResult
from rig.run.status import LiveStatus
from rig.tui.choice import ProfileChoice
from rig.tui.run_process import RunProcess
from rig.tui.session import BenchSession

T = TypeVar("T")


class LiveJob:
    """Run `choice` on `session` once: `execute()` on a worker thread, `stop()` from any."""

    def __init__(self, session: BenchSession, choice: ProfileChoice,
                 spawn: Callable[[Callable[[], T]], T] | None = None) -> None:
        if not choice.ok or choice.profile is None:
            raise ValueError(f"profile {choice.spec} cannot run: {choice.refused or choice.error}")
        self.session, self.choice = session, choice
        self._spawn = spawn or (lambda fn: fn())  # where processes start (rig.tui.priority)
        self.latest: LiveStatus | None = None
        self.statuses = 0  # statuses received (the UI redraws when this changes)
        self.messages: deque[str] = deque(maxlen=50)
        self.result: RunResult | None = None
        self.error = ""
        self.stopped_at: float | None = None  # monotonic time of the e-stop
        self.done = threading.Event()
        self._proc: RunProcess | None = None
        self._lock = threading.Lock()

    @property
    def running(self) -> bool:
        return not self.done.is_set()

    def execute(self) -> RunResult | None:
        """The run (worker thread); a failure is kept in `error`, never raised."""
        try:
            self._execute()
        except Exception as exc:  # noqa: BLE001 - shown to the operator
            self.error = f"{type(exc).__name__}: {exc}".splitlines()[0]
        finally:
            self.done.set()
        return self.result

    def _execute(self) -> None:
        config = self._spawn(lambda: self.session.live_config(self.messages.append))
        profile = self.choice.profile
        assert profile is not None  # checked in __init__
        with self._lock:
            if self.stopped_at is not None:  # e-stopped while the sim started: nothing moved
                self.error = "emergency stop by the operator before the run started"
                return
            self._proc = self._spawn(lambda: RunProcess(config, profile, self.choice.text,
                                                        self.session.out_dir))
        for kind, payload in self._proc.messages():
            if kind == "status":
                self.latest = payload  # type: ignore[assignment]
                self.statuses += 1
            elif kind == "progress":
                self.messages.append(str(payload))
            elif kind == "result":
                self.result = payload  # type: ignore[assignment]
            elif kind == "error":
                self.error = str(payload)
        code = self._proc.join()
        if self.result is None and not self.error:
            self.error = (f"the run process ended with exit code {code} and no result: "
                          f"{self._proc.stderr_tail or 'no message'}")

    def stop(self) -> None:
        """The e-stop: thread-safe, idempotent; the runner aborts into the safe state."""
        with self._lock:
            if self.stopped_at is None:
                self.stopped_at = time.monotonic()
            proc = self._proc
        if proc is not None:
            proc.stop()
