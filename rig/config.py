"""The rig configuration: one TOML file, validated on load into frozen dataclasses, SI inside.

Each dimensional quantity states its unit in the file, `{ value = 12, unit = "in^2" }`,
so a bench written in SI and one in the report's units read alike; rates are plain
numbers in Hz under keys ending in `_hz` (rig.units has no frequency unit). Every
problem is a ConfigError naming the file and the dotted field, e.g.
`rig.toml: table.actuator[3].piston_area: must be > 0 in^2, got -2`. Actuators are
numbered from 1, in the file's order. `parse_config(config_to_dict(c), s) == c`.
A table is read field by field by rig.config_fields.Section.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from rig.config_fields import Section, show
from rig.errors import ConfigError
from rig.paths import data_file

N_ACTUATORS = 6
BACKENDS = ("sim", "hardware")
SERIAL_FRAME_BITS = 16 * 10  # design.md §2: 16-byte sensor frames, 8N1 = 10 bits a byte
MAX_CLASSICAL_BITRATE = 1_000_000
MAX_STROKE = 1.0  # m: ActuatorSetpoint.Position in data/isolator_rig.dbc carries ±1 m



@dataclass(frozen=True)
class Actuator:
    """One uniaxial actuator, SI. Extending it moves its platform attachment `position`
    (m, from the platform centre) along `line_of_action` (unit vector x, y); `stroke`
    (m) is ± from mid-stroke, where every actuator sits when the table is at u = 0."""

    index: int
    name: str
    line_of_action: tuple[float, float]
    position: tuple[float, float]
    piston_area: float  # m^2
    stroke: float  # m
    servovalve_flow: float  # m^3/s
    force_capacity: float  # N, the actuator's rating
    max_acceleration: float  # m/s^2

    @property
    def max_velocity(self) -> float:
        """m/s: the servovalve's rated flow cannot fill the piston any faster."""
        return self.servovalve_flow / self.piston_area


@dataclass(frozen=True)
class Table:
    """The platform, its load and its six actuators, SI."""

    actuators: tuple[Actuator, ...]
    platform_side: float  # m
    platform_mass: float  # kg
    payload_mass: float  # kg
    supply_pressure: float  # Pa

    @property
    def moving_mass(self) -> float:
        """kg: platform plus payload, the payload taken as rigidly coupled (an upper bound)."""
        return self.platform_mass + self.payload_mass

    @property
    def lines_of_action(self) -> np.ndarray:
        """(6, 2) unit vectors, row i for actuator i + 1."""
        return np.array([a.line_of_action for a in self.actuators])

    @property
    def positions(self) -> np.ndarray:
        """(6, 2) attachment points (m) from the platform centre."""
        return np.array([a.position for a in self.actuators])


@dataclass(frozen=True)
class Sensor:
    """An optical displacement sensor: position (m) = counts × scale + offset."""

    scale: float  # m per count, non-zero (negative if the sensor counts the other way)
    offset: float  # m
    noise_rms: float  # m, 1-sigma white noise of one sample
    sample_rate: float  # Hz

    def to_si(self, counts: ArrayLike) -> np.ndarray:
        """Position (m), same shape as `counts`."""
        return np.asarray(counts, dtype=float) * self.scale + self.offset

    def to_counts(self, position: ArrayLike) -> np.ndarray:
        """Nearest counts (int64) for `position` (m)."""
        return np.rint((np.asarray(position, dtype=float) - self.offset) / self.scale).astype(
            np.int64)


@dataclass(frozen=True)
class CanBus:
    """Where the CAN bus is: python-can `interface`, `channel`, `bitrate` (bit/s) and
    `extra` keyword arguments for can.Bus; `load_budget` is the worst-case fraction
    of the bitrate the cyclic traffic may take."""

    interface: str
    channel: str | int
    bitrate: int
    load_budget: float
    extra: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))

    def bus_kwargs(self) -> dict[str, Any]:
        """Keyword arguments for `can.Bus(**kwargs)`."""
        return {"interface": self.interface, "channel": self.channel, "bitrate": self.bitrate,
                **self.extra}


@dataclass(frozen=True)
class SerialPort:
    """The mass sensor's serial port: device path and baud rate (bit/s)."""

    path: str
    baud: int


@dataclass(frozen=True)
class Rates:
    """Cyclic rates (Hz): setpoints and feedback per actuator, heartbeats per node."""

    setpoint: float
    feedback: float
    heartbeat: float


@dataclass(frozen=True)
class RigConfig:
    """The whole rig configuration, SI. `source` names the file (not compared)."""

    backend: str
    table: Table
    table_sensor: Sensor
    mass_sensor: Sensor
    can: CanBus
    serial: SerialPort
    rates: Rates
    source: str = field(default="<memory>", compare=False)


def load_config(path: str | Path | None = None) -> RigConfig:
    """Read and validate a rig TOML file (default: data/rig.toml)."""
    path = Path(path) if path is not None else data_file("rig.toml")
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(str(path), "", "no such configuration file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(str(path), "", f"cannot read: {e}") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(str(path), "", f"not valid TOML: {e}") from None
    except RecursionError:  # tomllib recurses per nesting level: a hostile file
        raise ConfigError(str(path), "", "not valid TOML: nested too deeply") from None
    return parse_config(doc, str(path))


def parse_config(doc: Mapping[str, Any], source: str) -> RigConfig:
    """Build a RigConfig from a parsed TOML document; ConfigError names the field."""
    top = Section(doc, source, "")
    backend = top.choice("backend", BACKENDS)
    table = _table(top.section("table"))
    sensors = top.section("sensors")
    table_sensor, mass_sensor = _sensor(sensors.section("table")), _sensor(sensors.section("mass"))
    sensors.close()
    can, serial, rates = _can(top.section("can")), _serial(top.section("serial")), _rates(top)
    top.close()
    needed = mass_sensor.sample_rate * SERIAL_FRAME_BITS
    if needed > serial.baud:
        raise ConfigError(source, "serial.baud", f"{serial.baud} baud carries "
                          f"{serial.baud / SERIAL_FRAME_BITS:.0f} sensor frames/s, the mass "
                          f"sensor sends {mass_sensor.sample_rate:g}/s")
    return RigConfig(backend, table, table_sensor, mass_sensor, can, serial, rates, source)


def config_to_dict(config: RigConfig) -> dict[str, Any]:
    """The TOML document of `config`, in SI with the units stated."""
    t = config.table

    def q(value: Any, unit: str) -> dict[str, Any]:
        return {"value": list(value) if isinstance(value, tuple) else value, "unit": unit}

    def sensor(s: Sensor) -> dict[str, Any]:
        return {"scale": q(s.scale, "m"), "offset": q(s.offset, "m"),
                "noise_rms": q(s.noise_rms, "m"), "sample_rate_hz": s.sample_rate}

    actuators = [{"index": a.index, "name": a.name, "line_of_action": list(a.line_of_action),
                  "position": q(a.position, "m"), "piston_area": q(a.piston_area, "m^2"),
                  "stroke": q(a.stroke, "m"), "servovalve_flow": q(a.servovalve_flow, "m^3/s"),
                  "force_capacity": q(a.force_capacity, "N"),
                  "max_acceleration": q(a.max_acceleration, "m/s^2")} for a in t.actuators]
    return {
        "backend": config.backend,
        "table": {"platform_side": q(t.platform_side, "m"),
                  "platform_mass": q(t.platform_mass, "kg"),
                  "payload_mass": q(t.payload_mass, "kg"),
                  "supply_pressure": q(t.supply_pressure, "Pa"), "actuator": actuators},
        "sensors": {"table": sensor(config.table_sensor), "mass": sensor(config.mass_sensor)},
        "can": {"interface": config.can.interface, "channel": config.can.channel,
                "bitrate": config.can.bitrate, "load_budget": config.can.load_budget,
                "extra": dict(config.can.extra)},
        "serial": {"path": config.serial.path, "baud": config.serial.baud},
        "rates": {"setpoint_hz": config.rates.setpoint, "feedback_hz": config.rates.feedback,
                  "heartbeat_hz": config.rates.heartbeat},
    }


def _table(s: Section) -> Table:
    side = s.quantity("platform_side", "length")
    masses = [s.quantity(k, "mass") for k in ("platform_mass", "payload_mass")]
    pressure = s.quantity("supply_pressure", "pressure")
    raw = s.get("actuator")
    if not isinstance(raw, list) or len(raw) != N_ACTUATORS:
        got = f"{len(raw)}" if isinstance(raw, list) else show(raw)
        s.fail("actuator", f"needs exactly {N_ACTUATORS} [[table.actuator]] tables, got {got}")
    actuators = tuple(_actuator(Section(a, s.source, f"{s.path}.actuator[{i}]"), i, side)
                      for i, a in enumerate(raw, start=1))
    s.close()
    _check_layout(actuators, s)
    return Table(actuators, side, masses[0], masses[1], pressure)


def _actuator(s: Section, i: int, side: float) -> Actuator:
    index = s.integer("index", low=1)
    if index != i:
        s.fail("index", f"must be {i}: actuators are listed in order 1..{N_ACTUATORS}, got {index}")
    name = s.string("name")
    direction = s.vector("line_of_action")
    norm = math.hypot(*direction)
    if abs(norm - 1.0) > 1e-3:
        s.fail("line_of_action", f"must be a unit vector [x, y], got length {norm:.4g}")
    position = s.vector("position", "length")
    if max(abs(c) for c in position) > side / 2 * (1 + 1e-9):
        s.fail("position", f"({position[0]:g}, {position[1]:g}) m lies off the "
               f"{side:g} m square platform")
    kw = {k: s.quantity(k, kind) for k, kind in (
        ("piston_area", "area"), ("stroke", "length"), ("servovalve_flow", "flow"),
        ("force_capacity", "force"), ("max_acceleration", "acceleration"))}
    if kw["stroke"] > MAX_STROKE:
        s.fail("stroke", f"must be <= {MAX_STROKE:g} m, the setpoint message's range")
    s.close()
    # normalise a hand-typed 0.7071 but keep a unit vector as given, so files round-trip
    unit = direction if abs(norm - 1.0) < 1e-12 else (direction[0] / norm, direction[1] / norm)
    return Actuator(index=index, name=name, line_of_action=unit, position=position, **kw)


def _check_layout(actuators: tuple[Actuator, ...], s: Section) -> None:
    """The six must hold the platform in x, y and yaw, or some motion is unguided."""
    n = np.array([a.line_of_action for a in actuators])
    r = np.array([a.position for a in actuators])
    equilibrium = np.vstack([n[:, 0], n[:, 1], r[:, 0] * n[:, 1] - r[:, 1] * n[:, 0]])
    rank = np.linalg.matrix_rank(equilibrium / np.maximum(
        np.abs(equilibrium).max(axis=1, keepdims=True), 1e-12))
    if rank < 3:
        s.fail("actuator", f"the lines of action hold only {rank} of x, y and yaw; need all 3")


def _sensor(s: Section) -> Sensor:
    scale = s.quantity("scale", "length", low=None)
    if scale == 0:
        s.fail("scale", "must not be 0")
    result = Sensor(scale=scale, offset=s.quantity("offset", "length", low=None),
                    noise_rms=s.quantity("noise_rms", "length", strict=False),
                    sample_rate=s.number("sample_rate_hz", low=0.0, high=100_000.0))
    s.close()
    return result


def _can(s: Section) -> CanBus:
    interface = s.string("interface")
    channel = s.get("channel")
    if isinstance(channel, bool) or not isinstance(channel, (str, int)) or channel == "":
        s.fail("channel", f"must be a non-empty string or an integer, got {show(channel)}")
    bitrate = s.integer("bitrate", low=1, high=MAX_CLASSICAL_BITRATE)
    budget = s.number("load_budget", low=0.0, high=1.0)
    extra = s.get("extra", {})
    if not isinstance(extra, dict):
        s.fail("extra", f"must be a table of can.Bus keyword arguments, got {show(extra)}")
    clash = sorted(set(extra) & {"interface", "channel", "bitrate"})
    if clash:
        s.fail(f"extra.{clash[0]}", "set it in [can] itself, not in [can.extra]")
    if interface == "socketcand" and not {"host", "port"} <= set(extra):
        s.fail("extra", "the socketcand interface needs host and port")
    s.close()
    return CanBus(interface, channel, bitrate, budget, MappingProxyType(dict(extra)))


def _serial(s: Section) -> SerialPort:
    result = SerialPort(s.string("path"), s.integer("baud", low=1))
    s.close()
    return result


def _rates(top: Section) -> Rates:
    s = top.section("rates")
    result = Rates(*(s.number(k, low=0.0, high=10_000.0)
                     for k in ("setpoint_hz", "feedback_hz", "heartbeat_hz")))
    s.close()
    return result
