"""The simulated CAN nodes: six actuator controllers and the table sensor's encoder.

An actuator controller (`ActuatorController`, a `CanDevice` on the SocketcandServer)
keeps the setpoints it receives by their full sample index. After START at sample
s0 it plays sample s0 + (t − t_start)·rate at plant time t, interpolating
between samples by a quintic through each sample's position, velocity and
acceleration (`interpolate_setpoints`), and the plant's servo axis follows that
target.

Why a quintic, not straight lines: a lag of a piecewise-linear target has an
acceleration that jumps at every sample (400 Hz), and a mass held by static
friction breaks away when m·ü crosses the breakaway force (91 N on 2,722 kg:
0.03 m/s²), so that ripple, invisible in any displacement record (0.015 µm of
u), moved the mass's x by 5 µm RMS, up to 18 µm (measured on run A with
Table 1's average constants: linear or Catmull–Rom against the profile's exact
ramps). The analysis cannot see it and fitted biased constants with error bars
that covered the rig's value in 68 % of cases. A quintic Hermite with
fourth-order differences for the velocity and acceleration is C², as a motion
controller's PVT interpolation is, and puts the plant within 0.3 µm RMS of the
exact ramps' response.
Watchdog: if the setpoint it needs has not arrived `WATCHDOG_S` after it was due,
it holds its position and sets `Fault.WATCHDOG_HOLD` (the stream stopped).
STOP while running means "no more setpoints": play the ones held, then stay at
the last (state ENABLED, no fault); SAFE_STATE holds the current position for good.

Servo tick: the controller counts its servo ticks in setpoint samples (1 / rate).
START sets the count to the start sample, so while RUNNING the tick is the index
of the setpoint being played; it keeps counting after the run. Each feedback
frame carries the tick of its measurement as `Sequence` (16 bits, wrapping), so
the rig compares a feedback with exactly the setpoint played at that instant,
whatever the frame's delivery latency (rig.run.interlocks).

START takes effect the instant it arrives (`clock`), as on a controller whose
servo tick is short. The plant computes a chunk (20–40 ms) ahead, so the grid
points already computed keep the old target and the motion starts up to that
much late, inside the rig's servo-lag allowance. Causality: a grid point before
START arrived never plays the run. After a stall of the plant thread it computes
grid points in the past; when START took effect at "the first grid point computed
after it", such a stall started the actuators before START had reached them, up
to the stall's length ahead of the rig's schedule.
"""

from __future__ import annotations

import math
import struct
import threading
from collections.abc import Callable, Mapping

import can

from analysis.simulate.motion import quintic_at
from rig.wire import can_messages as cm
from rig.wire.can_messages import CommandKind, Fault, NodeState, RigCommand, Setpoint

WATCHDOG_S = 0.1  # s a needed setpoint may be late before the actuator holds
STENCIL = 2  # samples each side of a knot its velocity and acceleration are read from


def interpolate_setpoints(samples: Mapping[int, float], i: float, h: float) -> float:
    """The target (m) at fractional sample index `i` between samples k = ⌊i⌋ and k + 1
    (both present), `h` (s) apart: the quintic Hermite through the two samples with
    velocities and accelerations from central differences.

    Fourth order where two samples each side of a knot are present, second order with
    one, and a knot at the edge of the stream (the run's first or last sample) is taken
    at rest, as the table is before and after a profile. Exact for polynomials up to
    degree 4 inside the stream.
    """
    k = math.floor(i)
    return quintic_at(i - k, h, samples[k], *_knot_rates(samples, k, h), samples[k + 1],
                      *_knot_rates(samples, k + 1, h))


def _knot_rates(s: Mapping[int, float], j: int, h: float) -> tuple[float, float]:
    """(velocity m/s, acceleration m/s²) of the setpoint stream at sample j."""
    if all(j + o in s for o in (-2, -1, 1, 2)):
        v = (-s[j + 2] + 8.0 * s[j + 1] - 8.0 * s[j - 1] + s[j - 2]) / (12.0 * h)
        a = (-s[j + 2] + 16.0 * s[j + 1] - 30.0 * s[j] + 16.0 * s[j - 1] - s[j - 2]) / (
            12.0 * h * h)
        return v, a
    if j - 1 in s and j + 1 in s:
        return (s[j + 1] - s[j - 1]) / (2.0 * h), (s[j + 1] - 2.0 * s[j] + s[j - 1]) / (h * h)
    return 0.0, 0.0


class ActuatorController:
    """One actuator's controller node (1–6) following sample-indexed setpoints at `rate` Hz."""

    def __init__(self, index: int, rate: float, clock: Callable[[], float] | None = None
                 ) -> None:
        """clock: the plant's clock (host monotonic s), to stamp START's arrival; None
        (unit tests driving `target` by hand) lets START act at the next `target` call."""
        self.index, self.rate = index, rate
        self._clock = clock
        self._start_arrived: float | None = None
        self._tick_origin = (0.0, 0)  # (plant s, tick): tick(t) = tick + floor((t − s)·rate)
        self.safe_state_at: float | None = None  # clock time it entered SAFE_STATE (tests)
        self.hold_at: float | None = None  # plant time the watchdog made it hold
        self.feedback_muted_from: float | None = None  # fault: no feedback from this time
        self.state = NodeState.DISABLED
        self.faults = Fault.NONE
        self._lock = threading.Lock()
        self._setpoints: dict[int, float] = {}
        self._last_seq: int | None = None
        self._start_sample: int | None = None
        self._t_start: float | None = None
        self._hold = 0.0  # m, target while not following
        self._stopping = False  # STOP came: finish the buffered samples, then hold
        self.setpoints_received = 0

    def on_frame(self, msg: can.Message) -> None:
        """Bus frames (server thread): this actuator's setpoints and every rig command."""
        if msg.arbitration_id == cm.SETPOINT_BASE + self.index:
            sp = cm.from_can(msg)
            assert isinstance(sp, Setpoint)
            with self._lock:
                full = sp.sequence if self._last_seq is None else cm.unwrap(
                    self._last_seq, sp.sequence, cm.SETPOINT_SEQUENCE_BITS)
                self._last_seq = full
                self._setpoints[full] = sp.position
                self.setpoints_received += 1
        elif msg.arbitration_id == cm.COMMAND_ID:
            cmd = cm.from_can(msg)
            assert isinstance(cmd, RigCommand)
            with self._lock:
                self._command(cmd)

    def _command(self, cmd: RigCommand) -> None:
        if self.state == NodeState.SAFE_STATE and cmd.command != CommandKind.ENABLE:
            return
        if cmd.command == CommandKind.ENABLE:
            self.state, self.faults = NodeState.ENABLED, Fault.NONE
            self._setpoints.clear()
            self._last_seq = None
        elif cmd.command == CommandKind.START and self.state == NodeState.ENABLED:
            self.state, self._start_sample = NodeState.RUNNING, cmd.start_sample
            self._t_start = None
            self._start_arrived = self._clock() if self._clock is not None else None
            if self._start_arrived is not None:  # ticks count the run from its arrival on
                self._tick_origin = (self._start_arrived, cmd.start_sample)
            self._stopping = False
        elif cmd.command == CommandKind.STOP:
            if self.state == NodeState.RUNNING:
                self._stopping = True
            else:
                self.state = NodeState.ENABLED
        elif cmd.command == CommandKind.SAFE_STATE:
            self.state, self._start_sample = NodeState.SAFE_STATE, None
            self.safe_state_at = self._clock() if self._clock is not None else 0.0

    def target(self, t: float) -> float:
        """The position (m) to follow at plant time `t` (s); plant thread."""
        with self._lock:
            if self.state != NodeState.RUNNING or self._start_sample is None:
                return self._hold
            if self._t_start is None:
                if self._start_arrived is None:  # no clock: START acts at this grid point
                    self._t_start = t
                    self._tick_origin = (t, self._start_sample)
                elif t < self._start_arrived:
                    return self._hold  # a grid point before START arrived (module doc)
                else:
                    self._t_start = self._start_arrived
            i = self._start_sample + (t - self._t_start) * self.rate
            k = math.floor(i)
            have = self._setpoints
            if k in have and k + 1 in have:
                self._hold = interpolate_setpoints(have, i, 1.0 / self.rate)
                for old in [j for j in have if j < k - STENCIL]:
                    del have[old]
            elif k in have:
                self._hold = have[k]
            elif self._stopping and (not have or k > max(have)):
                self.state, self._start_sample = NodeState.ENABLED, None  # done: hold the last
            elif not have or i - max(have) > WATCHDOG_S * self.rate:
                if not self.faults & Fault.WATCHDOG_HOLD:
                    self.hold_at = t
                self.faults |= Fault.WATCHDOG_HOLD
            return self._hold

    @property
    def started_at(self) -> float | None:
        """Plant time (s) the last START took effect; None before any."""
        return self._t_start

    def tick(self, t: float) -> int:
        """The servo tick at plant time `t` (s): while RUNNING the setpoint index played."""
        with self._lock:
            origin = self._tick_origin
        return self._tick_from(origin, t)

    def _tick_from(self, origin: tuple[float, int], t: float) -> int:
        origin_t, origin_tick = origin
        return origin_tick + math.floor((t - origin_t) * self.rate)

    def feedback(self, t: float, position: float) -> can.Message:
        """The feedback frame for `position` (m) measured at plant time `t` (s).

        Tick, state and faults are read in one hold of the lock: read apart, a START
        taking effect between them (the server thread) gave a frame RUNNING with the
        tick of before the run, whose setpoint the rig took from the end of the
        profile (seen: "actuator 1 following error 76.2 mm at setpoint 7603" on a
        3 in ramp, 0.5 s into the run, under GIL contention).
        """
        with self._lock:
            origin, state, faults = self._tick_origin, self.state, self.faults
        return cm.to_can(cm.Feedback(self.index, self._tick_from(origin, t), position, state,
                                     faults))

    def sends_feedback(self, t: float) -> bool:
        """False once the fault `feedback_muted_from` has begun (a stalled feedback stream)."""
        return self.feedback_muted_from is None or t < self.feedback_muted_from


def heartbeat(node: int, counter: int, state: NodeState) -> can.Message:
    return cm.to_can(cm.Heartbeat(node, counter, state))


_TABLE = struct.Struct("<II")


def table_sample(counts: int, sequence: int, timestamp_us: int) -> can.Message:
    """A TableSensor frame, packed directly: 1,000 a second, and cantools' checked encode
    costs ~70 µs. Same bytes as `cm.encode(TableSample(...))` (tests/test_sim_serve.py)."""
    low = (counts & 0xFFFFFF) | (sequence & 0xFF) << 24
    data = _TABLE.pack(low, timestamp_us & 0xFFFFFFFF)
    return can.Message(arbitration_id=cm.TABLE_SENSOR_ID, data=data, is_extended_id=False)
