"""Received frames → run file rows, lost-frame accounting and the run's watchdogs.

One `Recorder` per run, called on the runner's thread only (the writer's rule).
Time base: the run file's host time (s since the writer started). CAN frames
carry the bus's Unix timestamp, mapped by the run's start_unix; serial frames
carry the arrival time on the monotonic clock. Sensor samples are placed at
their *sampling* instant: each sensor's device timestamps are mapped onto host
time by a `ClockFit` (rig.run.clock_fit; docs/time_alignment.md). A sample is
written `HOLD_S` after it arrived, on the fit as it stands then, so every
sample but the first half second's is placed by a fit that has seen it and its
neighbours; `finish()` refits and writes the rest. Live readers lag by HOLD_S.

`rig import` feeds a logged bus through the same path; a bench DBC with a MassSensor
message (rig.wire.can_messages) brings the mass sensor over CAN, handled as the table's.

Losses, never interpolated: numbered frames (sensor device timestamps, feedback
servo ticks, heartbeat counters) are classified on arrival (rig.run.interlocks.Sequences):
missing ones are counted as `lost`, repeats as `duplicates` (not written twice),
frames overtaken by a later one as `reordered`. Sensor channels are written in
device-time order from the held-back samples, so a reordered sample still lands
in its place, and a hole in device time is marked in /gaps with its size. CAN
`crc_errors` counts error frames and frames of the rig's DBC ids that do not
decode (wrong length, an index that contradicts the id, an unknown state).

Watchdogs (`check`): the rules of rig.run.interlocks (liveness of each sensor and
actuator, following error by servo tick, START taken by every actuator) plus an
actuator reporting a fault and a CAN bus-off error frame; the first broken rule
raises `RunAborted` naming it.
"""

from __future__ import annotations

import math
from collections import deque

import can
import numpy as np
from cantools.database.can import Database

from rig.config import RigConfig
from rig.errors import DataError, RigError
from rig.geometry import ActuatorPlan
from rig.run.clock_fit import ClockFit
from rig.run.interlocks import FOLLOWING_LIMIT_M, LIVENESS_S, FrameOrder, Interlocks, Sequences
from rig.run.status import ActuatorLive, LiveStatus, Trace
from rig.runfile import RunWriter
from rig.wire import can_messages as cm
from rig.wire.can_messages import Fault, Feedback, Heartbeat, MassSample, NodeState, TableSample
from rig.wire.serial_frame import DecoderStats, Frame, encode_frame

__all__ = ["FOLLOWING_LIMIT_M", "HOLD_S", "LIVENESS_S", "Recorder", "RunAborted"]

HOLD_S = 0.5  # s sensor samples wait for a better clock fit before they are written
CHECK_EVERY_S = 0.005  # s between two looks at the time-based watchdog rules
CAN_ERR_BUSOFF = 0x040  # SocketCAN error class bit of an error frame: the controller is off
_US = 1 << 32  # device timestamps are 32-bit µs


class RunAborted(RigError):
    """A watchdog stopped the run; the message names the rule and the value."""


class Recorder:
    """Writes what the receivers hand over and keeps the counts a run summary reports."""

    def __init__(self, writer: RunWriter, config: RigConfig, start_unix: float,
                 t0_mono: float, db: Database | None = None) -> None:
        """`db`: a bench DBC (rig.wire.can_messages.bench_database) to decode with instead of the
        rig's; one with a MassSensor message brings mass_x over CAN (a logged bench bus)."""
        self.w, self.config, self._db = writer, config, db
        self._start_unix, self._t0 = start_unix, t0_mono
        self.table_clock, self.mass_clock = ClockFit(), ClockFit()
        self._seq = Sequences()
        self.watch = Interlocks(config.rates.setpoint)
        self.lost = {"can": 0, "serial": 0}
        self.counts = {"can": 0, "serial": 0, "table": 0, "mass": 0}
        self.plan: ActuatorPlan | None = None
        self.start_run_t: float | None = None  # run time START was sent
        self._serial_stats = DecoderStats()
        self._pending: dict[str, deque] = {"table_u": deque(), "mass_x": deque()}
        self._written: dict[str, tuple[float, float] | None] = {"table_u": None, "mass_x": None}
        self._device: dict[str, list[float]] = {"table_u": [], "mass_x": []}  # s, per row written
        self._period = {"table_u": 1.0 / config.table_sensor.sample_rate,
                        "mass_x": 1.0 / config.mass_sensor.sample_rate}
        self._fb_per_frame = config.rates.setpoint / config.rates.feedback
        self._fb_state: dict[int, NodeState] = {}
        self._ours = cm.known_ids(db)
        # for displays only (rig.run.status): recent samples on arrival time, last feedback
        self.traces = {"table_u": Trace(), "mass_x": Trace()}
        self._last_feedback: dict[int, tuple[float, int, int, float]] = {}
        self._next_check = -math.inf

    @property
    def faults(self) -> list[str]:
        """Broken rules noticed while receiving (the first one aborts the run)."""
        return self.watch.faults

    def start(self, plan: ActuatorPlan, start_run_t: float) -> None:
        """START went out at run time `start_run_t` (s)."""
        self.plan, self.start_run_t = plan, start_run_t
        self.watch.start(plan, start_run_t)

    # -- CAN -------------------------------------------------------------------------------

    def can_frame(self, msg: can.Message) -> cm.RigMessage | None:
        """Record, count and decode one frame; the rig message in it, if any."""
        t = msg.timestamp - self._start_unix
        self.counts["can"] += 1
        self.w.can_frame(t, msg.arbitration_id, bytes(msg.data), dlc=msg.dlc,
                         extended=msg.is_extended_id, error=msg.is_error_frame,
                         remote=msg.is_remote_frame)
        self.watch.reached("can", t)
        if msg.is_error_frame:
            self.w.count("can", "crc_errors")
            if msg.arbitration_id & CAN_ERR_BUSOFF:
                self.faults.append(f"CAN bus off (error frame class 0x{msg.arbitration_id:03X} "
                                   f"at t = {t:.3f} s)")
            return None
        try:
            m = cm.from_can(msg, self._db)
        except DataError:
            if msg.arbitration_id in self._ours and not msg.is_extended_id:
                self.w.count("can", "crc_errors")  # one of ours, but it fails the DBC
            return None  # kept raw, never decoded
        if isinstance(m, TableSample):
            self._sensor("table_u", cm.TABLE_SENSOR_ID, t, m)
        elif isinstance(m, MassSample):
            self._sensor("mass_x", msg.arbitration_id, t, m)
        elif isinstance(m, Feedback):
            self._feedback(t, m)
        elif isinstance(m, Heartbeat):
            self._count(self._seq.step(msg.arbitration_id, m.counter, 1 << cm.COUNTER_BITS))
        return m

    def idle(self, stream: str, stamp: float) -> None:
        """The receiver of `stream` found nothing more up to `stamp` (Unix s for CAN,
        monotonic s for serial, as their frames): that stream is complete up to there."""
        t = stamp - (self._start_unix if stream == "can" else self._t0)
        self.watch.reached(stream, t)

    def _count(self, step: FrameOrder) -> bool:
        """Count a CAN frame's step; True if its content is new (goes to the channels)."""
        if step.lost:
            self.lost["can"] += step.lost
            self.w.count("can", "lost", step.lost)
        if step.duplicate:
            self.w.count("can", "duplicates")
        if step.late:  # counted lost when its successor came; it was not lost after all
            if self.lost["can"] > 0:
                self.lost["can"] -= 1
                self.w.count("can", "lost", -1)
            self.w.count("can", "reordered")
        return not step.duplicate

    def _sensor(self, channel: str, key: int, t: float, m: TableSample | MassSample) -> None:
        """A sensor sample on CAN: the table's, or a bench's mass sensor (rig.wire.can_messages)."""
        step = self._seq.step(key, m.timestamp_us, _US, 1e6 * self._period[channel])
        if not self._count(step):
            return
        table = channel == "table_u"
        fit = self.table_clock if table else self.mass_clock
        sensor = self.config.table_sensor if table else self.config.mass_sensor
        device_s = fit.device_seconds(m.timestamp_us)
        fit.add(device_s, t)
        value = m.counts * sensor.scale + sensor.offset
        self._defer(channel, t, device_s, value)
        self.traces[channel].append(t, value)
        self.counts["table" if table else "mass"] += 1
        self.watch.sensor("table" if table else "mass", t)

    def _defer(self, channel: str, arrival: float, device_s: float, value: float) -> None:
        """Hold a sample back (in device-time order) and write those older than `HOLD_S`,
        placed on the clock fit as it stands then (module doc)."""
        pending = self._pending[channel]
        if pending and device_s < pending[-1][1]:  # reordered: put it in its place
            k = len(pending)
            while k > 0 and pending[k - 1][1] > device_s:
                k -= 1
            pending.insert(k, (arrival, device_s, value))
        else:
            pending.append((arrival, device_s, value))
        while pending and pending[0][0] < arrival - HOLD_S:
            self._write_pending(channel, pending.popleft())

    def _write_pending(self, channel: str, item: tuple[float, float, float]) -> None:
        """Write one held sample; a hole in device time before it goes to /gaps first."""
        _, device_s, value = item
        fit = self.table_clock if channel == "table_u" else self.mass_clock
        host = fit.model.to_host(device_s)
        last, period = self._written[channel], self._period[channel]
        if last is not None:
            if device_s - last[0] < 0.5 * period:
                return  # a repeat, or older than what is written: a channel never goes back
            missing = round((device_s - last[0]) / period) - 1
            if missing > 0:
                self.w.gap(channel, last[1], host, missing)
        self.w.sample(channel, host, value)
        self._device[channel].append(device_s)
        self._written[channel] = (device_s, host)

    def finish(self) -> None:
        """Refit both clocks on everything, write every sample still held back, and place
        every sample of the run again on that final fit.

        Why again: a sample was written on the fit as it stood half a second after it
        arrived, with the rate taken as 1 for the first 2 s; the placements then moved
        with each refit (7–27 µs RMS about the truth, the table-to-mass offset drifting
        by up to 15 ppm within a run, 75 µs over 5 s: 150 µm of x at run C's speed).
        One line through the whole run leaves a constant offset, which the analysis
        fits as the channels' skew, and the final fit's rate error.
        """
        for channel, fit in (("table_u", self.table_clock), ("mass_x", self.mass_clock)):
            model = fit.refit()
            pending = self._pending[channel]
            while pending:
                self._write_pending(channel, pending.popleft())
            device = np.asarray(self._device[channel])
            self.w.retime(channel, model.offset + model.rate * device)

    def _feedback(self, t: float, m: Feedback) -> None:
        i = m.actuator
        key = cm.FEEDBACK_BASE + i
        if self._fb_state.get(i) != m.status:
            self._seq.forget(key)  # the servo tick restarts at START: no loss to count there
            self._fb_state[i] = m.status
        step = self._seq.step(key, m.sequence, 1 << cm.FEEDBACK_SEQUENCE_BITS,
                              self._fb_per_frame)
        if self._count(step) and not step.late:
            self.w.sample(f"actuator_feedback_{i}", t, m.position)
            self.w.sample(f"actuator_status_{i}", t, int(m.status) | int(m.faults) << 4)
        if m.faults != Fault.NONE or m.status == NodeState.FAULT:
            self.faults.append(f"actuator {i} reports {m.status.name} with faults "
                               f"{m.faults!r} at t = {t:.3f} s")
        error = self.watch.feedback(t, m)
        self._last_feedback[i] = (m.position, int(m.status), int(m.faults), error)

    # -- serial ----------------------------------------------------------------------------

    def serial_frames(self, arrival_mono: float, frames: list[Frame],
                      stats: DecoderStats) -> None:
        """Frames decoded from one read (maybe none: garbage only) and the decoder's totals."""
        t = arrival_mono - self._t0
        fit, sensor = self.mass_clock, self.config.mass_sensor
        new_gaps = stats.seq_gaps - self._serial_stats.seq_gaps
        if new_gaps:  # somewhere in this read; placed before its frames
            self.w.gap("raw/serial", t, t, new_gaps)
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
        self.watch.reached("serial", t)
        if frames:
            self.watch.sensor("mass", t)

    @property
    def crc_errors(self) -> int:
        return self._serial_stats.crc_errors

    # -- setpoints sent and watchdogs ------------------------------------------------------

    def setpoint_sent(self, actuator: int, index: int, position: float) -> None:
        """Log a setpoint at the time the actuators will play it (START + index / rate)."""
        if self.plan is not None and self.start_run_t is not None:
            t = self.start_run_t + index / self.plan.rate
            self.w.sample(f"actuator_setpoint_{actuator}", t, position)

    def live(self, phase: str, now_run: float, frames_per_s: float) -> LiveStatus:
        """A snapshot for displays (rig.run.status); times from START (s), which may be negative."""
        start = self.start_run_t if self.start_run_t is not None else now_run
        duration = float(self.plan.t[-1]) if self.plan is not None else 0.0
        actuators = []
        for i in cm.ACTUATORS:
            setpoint = float("nan")
            if self.plan is not None and self.start_run_t is not None:
                setpoint = float(np.interp(now_run - start, self.plan.t,
                                           self.plan.extension[:, i - 1]))
            pos, status, faults, error = self._last_feedback.get(
                i, (math.nan, -1, 0, math.nan))
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
        """Raise RunAborted if a watchdog tripped; sources must be live after `since` (run s).

        A broken rule noticed on receipt aborts at once; the time-based rules (liveness,
        START) are looked at every CHECK_EVERY_S, not on every pass of the runner's loop.
        """
        if not self.watch.faults and now_run < self._next_check:
            return
        self._next_check = now_run + CHECK_EVERY_S
        broken = self.watch.check(now_run, since)
        if broken is not None:
            raise RunAborted(broken)
