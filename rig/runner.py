"""One run on the table: check, arm, stream setpoints, log both buses, always end safe.

Order (design.md §4.6–7):
1. `check_all` and the bus-load budget, before anything is opened: a refused
   profile never reaches the bus.
2. With `backend = "sim"` start `sim serve` (rig.simproc) unless given one.
3. Open the bus, the serial port and the run file; start the receivers; log a
   short baseline; `confirm()` arms (the CLI asks, or --yes).
4. Send the timed messages of rig.commands at their due times, keeping the
   queue of received frames drained into the run file; watch the watchdogs.
5. `finally`: SAFE_STATE on the bus, receivers stopped, port and bus closed,
   the run file closed with success / abort / fail and the reason.
"""

from __future__ import annotations

import logging
import queue
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import can

from rig import can_messages as cm
from rig.acquire import Receivers, open_bus, open_port
from rig.can_messages import Setpoint
from rig.commands import LEAD_SAMPLES, Timed, run_messages, safe_state
from rig.config import RigConfig, config_to_dict
from rig.errors import RigError
from rig.geometry import ActuatorPlan, actuator_plan
from rig.limits import check_plan
from rig.live import LiveStatus, Publisher, RunControl
from rig.profile import Profile
from rig.recorder import Recorder, RunAborted
from rig.runfile import RunInfo, RunWriter, standard_channels

log = logging.getLogger(__name__)

BASELINE_S = 0.3  # s logged before START: the sensors' rest values
SETTLE_S = 0.3  # s logged after STOP
PUMP_BATCH = 64  # received items handled between two looks at the setpoint schedule


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
    control: the e-stop flag and live listeners (rig.live); the stop is honoured from
    the moment the run file opens, within one pass of the loop (a few ms).
    """
    plan = actuator_plan(config, profile)
    check_plan(config, plan)  # LimitError: nothing opened, nothing sent
    cm.check_bus_load(config)
    if config.backend == "sim" and start_sim:
        from rig.simproc import SimProcess  # starts a process: only when asked for
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

    def tick(self) -> None:
        if self.control is not None and self.control.stop.is_set():
            raise RunAborted("emergency stop by the operator")
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
    status, reason = "fail", ""
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
        _stream(bus, receivers, rec, writer, plan, progress, loop)
        status = "success"
    except (RunAborted, NotArmed) as exc:
        status, reason = "abort", str(exc)
    except KeyboardInterrupt:
        status, reason = "abort", "interrupted by the operator (Ctrl-C)"
    except Exception as exc:
        status, reason = "fail", f"{type(exc).__name__}: {exc}".splitlines()[0]
        raise
    finally:
        _safe(bus)
        if receivers is not None:
            receivers.close()
            _drain(receivers, rec, writer)  # rec exists whenever receivers do
            if writer is not None and not writer.closed:
                rec.finish()
        if port is not None:
            port.close()
        bus.shutdown()
        if writer is not None:
            writer.close(status, reason)
        if loop is not None and control is not None:
            loop.phase = "ended"
            control.publish(loop.status(status, reason or status))
    return RunResult(path, status, reason, time.monotonic() - t_begin,
                     dict(rec.counts), dict(rec.lost), rec.crc_errors)


def _stream(bus: can.BusABC, receivers: Receivers, rec: Recorder, writer: RunWriter,
            plan: ActuatorPlan, progress: Callable[[str], None], loop: _Loop) -> None:
    """Send every timed message at its due time; drain and watch in between."""
    rec.plan = plan
    messages = list(run_messages(plan))
    k = 0
    while k < len(messages) and messages[k].due < 0:  # ENABLE and the prefill
        k = _send(bus, rec, messages[k], k)
    start = time.monotonic()
    rec.start_run_t = writer.elapsed()
    for j in range(k):  # prefill setpoints are logged now that START's time is known
        _log_setpoint(rec, messages[j])
    since = rec.start_run_t
    loop.phase = "running"
    progress(f"START: {len(plan.t)} setpoints at {plan.rate:g} Hz, {plan.t[-1]:.2f} s")
    while k < len(messages):
        now = time.monotonic() - start
        while k < len(messages) and messages[k].due <= now:
            k = _send(bus, rec, messages[k], k)
        _pump(receivers, rec, writer, timeout=0.001)
        rec.check(writer.elapsed(), since)
        loop.tick()
    # STOP went out with the last setpoint, LEAD_SAMPLES before it is played
    loop.phase = "settling"
    _pump_until(receivers, rec, writer, writer.elapsed() + LEAD_SAMPLES / plan.rate + SETTLE_S,
                since=since, loop=loop)


def _send(bus: can.BusABC, rec: Recorder, timed: Timed, k: int) -> int:
    bus.send(cm.to_can(timed.message))
    if rec.start_run_t is not None:
        _log_setpoint(rec, timed)
    return k + 1


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


def _handle(rec: Recorder, item: tuple) -> None:
    if item[0] == "can":
        rec.can_frame(item[1])
    elif item[0] == "serial":
        rec.serial_frames(item[1], item[2], item[3])
    else:
        raise RigError(f"{item[1]} receiver failed: {type(item[2]).__name__}: {item[2]}")


def _pump_until(receivers: Receivers, rec: Recorder, writer: RunWriter, until: float,
                since: float | None, loop: _Loop) -> None:
    while writer.elapsed() < until:
        _pump(receivers, rec, writer, timeout=0.005)
        if since is not None:
            rec.check(writer.elapsed(), since)
        loop.tick()


def _drain(receivers: Receivers, rec: Recorder, writer: RunWriter) -> None:
    """What arrived before the receivers stopped still goes in the file."""
    while not receivers.queue.empty():
        item = receivers.queue.get_nowait()
        if item[0] != "error":
            _handle(rec, item)


def _safe(bus: can.BusABC) -> None:
    """SAFE_STATE to every node; best effort (a dead bus cannot carry it)."""
    try:
        bus.send(cm.to_can(safe_state()))
    except (can.CanError, OSError, ValueError) as exc:  # a dead bus: the actuators' watchdog holds
        log.warning("could not send SAFE_STATE: %s", exc)


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
