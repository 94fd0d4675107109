"""One run on the table: check, arm, stream setpoints, log both buses, always end safe.

Order (design.md §4.6–7):
1. `check_all`, the bus-load budget and the output directory (missing, not
   writable, nearly full), before anything is opened: a refused run never
   reaches the bus.
2. With `backend = "sim"` start `sim serve` (rig.run.sim_process) unless given one.
3. Open the bus, the serial port and the run file; start the receivers; log a
   short baseline; `confirm()` arms (the CLI asks, or --yes).
4. Send the timed messages of rig.run.schedule at their due times, keeping the
   queue of received frames drained into the run file; watch the watchdogs.
   The schedule's origin is the instant START went out: the actuators play
   sample i at START + i / rate, and so does the run file's setpoint channel.
5. `finally`: SAFE_STATE on the bus, receivers stopped, port and bus closed,
   the run file closed with success / abort / fail and the reason.

Failures and how a run ends (docs/reliability.md): a watchdog, a lost bus or
port, the operator's e-stop or Ctrl-C end it as `abort`; a storage failure as
`fail` (the writer closes the file itself, with every flushed row); both return
a RunResult. Anything else is a bug: `fail`, and the exception propagates.
Commands (ENABLE, START, STOP, SAFE_STATE) go out `COMMAND_REPEATS` times: a node
obeys a repeat as a no-op, and one frame lost on the bus must not leave an
actuator disabled. If the run's bus is dead, SAFE_STATE is tried once more over a
fresh connection; the actuators' index watchdog holds them anyway.
"""

from __future__ import annotations

import logging
import queue
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

import can

from rig.config import RigConfig, config_to_dict
from rig.errors import DataError, RigError
from rig.geometry import ActuatorPlan, actuator_plan
from rig.limits import check_plan
from rig.profile import Profile
from rig.run.receive import (
    CanReceived,
    Idle,
    Received,
    ReceiverFailed,
    Receivers,
    SerialReceived,
    open_bus,
    open_port,
)
from rig.run.recorder import Recorder, RunAborted
from rig.run.safe_state import COMMAND_REPEATS, one_line, send_safe_state
from rig.run.schedule import LEAD_SAMPLES, Timed, run_messages
from rig.run.status import LiveStatus, Publisher, RunControl
from rig.runfile import RunInfo, RunWriter, check_output_dir, standard_channels
from rig.wire import can_messages as cm
from rig.wire.bus_load import check_bus_load
from rig.wire.can_messages import RigCommand, Setpoint

log = logging.getLogger(__name__)

BASELINE_S = 0.3  # s logged before START: the sensors' rest values
SETTLE_S = 0.3  # s logged after STOP
PUMP_BATCH = 64  # received items handled between two looks at the setpoint schedule
# The receive threads, the runner and (in tests and campaigns) the simulated rig share
# the GIL. A thread back from a C call (a socket read, an HDF5 write) waits up to the
# switch interval for it: at Python's 5 ms, with the per-core speed of a busy shared
# host, setpoints went out late enough for the actuators' watchdog (0.1 s) to hold and
# the receive queue fell 1 s behind; at 0.5 ms the same runs kept up.
RUN_SWITCH_INTERVAL_S = 5e-4


class BusLost(RunAborted):
    """The run's CAN connection failed: SAFE_STATE needs a fresh one (rig.run.safe_state)."""


class NotArmed(RigError):
    """The operator did not confirm; nothing moved."""


@dataclass
class RunResult:
    """What a run did: file, status, reason, duration (s), samples, losses per source."""

    path: Path
    status: str
    reason: str
    duration: float
    samples: dict[str, int] = field(default_factory=dict)
    lost: dict[str, int] = field(default_factory=dict)
    crc_errors: int = 0

    def summary(self) -> str:
        s, lost = self.samples, self.lost
        return (f"{self.path.name}: {self.status} in {self.duration:.2f} s, table_u "
                f"{s.get('table', 0)} samples, mass_x {s.get('mass', 0)} samples, "
                f"CAN {s.get('can', 0)} frames, lost {lost.get('can', 0)} CAN + "
                f"{lost.get('serial', 0)} serial frames, {self.crc_errors} CRC errors"
                + (f" ({self.reason})" if self.reason else ""))


def run_profile(config: RigConfig, profile: Profile, profile_text: str, out_dir: Path,
                confirm: Callable[[], bool] = lambda: True,
                progress: Callable[[str], None] = lambda _: None,
                sim_args: tuple[str, ...] = (), start_sim: bool = True,
                control: RunControl | None = None) -> RunResult:
    """Run `profile` once and write `out_dir/<time>_<profile>.h5`; see module docstring.

    start_sim: with backend "sim", start `sim serve` for this run; False when the
    caller already runs one (a campaign) and `config` points at it.
    control: the e-stop flag and live listeners (rig.run.status); the stop is honoured from
    the moment the run file opens, within one pass of the loop (a few ms).
    """
    plan = actuator_plan(config, profile)
    check_plan(config, plan)  # LimitError: nothing opened, nothing sent
    check_bus_load(config)
    check_output_dir(Path(out_dir))  # DataError: missing, not writable or full; nothing started
    if config.backend == "sim" and start_sim:
        from rig.run.sim_process import SimProcess  # starts a process: only when asked for
        with SimProcess(config, extra_args=sim_args) as sim:
            progress(f"sim serve running (pid {sim.pid})")
            return _run(sim.config, profile, profile_text, plan, out_dir, confirm, progress,
                        control)
    return _run(config, profile, profile_text, plan, out_dir, confirm, progress, control)


class _Loop:
    """What every pass of the runner's loops does besides receiving: e-stop and listeners."""

    def __init__(self, rec: Recorder, writer: RunWriter, control: RunControl | None) -> None:
        self.rec, self.writer, self.control = rec, writer, control
        self.publisher = Publisher(control)
        self.phase = "baseline"
        self.interrupted = False  # Ctrl-C while the table moves (_trap_ctrl_c)

    def tick(self) -> None:
        if self.control is not None and self.control.stop.is_set():
            raise RunAborted("emergency stop by the operator")
        if self.interrupted:
            raise RunAborted("interrupted by the operator (Ctrl-C)")
        if self.publisher.due():
            self.control.publish(self.status())

    def status(self, status: str = "", reason: str = "") -> LiveStatus:
        fps = self.publisher.sent(self.rec.counts["can"] + self.rec.counts["serial"])
        live = self.rec.live(self.phase, self.writer.elapsed(), fps)
        return replace(live, status=status, reason=reason) if status else live


def _run(config: RigConfig, profile: Profile, profile_text: str, plan: ActuatorPlan,
         out_dir: Path, confirm: Callable[[], bool], progress: Callable[[str], None],
         control: RunControl | None = None) -> RunResult:
    path = Path(out_dir) / f"{time.strftime('%Y%m%dT%H%M%S')}_{profile.name}.h5"
    info = RunInfo(profile.name, profile_text, config.backend,
                   configuration_toml=_toml(config),
                   calibration={"table_sensor": {"scale_m": config.table_sensor.scale,
                                                 "offset_m": config.table_sensor.offset},
                                "mass_sensor": {"scale_m": config.mass_sensor.scale,
                                                "offset_m": config.mass_sensor.offset}})
    bus = open_bus(config)
    port = receivers = writer = rec = loop = None
    untrap: Callable[[], None] = _nothing
    switch_interval = sys.getswitchinterval()
    sys.setswitchinterval(min(switch_interval, RUN_SWITCH_INTERVAL_S))
    status, reason, bus_dead = "fail", "", False
    t_begin = time.monotonic()
    try:
        port = open_port(config)
        writer = RunWriter(path, info, channels=standard_channels(_sources(config)))
        start_unix = _start_unix(writer)
        rec = Recorder(writer, config, start_unix, writer.t0)
        receivers = Receivers(bus, port)
        loop = _Loop(rec, writer, control)
        progress(f"logging to {path}")
        _pump_until(receivers, rec, writer, writer.elapsed() + BASELINE_S, since=None, loop=loop)
        if not confirm():
            raise NotArmed("not armed: the operator did not confirm; nothing moved")
        untrap = _trap_ctrl_c(loop)  # from here until the file is closed
        _stream(bus, receivers, rec, writer, plan, progress, loop)
        status = "success"
    except (RunAborted, NotArmed) as exc:
        status, reason, bus_dead = "abort", str(exc), isinstance(exc, BusLost)
    except KeyboardInterrupt:
        status, reason = "abort", "interrupted by the operator (Ctrl-C)"
    except Exception as exc:
        status, reason = "fail", f"{type(exc).__name__}: {exc}".splitlines()[0]
        if not (isinstance(exc, DataError) and writer is not None and writer.closed):
            raise
        reason = str(exc)  # the writer failed (storage) and closed the file with every flushed row
    finally:
        try:
            send_safe_state(bus, config, bus_dead)
            if receivers is not None:
                receivers.close()
                if writer is not None and not writer.closed:
                    _drain(receivers, rec)  # rec exists whenever receivers do
                    rec.finish()
            if port is not None:
                port.close()
            bus.shutdown()
            if writer is not None:
                writer.close(status, reason)
            if loop is not None and control is not None:
                loop.phase = "ended"
                control.publish(loop.status(status, reason or status))
        finally:
            untrap()
            sys.setswitchinterval(switch_interval)
    return RunResult(path, status, reason, time.monotonic() - t_begin,
                     dict(rec.counts), dict(rec.lost), rec.crc_errors)


def _nothing() -> None:
    return None


def _trap_ctrl_c(loop: _Loop) -> Callable[[], None]:
    """Ctrl-C (SIGINT) sets a flag the loop turns into an orderly abort; returns the undo.

    A KeyboardInterrupt raised at an arbitrary point could land inside a run-file write;
    the flag is looked at once per pass (~1 ms). Only the main thread can take signals,
    so a run in a worker thread (the TUI) keeps the process's own handling.
    """
    if threading.current_thread() is not threading.main_thread():
        return _nothing

    def interrupted(signum: int, frame: object) -> None:
        loop.interrupted = True

    previous = signal.signal(signal.SIGINT, interrupted)
    # None: the old handler was not set from Python; the default is the closest we can restore
    return lambda: signal.signal(signal.SIGINT, previous if previous is not None
                                 else signal.SIG_DFL)


def _stream(bus: can.BusABC, receivers: Receivers, rec: Recorder, writer: RunWriter,
            plan: ActuatorPlan, progress: Callable[[str], None], loop: _Loop) -> None:
    """Send every timed message at its due time; drain and watch in between.

    Messages come lazily from the generator: a long run would otherwise allocate
    millions of objects up front, all at the instant the table starts.
    """
    messages: Iterator[Timed] = run_messages(plan)
    prefill = []
    timed = next(messages)
    while timed.due < 0:  # ENABLE and the prefill
        _send(bus, timed)
        prefill.append(timed)
        timed = next(messages)
    _send(bus, timed)  # START: the schedule's origin is the instant it went out
    start = time.monotonic()
    rec.start(plan, writer.elapsed())
    for t in prefill:  # logged now that START's time is known
        _log_setpoint(rec, t)
    since = rec.start_run_t
    loop.phase = "running"
    progress(f"START: {len(plan.t)} setpoints at {plan.rate:g} Hz, {plan.t[-1]:.2f} s")
    timed = next(messages, None)
    while timed is not None:
        now = time.monotonic() - start
        while timed is not None and timed.due <= now:
            _send(bus, timed)
            _log_setpoint(rec, timed)
            timed = next(messages, None)
        _pump(receivers, rec, writer, timeout=0.001)
        rec.check(writer.elapsed(), since)
        loop.tick()
    # STOP went out with the last setpoint, LEAD_SAMPLES before it is played
    loop.phase = "settling"
    _pump_until(receivers, rec, writer, writer.elapsed() + LEAD_SAMPLES / plan.rate + SETTLE_S,
                since=since, loop=loop)


def _send(bus: can.BusABC, timed: Timed) -> None:
    """Put one message on the bus (a command COMMAND_REPEATS times); a dead bus aborts."""
    frame = cm.to_can(timed.message)
    try:
        for _ in range(COMMAND_REPEATS if isinstance(timed.message, RigCommand) else 1):
            bus.send(frame)
    except (can.CanError, OSError) as exc:
        raise BusLost(f"CAN bus lost: cannot send: {one_line(exc)}") from None


def _log_setpoint(rec: Recorder, timed: Timed) -> None:
    m = timed.message
    if isinstance(m, Setpoint):
        rec.setpoint_sent(m.actuator, m.sequence, m.position)


def _pump(receivers: Receivers, rec: Recorder, writer: RunWriter, timeout: float) -> None:
    """Hand up to PUMP_BATCH queued items to the recorder; wait up to `timeout` s for one.

    Bounded, so that on a starved core the setpoints still go out on time: the
    queue absorbs a backlog of received frames, the actuators cannot absorb a gap.
    """
    q = receivers.queue
    try:
        item = q.get(timeout=timeout)
    except queue.Empty:
        writer.poll()
        return
    for _ in range(PUMP_BATCH):
        _handle(rec, item)
        if q.empty():
            break
        item = q.get_nowait()
    else:
        _handle(rec, item)
    writer.poll()


def _handle(rec: Recorder, item: Received) -> None:
    match item:
        case CanReceived(frame):
            rec.can_frame(frame)
        case SerialReceived(host_s, frames, stats):
            rec.serial_frames(host_s, frames, stats)
        case Idle(source, since):
            rec.idle(source, since)
        # a receiver died with its bus or port: the rig is blind
        case ReceiverFailed("can", error):
            raise BusLost(f"CAN bus lost: {type(error).__name__}: {one_line(error)}")
        case ReceiverFailed(_, error):
            raise RunAborted(f"serial port (mass sensor) lost: {type(error).__name__}: "
                             f"{one_line(error)}")


def _pump_until(receivers: Receivers, rec: Recorder, writer: RunWriter, until: float,
                since: float | None, loop: _Loop) -> None:
    while writer.elapsed() < until:
        _pump(receivers, rec, writer, timeout=0.005)
        if since is not None:
            rec.check(writer.elapsed(), since)
        loop.tick()


def _drain(receivers: Receivers, rec: Recorder) -> None:
    """What arrived before the receivers stopped still goes in the file."""
    while not receivers.queue.empty():
        item = receivers.queue.get_nowait()
        if not isinstance(item, ReceiverFailed):
            _handle(rec, item)


def _start_unix(writer: RunWriter) -> float:
    """Unix time of the writer's t = 0: the wall clock now minus the run time elapsed."""
    return time.time() - writer.elapsed()


def _sources(config: RigConfig) -> dict[str, str]:
    out = {"table_u": f"can:0x{cm.TABLE_SENSOR_ID:03X} TableSensor.Counts",
           "mass_x": f"serial:{config.serial.path} MassSensor.counts"}
    for i in cm.ACTUATORS:
        out[f"actuator_setpoint_{i}"] = f"can:0x{cm.SETPOINT_BASE + i:03X} ActuatorSetpoint{i}"
        out[f"actuator_feedback_{i}"] = f"can:0x{cm.FEEDBACK_BASE + i:03X} ActuatorFeedback{i}"
        out[f"actuator_status_{i}"] = (f"can:0x{cm.FEEDBACK_BASE + i:03X} Status | faults << 4")
    return out


def _toml(config: RigConfig) -> str:
    """The configuration file as read, plus where the bus and port really were this run."""
    try:
        text = Path(config.source).read_text(encoding="utf-8")
    except OSError:
        text = "# configuration given in memory\n"
    extra = config_to_dict(config)
    return (f"{text}\n# effective this run: can {extra['can']}, serial {extra['serial']}\n")
