"""What a display sees of a run while it happens, and how an operator stops it.

The runner owns the run; a display (the TUI, a test) only *listens*. Listeners
get a `LiveStatus` a few times a second on the runner's thread and must return
quickly; one that raises is dropped with a warning and the run goes on —
a failing display never stops logging (design: display listeners are
non-critical). `RunControl.stop` is the emergency stop: any thread may set it,
and the runner aborts into the safe state at its next look (every few ms).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

log = logging.getLogger(__name__)

LIVE_RATE_HZ = 20.0  # statuses per second handed to listeners
TRACE_S = 6.0  # s of recent sensor samples a status carries
TRACE_POINTS = 600  # at most this many points per trace (decimated): a terminal plot's width
TRACE_BUFFER = 8192  # samples kept per trace: TRACE_S at 1 kHz with room


@dataclass(frozen=True)
class ActuatorLive:
    """One actuator as last heard: positions in m, error in m, status as the CAN enum name."""

    index: int
    setpoint: float = float("nan")
    feedback: float = float("nan")
    following_error: float = float("nan")
    status: str = "?"
    faults: int = 0


@dataclass(frozen=True)
class LiveStatus:
    """A snapshot: run time (s, from START; negative before), phase, traces and health.

    Traces are (t, value) arrays in s and m on arrival time, so they lag the file's
    clock-fitted samples by the sensor latency: fine for eyes, not for analysis.
    """

    phase: str  # "baseline", "running", "settling", "ended"
    elapsed: float
    duration: float
    table_u: tuple[np.ndarray, np.ndarray]
    mass_x: tuple[np.ndarray, np.ndarray]
    actuators: tuple[ActuatorLive, ...]
    frames: dict[str, int]
    lost: dict[str, int]
    crc_errors: int
    frames_per_s: float
    status: str = ""  # "success" / "abort" / "fail" once ended
    reason: str = ""

    @property
    def relative_z(self) -> tuple[np.ndarray, np.ndarray]:
        """z = x − u on the mass trace's times (the table interpolated)."""
        t, x = self.mass_x
        tu, u = self.table_u
        if len(t) == 0 or len(tu) < 2:
            return np.empty(0), np.empty(0)
        return t, x - np.interp(t, tu, u)


@dataclass
class RunControl:
    """Handed to `run_profile`: the e-stop flag and the listeners."""

    stop: threading.Event = field(default_factory=threading.Event)
    listeners: list[Callable[[LiveStatus], None]] = field(default_factory=list)
    rate_hz: float = LIVE_RATE_HZ

    def emergency_stop(self) -> None:
        """Any thread: abort the run into the safe state at the runner's next look."""
        self.stop.set()

    def publish(self, status: LiveStatus) -> None:
        for listener in list(self.listeners):
            try:
                listener(status)
            except Exception:  # noqa: BLE001 - a display fault must not stop a run
                log.warning("live listener %r failed and was removed", listener, exc_info=True)
                self.listeners.remove(listener)


class Trace:
    """A bounded buffer of (t, value) for one live signal; append is O(1)."""

    def __init__(self, maxlen: int = TRACE_BUFFER) -> None:
        self._t: deque[float] = deque(maxlen=maxlen)
        self._v: deque[float] = deque(maxlen=maxlen)

    def append(self, t: float, v: float) -> None:
        self._t.append(t)
        self._v.append(v)

    def recent(self, now: float, span: float = TRACE_S, points: int = TRACE_POINTS
               ) -> tuple[np.ndarray, np.ndarray]:
        t = np.fromiter(self._t, float, len(self._t))
        v = np.fromiter(self._v, float, len(self._v))
        keep = t >= now - span
        t, v = t[keep], v[keep]
        step = max(1, -(-len(t) // points))
        return t[::step], v[::step]


@dataclass
class Publisher:
    """Rate-limits statuses to `control.rate_hz`; `due()` is cheap enough to call per loop."""

    control: RunControl | None
    _next: float = 0.0
    _frames_then: int = 0
    _t_then: float = field(default_factory=time.monotonic)

    def due(self) -> bool:
        return bool(self.control and self.control.listeners) and time.monotonic() >= self._next

    def sent(self, frames: int) -> float:
        """Mark a status sent; returns frames per second since the last one."""
        now = time.monotonic()
        rate = (frames - self._frames_then) / max(now - self._t_then, 1e-6)
        self._frames_then, self._t_then = frames, now
        self._next = now + 1.0 / self.control.rate_hz if self.control else now
        return rate
