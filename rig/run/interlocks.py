"""The run's interlocks: which received frames mean the run must stop, and why.

Pure bookkeeping on the runner's thread (no I/O, no clock of its own): the
recorder feeds it what arrived, with run times (s since the writer started),
and `check` returns the first broken rule as one line, or None.

**Following error by servo tick.** Each ActuatorFeedback carries in `Sequence`
the servo tick of its measurement: while the actuator is RUNNING, the index of
the setpoint it was playing (sim.devices; the actuators play sample i at
START + i / rate). So a feedback is compared with exactly the setpoints it was
following, whatever its delivery latency: a frame delayed 0.3 s in a stalled
receive path is still judged against the setpoint of its own instant, and a
stuck valve shows as soon as the setpoints have moved `FOLLOWING_LIMIT_M` away
from it. The only allowance is the servo's own lag, `SERVO_LAG_S` of setpoints.
(Before, feedback was judged by arrival time against a 0.25 s window of
setpoints, wide enough for the delivery stalls of a loaded machine and so slow
to catch a stuck valve.)

**Liveness on each stream's horizon.** A source is silent when nothing of it
arrived for longer than its limit *up to the time the rig has processed its
stream*: the horizon of the CAN stream is the newest bus stamp handled (or the
last time its receiver found the bus idle), that of the serial port the last
read. So a stall of the rig itself (its receive queue backed up, every source
late together) is not mistaken for a silent sensor, while a sensor, an actuator
or a whole bus that stops is caught LIVENESS_S after its last frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rig.geometry import ActuatorPlan
from rig.wire import can_messages as cm
from rig.wire.can_messages import Feedback, NodeState

LIVENESS_S = 0.25  # s a sensor may stay silent during a run (250 samples at 1 kHz)
# s an actuator's feedback may stay silent: 30 frames at 100 Hz. Longer than LIVENESS_S
# by a few feedback periods, so a silent bus is reported as the 1 kHz table sensor's
# silence, and one actuator's silence names that actuator
FEEDBACK_LIVENESS_S = 0.3
FOLLOWING_LIMIT_M = 0.0254  # 1 in between an actuator and the setpoints it was playing
# s of setpoints a healthy actuator may still be behind: its servo lag (τ = 5 ms in the
# sim, ~16 ms for a 10 Hz servo loop) and START taking effect at the controller's next tick
SERVO_LAG_S = 0.05
START_GRACE_S = 0.25  # s after START every actuator must have reported RUNNING
BACKLOG_LIMIT_S = 1.0  # s the rig may fall behind its receive queue before it gives up


@dataclass(frozen=True)
class FrameOrder:
    """How a numbered frame relates to the newest one of its stream seen before it."""

    lost: int = 0  # frames missing just before this one
    duplicate: bool = False  # the same number again
    late: bool = False  # older than the newest seen: arrived after a later frame


class Sequences:
    """Classifies frames of numbered streams (a sequence counter or a device timestamp)."""

    def __init__(self) -> None:
        self._last: dict[object, int] = {}

    def step(self, key: object, value: int, modulus: int, per_frame: float = 1.0) -> FrameOrder:
        """`value` (mod `modulus`) of stream `key`; frames advance it by `per_frame`.

        A step of more than half the modulus is a *late* frame (reordered), not a
        loss of almost a whole wrap: the newest value stays the reference.
        """
        last = self._last.get(key)
        if last is None:
            self._last[key] = value
            return FrameOrder()
        d = (value - last) % modulus
        if d == 0:
            return FrameOrder(duplicate=per_frame >= 1.0)
        if d > modulus // 2:
            return FrameOrder(late=True)
        self._last[key] = value
        return FrameOrder(lost=round(d / per_frame) - 1 if d > 1.5 * per_frame else 0)

    def forget(self, key: object) -> None:
        """Start `key` afresh (its numbering restarted)."""
        self._last.pop(key, None)


@dataclass
class _Actuator:
    last_seen: float = -math.inf  # run s, bus stamp
    state: NodeState | None = None
    started: bool = False  # reported RUNNING since START
    tick: int | None = None  # unwrapped servo tick of the last feedback


class Interlocks:
    """Watches the actuators and the sensors of one run; `check` names a broken rule."""

    def __init__(self, setpoint_rate: float) -> None:
        self.rate = setpoint_rate
        self.plan: ActuatorPlan | None = None
        self.start_t: float | None = None  # run s START was sent
        self.actuators = {i: _Actuator() for i in cm.ACTUATORS}
        self.sensors_seen = {"table": -math.inf, "mass": -math.inf}  # run s, arrival
        self.horizon = {"can": -math.inf, "serial": -math.inf}  # run s, see module doc
        self.faults: list[str] = []  # broken rules noticed while receiving; first wins

    def start(self, plan: ActuatorPlan, start_t: float) -> None:
        """START went out at run time `start_t` (s); the actuators now follow `plan`."""
        self.plan, self.start_t = plan, start_t

    # -- what arrived ----------------------------------------------------------------------

    def feedback(self, t: float, m: Feedback) -> float:
        """Feedback stamped `t` (run s); returns its following error (m), NaN if none."""
        a = self.actuators[m.actuator]
        a.last_seen, a.state = max(a.last_seen, t), m.status
        if self.plan is None or self.start_t is None:
            return math.nan
        a.started |= m.status == NodeState.RUNNING
        if not a.started:
            return math.nan  # START not there yet: the START_GRACE_S rule watches it
        if m.status not in (NodeState.RUNNING, NodeState.ENABLED, NodeState.FAULT):
            self.faults.append(f"actuator {m.actuator} left the run: it reports "
                               f"{m.status.name} at t = {t:.3f} s")
            return math.nan
        a.tick = self._unwrap(m.sequence, t)
        error = self.following_error(m.actuator, a.tick, m.position)
        if error > FOLLOWING_LIMIT_M:
            self.faults.append(
                f"actuator {m.actuator} following error {error * 1000:.1f} mm exceeds limit "
                f"{FOLLOWING_LIMIT_M * 1000:.1f} mm at setpoint {a.tick} (t = {t:.3f} s)")
        return error

    def _unwrap(self, sequence: int, t: float) -> int:
        """The full tick nearest to the index the rig's schedule expects at `t`."""
        modulus = 1 << cm.FEEDBACK_SEQUENCE_BITS
        expected = round((t - self.start_t) * self.rate)
        return expected + (sequence - expected + modulus // 2) % modulus - modulus // 2

    def following_error(self, actuator: int, tick: int, position: float) -> float:
        """Distance (m) of `position` from the setpoints of ticks [tick − lag, tick + 1].

        Before the first sample the actuator holds the first; after the last, the last.
        """
        column = self.plan.extension[:, actuator - 1]
        n = len(column)
        lo = min(max(tick - round(SERVO_LAG_S * self.rate), 0), n - 1)
        hi = min(max(tick + 1, 0), n - 1)
        window = column[lo:hi + 1]
        return max(0.0, position - float(np.max(window)), float(np.min(window)) - position)

    def sensor(self, name: str, t: float) -> None:
        self.sensors_seen[name] = max(self.sensors_seen[name], t)

    def reached(self, stream: str, t: float) -> None:
        """Everything of `stream` ("can", "serial") up to run time `t` has been handled."""
        self.horizon[stream] = max(self.horizon[stream], t)

    # -- the rules ---------------------------------------------------------------------

    def check(self, now: float, since: float) -> str | None:
        """The first broken rule at run time `now`; sources must be live after `since`."""
        if self.faults:
            return self.faults[0]
        can, serial = (max(self.horizon[s], since) for s in ("can", "serial"))
        for stream, horizon in (("CAN", can), ("serial", serial)):
            if now - horizon > BACKLOG_LIMIT_S:
                return (f"{stream} receive path {now - horizon:.2f} s behind "
                        f"(limit {BACKLOG_LIMIT_S:.2f} s): the rig cannot keep up")
        for sensor, horizon in (("table", can), ("mass", serial)):
            silent = horizon - max(self.sensors_seen[sensor], since)
            if silent > LIVENESS_S:
                return (f"{sensor} sensor silent for {silent:.2f} s "
                        f"(liveness limit {LIVENESS_S:.2f} s)")
        for i, a in self.actuators.items():
            silent = can - max(a.last_seen, since)
            if silent > FEEDBACK_LIVENESS_S:
                return (f"actuator {i} feedback silent for {silent:.2f} s "
                        f"(liveness limit {FEEDBACK_LIVENESS_S:.2f} s)")
        if self.start_t is not None and can - self.start_t > START_GRACE_S:
            for i, a in self.actuators.items():
                if not a.started:
                    state = a.state.name if a.state is not None else "nothing"
                    return (f"actuator {i} not RUNNING {START_GRACE_S:.2f} s after START "
                            f"(it reports {state})")
        return None
