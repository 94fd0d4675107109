"""Faults the simulated rig can inject, configured per test or per `sim serve --fault`.

In-process tests set faults on a running `SimRig` directly (its `server.faults`,
`mass_sensor.faults`, `stick_valve`, `stall_feedback`, …: sim.rig_sim). A
subprocess `sim serve` takes them on its command line, `--fault NAME=VALUE`,
parsed here into one `SimFaults`:

    can_drop=P  can_duplicate=P  can_reorder=P  can_seed=N   per-frame probabilities
    can_error_burst_after=N  can_disconnect_after=N           after N frames on the bus
    serial_garbage=P  serial_bitflip=P  serial_truncate=P      per-frame probabilities
    serial_stop_after=N  serial_close_after=N                  after N sensor frames
    stuck_valve=A@S  stalled_feedback=A@S                      actuator A, S s after its START

Like the undeclared effects (sim.effects), nothing here is told to the rig: it has
to notice.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from rig.errors import ConfigError
from sim.pty_sensor import SerialFaults
from sim.socketcand_server import BusFaults


@dataclass
class ActuatorFault:
    """A fault of actuator `actuator` (1–6) beginning `after_start_s` after its START."""

    actuator: int
    after_start_s: float
    armed: bool = False  # set by the sim once injected (each fault fires once)


@dataclass(frozen=True)
class SimFaults:
    """Every fault the simulated rig starts with; the default injects nothing."""

    bus: BusFaults = field(default_factory=BusFaults)
    serial: SerialFaults = field(default_factory=SerialFaults)
    stuck_valve: ActuatorFault | None = None
    stalled_feedback: ActuatorFault | None = None


_BUS = {"can_drop": "drop_prob", "can_duplicate": "duplicate_prob",
        "can_reorder": "reorder_prob", "can_seed": "seed",
        "can_error_burst_after": "error_burst_after", "can_disconnect_after": "disconnect_after"}
_SERIAL = {"serial_garbage": "garbage_prob", "serial_bitflip": "bitflip_prob",
           "serial_truncate": "truncate_prob", "serial_stop_after": "stop_after_frames",
           "serial_close_after": "close_after_frames"}
_ACTUATOR = ("stuck_valve", "stalled_feedback")
NAMES = (*_BUS, *_SERIAL, *_ACTUATOR)


def parse_faults(specs: list[str]) -> SimFaults:
    """`NAME=VALUE` strings (module doc) as one SimFaults; ConfigError names a bad one."""
    faults = SimFaults()
    for spec in specs:
        name, sep, value = spec.partition("=")
        name = name.strip()
        if not sep or name not in NAMES:
            raise ConfigError("--fault", spec, f"expected NAME=VALUE with NAME one of "
                              f"{', '.join(NAMES)}")
        if name in _BUS:
            faults = replace(faults, bus=replace(faults.bus, **{_BUS[name]: _value(
                spec, value, _BUS[name])}))
        elif name in _SERIAL:
            faults = replace(faults, serial=replace(faults.serial, **{_SERIAL[name]: _value(
                spec, value, _SERIAL[name])}))
        else:
            faults = replace(faults, **{name: _actuator(spec, value)})
    return faults


def _value(spec: str, text: str, field_name: str) -> float | int:
    try:
        v = float(text) if field_name.endswith("prob") else int(text)
    except ValueError:
        raise ConfigError("--fault", spec, f"{text!r} is not a number") from None
    if field_name.endswith("prob") and not 0.0 <= v <= 1.0:
        raise ConfigError("--fault", spec, f"a probability must be in 0..1, got {v}")
    if not field_name.endswith("prob") and v < 0:
        raise ConfigError("--fault", spec, f"must be >= 0, got {v}")
    return v


def _actuator(spec: str, text: str) -> ActuatorFault:
    actuator, _, after = text.partition("@")
    try:
        fault = ActuatorFault(int(actuator), float(after or 0.0))
    except ValueError:
        raise ConfigError("--fault", spec, "expected ACTUATOR@SECONDS, e.g. 3@0.5") from None
    if not 1 <= fault.actuator <= 6 or not 0.0 <= fault.after_start_s < 3600.0:
        raise ConfigError("--fault", spec, "actuator must be 1..6 and seconds in 0..3600")
    return fault
