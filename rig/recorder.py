"""Received frames → run file rows, lost-frame accounting and the run's watchdogs.

One `Recorder` per run, called on the runner's thread only (the writer's rule).
Time base: the run file's host time (s since the writer started). CAN frames
carry the bus's Unix timestamp, mapped by the run's start_unix; serial frames
carry the arrival time on the monotonic clock. Sensor samples are placed at
their *sampling* instant: each sensor's device timestamps are mapped onto host
time by a `ClockFit` (rig.clock_fit; docs/time_alignment.md). A sample is
written `HOLD_S` after it arrived, on the fit as it stands then, so every
sample but the first half second's is placed by a fit that has seen it and its
neighbours; `finish()` refits and writes the rest. Live readers lag by HOLD_S.

Watchdogs (`check`): sensor silent longer than `LIVENESS_S`, an actuator that
reports a fault, or an actuator further than `FOLLOWING_LIMIT_M` from every
setpoint of the last `FOLLOWING_WINDOW_S` raises `RunAborted` naming the rule.
"""

from __future__ import annotations

from collections import deque

import can
import numpy as np

from rig import can_messages as cm
from rig.can_messages import Fault, Feedback, Heartbeat, NodeState, TableSample
from rig.clock_fit import ClockFit
from rig.config import RigConfig
from rig.errors import DataError, RigError
from rig.geometry import ActuatorPlan
from rig.live import ActuatorLive, LiveStatus, Trace
from rig.runfile import RunWriter
from rig.serial_frame import DecoderStats, Frame, encode_frame

LIVENESS_S = 0.25  # s a sensor may stay silent during a run
FOLLOWING_LIMIT_M = 0.0254  # 1 in from the recent setpoints
# s of setpoints a feedback frame may still reflect: the servo's lag plus the frame's
# delivery latency, which reached 0.2 s on a loaded 2-core machine (a 60 ms window
# tripped a healthy actuator in CI). Same bound as the sensors' liveness: a stuck valve
# is caught within this plus the time the setpoints need to move 1 in away.
FOLLOWING_WINDOW_S = 0.25
# s of setpoints *ahead* of the rig's schedule a feedback may show: frames are stamped when
# the rig reads them, and after a stall of its receive loop (0.33 s seen in CI at a run's
# start) a burst read at once can put the actuators tens of ms ahead of that schedule.
# A stuck valve falls behind, so this does not delay catching one.
FOLLOWING_AHEAD_S = 0.05
HOLD_S = 0.5  # s sensor samples wait for a better clock fit before they are written


class RunAborted(RigError):
    """A watchdog stopped the run; the message names the rule and the value."""


class Recorder:
    """Writes what the receivers hand over and keeps the counts a run summary reports."""

    def __init__(self, writer: RunWriter, config: RigConfig, start_unix: float,
                 t0_mono: float) -> None:
        self.w, self.config = writer, config
        self._start_unix, self._t0 = start_unix, t0_mono
        self.table_clock, self.mass_clock = ClockFit(), ClockFit()
        self._seq: dict[int, int] = {}  # arbitration id → last sequence (wrapped)
        self.lost = {"can": 0, "serial": 0}
        self.counts = {"can": 0, "serial": 0, "table": 0, "mass": 0}
        self.last_seen = {"table": -1.0, "mass": -1.0}  # run time s, arrival
        self.plan: ActuatorPlan | None = None
        self.start_run_t: float | None = None  # run time START was sent
        self.faults: list[str] = []
        self._serial_stats = DecoderStats()
        self._pending: dict[str, deque] = {"table_u": deque(), "mass_x": deque()}
        # for displays only (rig.live): recent samples on arrival time, last feedback
        self.traces = {"table_u": Trace(), "mass_x": Trace()}
        self._last_feedback: dict[int, tuple[float, int, int, float]] = {}

    # -- CAN -------------------------------------------------------------------------------

    def can_frame(self, msg: can.Message) -> None:
        t = msg.timestamp - self._start_unix
        self.counts["can"] += 1
        self.w.can_frame(t, msg.arbitration_id, bytes(msg.data), dlc=msg.dlc,
                         extended=msg.is_extended_id, error=msg.is_error_frame,
                         remote=msg.is_remote_frame)
        if msg.is_error_frame:
            return
        try:
            m = cm.from_can(msg)
        except DataError:
            return  # not ours: kept raw, never decoded
        if isinstance(m, TableSample):
            self._table(t, m)
        elif isinstance(m, Feedback):
            self._feedback(t, m)
        elif isinstance(m, Heartbeat):
            self._sequence(msg.arbitration_id, m.counter, cm.COUNTER_BITS, t)

    def _table(self, t: float, m: TableSample) -> None:
        self._sequence(cm.TABLE_SENSOR_ID, m.sequence, cm.SENSOR_SEQUENCE_BITS, t, "table_u")
        fit, sensor = self.table_clock, self.config.table_sensor
        device_s = fit.device_seconds(m.timestamp_us)
        fit.add(device_s, t)
        value = m.counts * sensor.scale + sensor.offset
        self._defer("table_u", t, device_s, value)
        self.traces["table_u"].append(t, value)
        self.counts["table"] += 1
        self.last_seen["table"] = t

    def _defer(self, channel: str, arrival: float, device_s: float | None, value: float) -> None:
        """Queue a sample (or a gap: device_s None, value = count) and write those older
        than `HOLD_S`, placed on the clock fit as it stands then (module doc)."""
        pending = self._pending[channel]
        pending.append((arrival, device_s, value))
        while pending and pending[0][0] < arrival - HOLD_S:
            self._write_pending(channel, pending.popleft())

    def _write_pending(self, channel: str, item: tuple[float, float | None, float]) -> None:
        arrival, device_s, value = item
        if device_s is None:
            self.w.gap(channel, arrival, arrival, int(value))
            return
        fit = self.table_clock if channel == "table_u" else self.mass_clock
        self.w.sample(channel, fit.model.to_host(device_s), value)

    def finish(self) -> None:
        """Refit both clocks on everything and write every sample still held back."""
        for channel, fit in (("table_u", self.table_clock), ("mass_x", self.mass_clock)):
            fit.refit()
            pending = self._pending[channel]
            while pending:
                self._write_pending(channel, pending.popleft())

    def _feedback(self, t: float, m: Feedback) -> None:
        i = m.actuator
        self._sequence(cm.FEEDBACK_BASE + i, m.sequence, cm.FEEDBACK_SEQUENCE_BITS, t,
                       f"actuator_feedback_{i}")
        self.w.sample(f"actuator_feedback_{i}", t, m.position)
        self.w.sample(f"actuator_status_{i}", t, int(m.status) | int(m.faults) << 4)
        if m.faults != Fault.NONE or m.status == NodeState.FAULT:
            self.faults.append(f"actuator {i} reports {m.status.name} with faults "
                               f"{m.faults!r} at t = {t:.3f} s")
        error = self._following(t, i, m.position)
        self._last_feedback[i] = (m.position, int(m.status), int(m.faults), error)

    def _sequence(self, key: int, seq: int, bits: int, t: float, channel: str = "") -> None:
        """Count frames missing between consecutive sequence numbers of one stream."""
        last = self._seq.get(key)
        self._seq[key] = seq
        if last is None:
            return
        step = (seq - last) % (1 << bits)
        if step == 0:
            self.w.count("can", "duplicates")
        elif step > 1:
            self.lost["can"] += step - 1
            self.w.count("can", "lost", step - 1)
            if channel in self._pending:
                self._defer(channel, t, None, step - 1)
            elif channel:
                self.w.gap(channel, t, t, step - 1)

    # -- serial ----------------------------------------------------------------------------

    def serial_frames(self, arrival_mono: float, frames: list[Frame],
                      stats: DecoderStats) -> None:
        t = arrival_mono - self._t0
        fit, sensor = self.mass_clock, self.config.mass_sensor
        new_gaps = stats.seq_gaps - self._serial_stats.seq_gaps
        if new_gaps:  # somewhere in this read; placed before its frames
            self.w.gap("raw/serial", t, t, new_gaps)
            self._defer("mass_x", t, None, new_gaps)
        for f in frames:
            self.w.serial_frame(t, encode_frame(f.seq, f.timestamp_us, f.counts, f.status))
            device_s = fit.device_seconds(f.timestamp_us)
            fit.add(device_s, t)
            value = f.counts * sensor.scale + sensor.offset
            self._defer("mass_x", t, device_s, value)
            self.traces["mass_x"].append(t, value)
        self._serial_stats = stats
        self.lost["serial"] = stats.seq_gaps
        for kind, total in (("lost", stats.seq_gaps), ("crc_errors", stats.crc_errors),
                            ("duplicates", stats.duplicates),
                            ("bytes_discarded", stats.bytes_discarded)):
            self.w.set_count("serial", kind, total)
        self.counts["serial"] += len(frames)
        self.counts["mass"] += len(frames)
        self.last_seen["mass"] = t

    @property
    def crc_errors(self) -> int:
        return self._serial_stats.crc_errors

    # -- setpoints sent and watchdogs ------------------------------------------------------

    def setpoint_sent(self, actuator: int, index: int, position: float) -> None:
        """Log a setpoint at the time the actuators will play it (START + index / rate)."""
        if self.plan is not None and self.start_run_t is not None:
            t = self.start_run_t + index / self.plan.rate
            self.w.sample(f"actuator_setpoint_{actuator}", t, position)

    def _following(self, t: float, actuator: int, position: float) -> float:
        """Following error (m, NaN before START); a fault is recorded past the limit."""
        if self.plan is None or self.start_run_t is None:
            return float("nan")
        local = t - self.start_run_t
        window = np.linspace(local - FOLLOWING_WINDOW_S, local + FOLLOWING_AHEAD_S, 61)
        sp = np.interp(window, self.plan.t, self.plan.extension[:, actuator - 1])
        error = max(0.0, position - sp.max(), sp.min() - position)
        if error > FOLLOWING_LIMIT_M:
            self.faults.append(f"actuator {actuator} following error {error * 1000:.1f} mm "
                               f"exceeds limit {FOLLOWING_LIMIT_M * 1000:.1f} mm "
                               f"at t = {t:.3f} s")
        return error

    def live(self, phase: str, now_run: float, frames_per_s: float) -> LiveStatus:
        """A snapshot for displays (rig.live); times from START (s), which may be negative."""
        start = self.start_run_t if self.start_run_t is not None else now_run
        duration = float(self.plan.t[-1]) if self.plan is not None else 0.0
        actuators = []
        for i in cm.ACTUATORS:
            setpoint = float("nan")
            if self.plan is not None and self.start_run_t is not None:
                setpoint = float(np.interp(now_run - start, self.plan.t,
                                           self.plan.extension[:, i - 1]))
            pos, status, faults, error = self._last_feedback.get(
                i, (float("nan"), -1, 0, float("nan")))
            name = NodeState(status).name if status in NodeState._value2member_map_ else "?"
            actuators.append(ActuatorLive(i, setpoint, pos, error, name, faults))
        traces = {}
        for name, trace in self.traces.items():
            t, v = trace.recent(now_run)
            traces[name] = (t - start, v)
        return LiveStatus(phase, now_run - start, duration, traces["table_u"], traces["mass_x"],
                          tuple(actuators), dict(self.counts), dict(self.lost),
                          self.crc_errors, frames_per_s)

    def check(self, now_run: float, since: float) -> None:
        """Raise RunAborted if a watchdog tripped; sensors must be live after `since` (run s)."""
        if self.faults:
            raise RunAborted(self.faults[0])
        for sensor, last in self.last_seen.items():
            silent = now_run - max(last, since)
            if silent > LIVENESS_S:
                raise RunAborted(f"{sensor} sensor silent for {silent:.2f} s "
                                 f"(liveness limit {LIVENESS_S:.2f} s)")
