"""The whole simulated rig in one object: CAN bus, actuators, plant, table and mass sensors.

`SimRig(config)` starts the socketcand server on a free loopback port, the six
actuator controllers on it, the plant (sim.plant) and the mass sensor on a pty;
`close()` stops them all. One loop thread paces the plant in real time and
sends the table sensor samples (1 kHz), the actuator feedback and the heartbeats.

Sensors: white noise of the configured rms, then whole counts (quantisation);
each device clock runs at its own small offset and drift from the host's.
`record_truth=True` keeps the noise-free value behind every sample sent, with
its host time, for tests; it is never sent to the rig.

Actuator feedback is measured at its own scheduled instant (100 Hz) from the
plant's history and carries the servo tick of that instant (sim.devices), so a
stalled loop sends late frames with the right content, as a real controller's
transmit queue would. Fault injection (sim.faults): `faults=` at construction
(what `sim serve --fault` sets), or live: `server.faults`, `mass_sensor.faults`,
`stick_valve`, `stall_feedback`, `server.disconnect_clients()`, `server.stall(s)`.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Self

import can
import numpy as np

from analysis.model.isolator import IsolatorModel
from analysis.model.report_constants import report_model
from rig.config import RigConfig, Sensor
from rig.geometry import x_components
from rig.wire import can_messages as cm
from rig.wire.can_messages import NodeState
from sim.devices import ActuatorController, heartbeat, table_sample
from sim.effects import Effect, with_effects
from sim.faults import SimFaults
from sim.plant import Plant, warm_up
from sim.pty_sensor import PtySensor
from sim.socketcand_server import SocketcandServer

log = logging.getLogger(__name__)

LOOP_S = 0.002  # s between the loop's wake-ups


@dataclass(frozen=True)
class SensorClock:
    """A device clock: reads offset_s + (t − t0)(1 + drift_ppm·1e-6) at host time t."""

    offset_s: float
    drift_ppm: float


@dataclass
class Truth:
    """Noise-free values behind the samples sent: per sensor, lists of (timestamp_us, host t, m)."""

    table: list[tuple[int, float, float]] = field(default_factory=list)
    mass: list[tuple[int, float, float]] = field(default_factory=list)


class SimRig:
    """The simulated rig of `config`, running from construction until `close()`."""

    def __init__(self, config: RigConfig, seed: int = 0, effects: tuple[Effect, ...] = (),
                 model: IsolatorModel | None = None, record_truth: bool = False,
                 table_clock: SensorClock = SensorClock(3.0, 25.0),
                 mass_clock: SensorClock = SensorClock(7.0, -40.0),
                 faults: SimFaults | None = None) -> None:
        self.config, self.effects = config, effects
        self.faults = faults or SimFaults()
        self._rng = np.random.default_rng(seed)
        self._rng_lock = threading.Lock()
        self._noise: list[float] = []
        self._noise_i = 0
        self.truth = Truth() if record_truth else None
        self.table_clock = table_clock
        rate = config.rates.setpoint
        self.actuators = [ActuatorController(a.index, rate, clock=time.monotonic)
                          for a in config.table.actuators]
        plant_model = with_effects(model or report_model("average"), effects)
        # compiled before the clock starts: the plant's grid begins at t0, and a cold
        # compile after it (90 s on a 2-core EPYC) left the first run's sensors
        # catching up on that much history, silent past the rig's liveness limit
        warm_up(plant_model)
        t0 = time.monotonic()
        self.t0, self.wall0 = t0, time.time() - (time.monotonic() - t0)
        self.plant = Plant(plant_model, self._targets, x_components(config),
                           np.array([a.max_velocity for a in config.table.actuators]), t0)
        self.plant.advance_to(t0 + 0.05)
        self.server = SocketcandServer(bus_name=str(config.can.channel), faults=self.faults.bus)
        for a in self.actuators:
            self.server.attach(a)
        self._mass_k = 0  # the sensor thread starts sampling at once: set its inputs first
        self._mass_clock = mass_clock
        self.mass_sensor = PtySensor(self._mass_counts, rate_hz=config.mass_sensor.sample_rate,
                                     baud=config.serial.baud, offset_s=mass_clock.offset_s,
                                     drift_ppm=mass_clock.drift_ppm, faults=self.faults.serial)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="sim-rig", daemon=True)
        self._thread.start()

    @property
    def can_port(self) -> int:
        return self.server.port

    @property
    def pty_path(self) -> str:
        return self.mass_sensor.path

    def stick_valve(self, actuator: int, at: float | None = None) -> float:
        """Fault: actuator `actuator`'s servovalve sticks at host time `at` (default now)
        while its controller goes on claiming RUNNING; returns when it took effect."""
        return self.plant.stick(actuator - 1, time.monotonic() if at is None else at)

    def stall_feedback(self, actuator: int, at: float | None = None) -> float:
        """Fault: actuator `actuator` sends no more feedback from host time `at` (default
        now); it goes on following its setpoints. Returns `at`."""
        at = time.monotonic() if at is None else at
        self.actuators[actuator - 1].feedback_muted_from = at
        return at

    def wall(self, t: float) -> float:
        """Wall-clock time (s, Unix) of host monotonic time `t`."""
        return self.wall0 + (t - self.t0)

    def close(self) -> None:
        """Stop the loop, the sensor and the bus; idempotent."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        self.mass_sensor.close()
        self.server.shutdown()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the plant's inputs and the sensors' outputs ------------------------------------

    def _targets(self, t: float) -> np.ndarray:
        targets = np.array([a.target(t) for a in self.actuators])
        self._arm_faults(t)
        return targets

    def _arm_faults(self, t: float) -> None:
        """Actuator faults set at construction begin a given time after that actuator's START."""
        for fault, inject in ((self.faults.stuck_valve, self.stick_valve),
                              (self.faults.stalled_feedback, self.stall_feedback)):
            if fault is None or fault.armed:
                continue
            started = self.actuators[fault.actuator - 1].started_at
            if started is not None and t >= started + fault.after_start_s:
                fault.armed = True
                inject(fault.actuator, t)

    def _noisy_counts(self, value: float, sensor: Sensor) -> int:
        """White noise, then whole counts; plain floats (numpy scalars cost ~10 µs here)."""
        with self._rng_lock:
            if self._noise_i >= len(self._noise):
                self._noise, self._noise_i = self._rng.standard_normal(4096).tolist(), 0
            z = self._noise[self._noise_i]
            self._noise_i += 1
        return round((value + z * sensor.noise_rms - sensor.offset) / sensor.scale)

    def _mass_counts(self, t: float) -> float:
        """The mass sensor's reading at host time `t` (pty sensor thread)."""
        x = self._mass_true(t)
        if self.truth is not None:
            k = self._mass_k
            rate = self.config.mass_sensor.sample_rate
            ts = round(1e6 * (self._mass_clock.offset_s + k / rate)) % (1 << 32)
            self.truth.mass.append((ts, self.wall(t), x))
        self._mass_k += 1
        return float(self._noisy_counts(x, self.config.mass_sensor))

    def _mass_true(self, t: float) -> float:
        """x as the mass sensor sees it, with any sensor effects (undeclared) applied."""
        delay = sum(e.value for e in self.effects if e.name == "sensor_delay")
        gain = 1.0 + sum(e.value for e in self.effects if e.name == "sensor_gain")
        return gain * self.plant.at(t - delay)[1]

    # -- the loop thread ------------------------------------------------------------------

    def _loop(self) -> None:
        try:
            self._run()
        except Exception:  # logged: a dead plant shows as silent sensors on the rig side
            log.exception("simulated rig loop failed")

    def _run(self) -> None:
        dt = self.plant.dt
        sensor_dt = 1.0 / self.config.table_sensor.sample_rate
        feedback_dt, beat_dt = 1.0 / self.config.rates.feedback, 1.0 / self.config.rates.heartbeat
        k_sensor, k_feedback, k_beat = 0, 0, 0
        start = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            self.plant.advance_to(now + self.plant.chunk * dt)  # one chunk ahead
            out: list[can.Message] = []
            while start + k_sensor * sensor_dt <= now:
                out.append(self._table_frame(start + k_sensor * sensor_dt, k_sensor))
                k_sensor += 1
            while start + k_feedback * feedback_dt <= now:
                out += self._feedback(start + k_feedback * feedback_dt)
                k_feedback += 1
            while start + k_beat * beat_dt <= now:
                out += self._heartbeats(k_beat)
                k_beat += 1
            if out:  # the actuators do not hear each other, so no origin is needed
                self.server.broadcast_many(out)
            # wake every LOOP_S, not every sample: each wake-up costs ~50 µs of a shared
            # core; the samples keep their own timestamps, so batching moves no data in time
            self._stop.wait(max(0.0, now + LOOP_S - time.monotonic()))

    def _table_frame(self, t: float, k: int) -> can.Message:
        u = self.plant.at(t)[0]
        c = self.table_clock
        ts = round(1e6 * (c.offset_s + (t - self.t0) * (1.0 + c.drift_ppm * 1e-6)))
        counts = self._noisy_counts(u, self.config.table_sensor)
        if self.truth is not None:
            self.truth.table.append((ts % (1 << 32), self.wall(t), u))
        return table_sample(counts, k, ts)

    def _feedback(self, t: float) -> list[can.Message]:
        """Each actuator's feedback measured at `t` (s, past: the plant's history)."""
        ext = self.plant.extensions(t)
        return [a.feedback(t, float(ext[a.index - 1])) for a in self.actuators
                if a.sends_feedback(t)]

    def _heartbeats(self, k: int) -> list[can.Message]:
        beats = [heartbeat(a.index, k, a.state) for a in self.actuators]
        return beats + [heartbeat(cm.NODE_TABLE_SENSOR, k, NodeState.RUNNING)]

    def truth_arrays(self) -> dict[str, np.ndarray]:
        """The recorded truth and the plant's grid as arrays (times as Unix wall time, s)."""
        out: dict[str, np.ndarray] = {}
        for name in ("table", "mass"):
            rows = np.array(getattr(self.truth, name) if self.truth else [], float).reshape(-1, 3)
            out[f"{name}_timestamp_us"], out[f"{name}_time"], out[f"{name}_value"] = rows.T
        h = self.plant.history()
        out["plant_time"] = self.wall0 + (h["t"] - self.t0)
        out["plant_u"], out["plant_x"] = h["u"], h["x"]
        return out
