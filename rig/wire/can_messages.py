"""The rig's CAN messages, typed: dataclasses in, dataclasses out, through data/isolator_rig.dbc.

The DBC is the one description of the wire (cantools loads it once); this module
maps its signals to dataclasses and back (their load on the bus: rig.wire.bus_load).
Classical CAN, 11-bit ids, 8 data bytes a frame. Ids by priority (lower wins arbitration):

    0x010        RigCommand          rig → all        enable, start at sample, stop, safe state
    0x101–0x106  ActuatorSetpoint<i> rig → actuator i  position from mid-stroke, 1 µm
    0x150        TableSensor         sensor → rig     counts, sequence, device µs
    0x201–0x206  ActuatorFeedback<i> actuator i → rig  position, state, fault bits
    0x701–0x708  Heartbeat<node>     node → all       node id, counter, state

The rig's mass sensor is on the serial port, not on this bus. A bench that puts a mass
sensor on CAN describes it in its own DBC (`bench_database`: the rig's messages plus a
`MassSensor` laid out as TableSensor), and the same functions decode it with `db=`.

Counters are the low bits of an unbounded count: encode wraps, `unwrap` restores.
"""

from __future__ import annotations

import enum
import functools
import os
from dataclasses import dataclass

import can
import cantools
from cantools.database.can import Database, Message

from rig.errors import DataError
from rig.paths import data_file

COMMAND_ID = 0x010
#: the message a bench DBC may add for a mass sensor on CAN (signals as TableSensor's)
MASS_SENSOR = "MassSensor"
_SENSOR_SIGNALS = ("Counts", "Sequence", "TimestampUs")
SETPOINT_BASE = 0x100
TABLE_SENSOR_ID = 0x150
FEEDBACK_BASE = 0x200
HEARTBEAT_BASE = 0x700
ACTUATORS = range(1, 7)
NODE_RIG = 7
NODE_TABLE_SENSOR = 8
NODES = range(1, 9)  # actuators 1–6 are nodes 1–6
#: width (bits) of each wrapping counter on the wire
SETPOINT_SEQUENCE_BITS = FEEDBACK_SEQUENCE_BITS = 16
SENSOR_SEQUENCE_BITS = COUNTER_BITS = 8
TIMESTAMP_BITS = 32


class NodeState(enum.IntEnum):
    """State a node reports in its heartbeat and an actuator in its feedback."""

    BOOT = 0
    DISABLED = 1
    ENABLED = 2
    RUNNING = 3
    SAFE_STATE = 4
    FAULT = 5


class CommandKind(enum.IntEnum):
    """What a RigCommand asks of every node."""

    ENABLE = 1
    START = 2  # begin following setpoints at `start_sample`
    STOP = 3  # hold the last setpoint
    SAFE_STATE = 4  # valves to the safe position, regardless of setpoints


class Fault(enum.IntFlag):
    """Fault bits of ActuatorFeedback."""

    NONE = 0
    FOLLOWING_ERROR = 1
    STROKE_LIMIT = 2
    VALVE = 4
    WATCHDOG_HOLD = 8  # the rig's heartbeat stopped; the actuator holds position


_FAULT_SIGNALS = {Fault.FOLLOWING_ERROR: "FaultFollowingError",
                  Fault.STROKE_LIMIT: "FaultStrokeLimit", Fault.VALVE: "FaultValve",
                  Fault.WATCHDOG_HOLD: "FaultWatchdogHold"}


@dataclass(frozen=True)
class Setpoint:
    """Actuator `actuator` (1–6) to `position` (m from mid-stroke) at setpoint `sequence`."""

    actuator: int
    sequence: int
    position: float


@dataclass(frozen=True)
class Feedback:
    """Actuator `actuator`'s measured `position` (m from mid-stroke), state and faults."""

    actuator: int
    sequence: int
    position: float
    status: NodeState
    faults: Fault = Fault.NONE


@dataclass(frozen=True)
class TableSample:
    """One table sensor sample: raw `counts` (config scale → m) at device `timestamp_us`."""

    counts: int
    sequence: int
    timestamp_us: int


@dataclass(frozen=True)
class MassSample:
    """One mass sensor sample on CAN (a bench DBC's MassSensor; the rig's own is serial)."""

    counts: int
    sequence: int
    timestamp_us: int


@dataclass(frozen=True)
class Heartbeat:
    """Node `node` (1–8) is alive in `state`; `counter` counts its heartbeats."""

    node: int
    counter: int
    state: NodeState


@dataclass(frozen=True)
class RigCommand:
    """A rig command to every node; `counter` lets a node drop a repeated frame."""

    command: CommandKind
    counter: int = 0
    start_sample: int = 0  # START: the full setpoint sample index to begin at


RigMessage = Setpoint | Feedback | TableSample | MassSample | Heartbeat | RigCommand


@functools.cache
def database() -> Database:
    """The rig's DBC, parsed once."""
    return cantools.database.load_file(str(data_file("isolator_rig.dbc")), strict=True)


def bench_database(path: str | os.PathLike[str]) -> Database:
    """A DBC given by the user, checked to describe the rig's messages exactly as ours does.

    It may add messages: a `MassSensor` (decoded as MassSample) and other nodes' (kept
    raw). DataError names the file and the first difference.
    """
    try:
        db = cantools.database.load_file(str(path), database_format="dbc", strict=True)
    except OSError as e:
        raise DataError(f"{path}: cannot read the DBC: {e.strerror or e}") from None
    except (cantools.database.Error, ValueError, UnicodeDecodeError) as e:  # syntax, overlaps
        raise DataError(f"{path}: not a readable DBC: {type(e).__name__}: {e}") from None
    for ours in database().messages:
        try:
            theirs = db.get_message_by_name(ours.name)
        except KeyError:
            raise DataError(f"{path}: no message {ours.name} (0x{ours.frame_id:03X}) of the "
                            "rig's DBC") from None
        if _layout(theirs) != _layout(ours):
            raise DataError(f"{path}: message {ours.name} differs from the rig's DBC "
                            f"(id, length or signals)")
    names = {m.name for m in db.messages}
    if MASS_SENSOR in names:
        mass = db.get_message_by_name(MASS_SENSOR)
        have = {s.name for s in mass.signals}
        if not set(_SENSOR_SIGNALS) <= have or mass.is_extended_frame:
            raise DataError(f"{path}: {MASS_SENSOR} needs an 11-bit id and signals "
                            f"{', '.join(_SENSOR_SIGNALS)}; it has 0x{mass.frame_id:X} and "
                            f"{', '.join(sorted(have))}")
    return db


def _layout(m: Message) -> tuple:
    return (m.frame_id, m.is_extended_frame, m.length, sorted(
        (s.name, s.start, s.length, s.byte_order, s.is_signed, s.scale, s.offset)
        for s in m.signals))


def known_ids(db: Database | None = None) -> frozenset[int]:
    """Every arbitration id of a message the rig decodes (for receive filters): all of the
    rig's DBC, or of `db` those that are the rig's or its MassSensor."""
    ours = {m.name for m in database().messages} | {MASS_SENSOR}
    messages = (database() if db is None else db).messages
    return frozenset(m.frame_id for m in messages if m.name in ours)


def encode(msg: RigMessage, db: Database | None = None) -> tuple[int, bytes]:
    """(arbitration id, 8 data bytes) of `msg` by the rig's DBC or `db`; ValueError names an
    out-of-range field."""
    db = database() if db is None else db
    frame_id, signals = _signals(msg, db)
    try:
        data = db.get_message_by_frame_id(frame_id).encode(signals, strict=True)
    except (cantools.database.EncodeError, ValueError, OverflowError) as e:  # range, NaN
        raise ValueError(f"cannot encode {msg}: {e}") from None
    return frame_id, data


def decode(arbitration_id: int, data: bytes, db: Database | None = None) -> RigMessage:
    """The message in a frame, by the rig's DBC or `db`; DataError for an unknown id, a
    message that is not the rig's, or malformed data."""
    try:
        message = (database() if db is None else db).get_message_by_frame_id(arbitration_id)
    except KeyError:
        raise DataError(f"CAN id 0x{arbitration_id:03X} is not in the rig's DBC") from None
    try:
        s = message.decode(bytes(data), decode_choices=False, allow_excess=False)
        return _build(message.name, arbitration_id, s)
    except (cantools.database.DecodeError, ValueError) as e:
        raise DataError(f"{message.name} (0x{arbitration_id:03X}) {bytes(data).hex()}: {e}") \
            from None


def to_can(msg: RigMessage, db: Database | None = None) -> can.Message:
    """A python-can frame (11-bit id) carrying `msg`."""
    frame_id, data = encode(msg, db)
    return can.Message(arbitration_id=frame_id, data=data, is_extended_id=False)


def from_can(frame: can.Message, db: Database | None = None) -> RigMessage:
    """The message in a python-can frame; DataError if it is not one of ours."""
    if frame.is_extended_id or frame.is_remote_frame or frame.is_fd:
        raise DataError(f"CAN frame 0x{frame.arbitration_id:X} is not a classical 11-bit "
                        "data frame")
    return decode(frame.arbitration_id, frame.data, db)


def unwrap(previous: int, counter: int, bits: int) -> int:
    """The full count nearest after `previous` whose low `bits` are `counter`.

    E.g. unwrap(65535, 1, 16) == 65537. Assumes fewer than 2**bits counts were lost.
    """
    modulus = 1 << bits
    return previous + (counter - previous) % modulus


def _check_index(name: str, value: int, allowed: range) -> None:
    if value not in allowed:
        raise ValueError(f"{name} must be in {allowed.start}..{allowed.stop - 1}, got {value}")


def _signals(msg: RigMessage, db: Database) -> tuple[int, dict[str, float | int]]:
    """Arbitration id and cantools signal values of `msg` (counters wrapped)."""
    if isinstance(msg, Setpoint):
        _check_index("actuator", msg.actuator, ACTUATORS)
        return SETPOINT_BASE + msg.actuator, {
            "ActuatorIndex": msg.actuator, "Position": msg.position,
            "Sequence": msg.sequence % (1 << SETPOINT_SEQUENCE_BITS)}
    if isinstance(msg, Feedback):
        _check_index("actuator", msg.actuator, ACTUATORS)
        faults = {sig: int(bool(msg.faults & bit)) for bit, sig in _FAULT_SIGNALS.items()}
        return FEEDBACK_BASE + msg.actuator, {
            "ActuatorIndex": msg.actuator, "Position": msg.position, "Status": int(msg.status),
            "Sequence": msg.sequence % (1 << FEEDBACK_SEQUENCE_BITS), **faults}
    if isinstance(msg, TableSample):
        return TABLE_SENSOR_ID, {
            "Counts": msg.counts, "Sequence": msg.sequence % (1 << SENSOR_SEQUENCE_BITS),
            "TimestampUs": msg.timestamp_us % (1 << TIMESTAMP_BITS)}
    if isinstance(msg, MassSample):
        try:
            frame_id = db.get_message_by_name(MASS_SENSOR).frame_id
        except KeyError:
            raise ValueError(f"the DBC has no {MASS_SENSOR} message for {msg}") from None
        return frame_id, {
            "Counts": msg.counts, "Sequence": msg.sequence % (1 << SENSOR_SEQUENCE_BITS),
            "TimestampUs": msg.timestamp_us % (1 << TIMESTAMP_BITS)}
    if isinstance(msg, Heartbeat):
        _check_index("node", msg.node, NODES)
        return HEARTBEAT_BASE + msg.node, {
            "NodeId": msg.node, "Counter": msg.counter % (1 << COUNTER_BITS),
            "State": int(msg.state)}
    if isinstance(msg, RigCommand):
        return COMMAND_ID, {"Command": int(msg.command), "StartSample": msg.start_sample,
                            "Counter": msg.counter % (1 << COUNTER_BITS)}
    raise TypeError(f"not a rig CAN message: {msg!r}")


def _build(name: str, frame_id: int, s: dict) -> RigMessage:
    """The dataclass for decoded signals `s` of message `name`; ValueError if inconsistent."""
    if name.startswith(("ActuatorSetpoint", "ActuatorFeedback")):
        base = SETPOINT_BASE if name.startswith("ActuatorSetpoint") else FEEDBACK_BASE
        if s["ActuatorIndex"] != frame_id - base:
            raise ValueError(f"ActuatorIndex {s['ActuatorIndex']} on the id of actuator "
                             f"{frame_id - base}")
        if base == SETPOINT_BASE:
            return Setpoint(int(s["ActuatorIndex"]), int(s["Sequence"]), _metres(s["Position"]))
        faults = Fault.NONE
        for bit, sig in _FAULT_SIGNALS.items():
            faults |= bit if s[sig] else Fault.NONE
        return Feedback(int(s["ActuatorIndex"]), int(s["Sequence"]), _metres(s["Position"]),
                        NodeState(s["Status"]), faults)
    if name in ("TableSensor", MASS_SENSOR):
        kind = TableSample if name == "TableSensor" else MassSample
        return kind(int(s["Counts"]), int(s["Sequence"]), int(s["TimestampUs"]))
    if name.startswith("Heartbeat"):
        if s["NodeId"] != frame_id - HEARTBEAT_BASE:
            raise ValueError(f"NodeId {s['NodeId']} on the id of node {frame_id - HEARTBEAT_BASE}")
        return Heartbeat(int(s["NodeId"]), int(s["Counter"]), NodeState(s["State"]))
    if name == "RigCommand":
        return RigCommand(CommandKind(s["Command"]), int(s["Counter"]), int(s["StartSample"]))
    raise ValueError("not one of the rig's messages")


def _metres(value: float) -> float:
    # raw × 1e-6 lands a few ulp off the decimal value; rounding far below the 1 µm
    # resolution makes −50000 µm decode as −0.05 m exactly, as it was sent
    return round(float(value), 9)
