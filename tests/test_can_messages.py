"""rig.wire.can_messages and rig.wire.bus_load: the DBC, typed round trips, counters and the
bus-load budget."""

from __future__ import annotations

import dataclasses

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.config import MAX_STROKE, load_config
from rig.errors import DataError, LimitError
from rig.wire import bus_load as bl
from rig.wire import can_messages as cm
from rig.wire.can_messages import (
    CommandKind,
    Fault,
    Feedback,
    Heartbeat,
    NodeState,
    RigCommand,
    Setpoint,
    TableSample,
)

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

DB = cm.database()
RESOLUTION = 1e-6  # m, Position signals


def _signal(message: str, signal: str):
    return DB.get_message_by_name(message).get_signal_by_name(signal)


def _ints(message: str, signal: str) -> st.SearchStrategy[int]:
    s = _signal(message, signal)
    return st.integers(int(s.minimum), int(s.maximum))


def _positions(message: str) -> st.SearchStrategy[float]:
    s = _signal(message, "Position")
    return st.floats(s.minimum, s.maximum, allow_nan=False)


def test_dbc_is_loaded_once_and_is_classical_11_bit_8_byte() -> None:
    assert cm.database() is DB
    assert len(DB.messages) == 1 + 6 + 1 + 6 + 8
    for m in DB.messages:
        assert not m.is_extended_frame and m.frame_id < 0x800 and m.length == 8, m.name


def test_the_setpoint_range_covers_every_stroke_the_config_accepts() -> None:
    for name in ("ActuatorSetpoint1", "ActuatorFeedback6"):
        s = _signal(name, "Position")
        assert (s.minimum, s.maximum) == (-MAX_STROKE, MAX_STROKE)
        assert s.scale == RESOLUTION


def test_every_dbc_message_has_a_typed_counterpart() -> None:
    examples = ([Setpoint(i, 0, 0.0) for i in cm.ACTUATORS]
                + [Feedback(i, 0, 0.0, NodeState.ENABLED) for i in cm.ACTUATORS]
                + [Heartbeat(n, 0, NodeState.BOOT) for n in cm.NODES]
                + [TableSample(0, 0, 0), RigCommand(CommandKind.ENABLE)])
    ids = {cm.encode(m)[0] for m in examples}
    assert ids == cm.known_ids()
    assert len(ids) == len(examples)


def test_setpoint_bytes_by_hand() -> None:
    # index 3, sequence 0x1234 little-endian, 1000 µm as int32 little-endian, padding 0
    assert cm.encode(Setpoint(3, 0x1234, 0.001)) == (0x103, bytes.fromhex("033412e803000000"))
    assert cm.encode(Setpoint(1, 0, -1e-6)) == (0x101, bytes.fromhex("010000ffffffff00"))


def test_feedback_fault_bits_by_hand() -> None:
    msg = Feedback(2, 5, 0.0, NodeState.RUNNING, Fault.VALVE | Fault.WATCHDOG_HOLD)
    frame_id, data = cm.encode(msg)
    assert frame_id == 0x202
    assert data[7] == 0x03 | (0b1100 << 4)  # status 3 in bits 56-59, faults in 60-63


def _round_trip(msg: cm.RigMessage) -> cm.RigMessage:
    frame_id, data = cm.encode(msg)
    back = cm.decode(frame_id, data)
    assert cm.encode(back) == (frame_id, data)  # the wire form is stable
    return back


@settings(max_examples=200, deadline=None)
@given(actuator=_ints("ActuatorSetpoint1", "ActuatorIndex"),
       sequence=_ints("ActuatorSetpoint1", "Sequence"), position=_positions("ActuatorSetpoint1"))
def test_setpoint_round_trip(actuator: int, sequence: int, position: float) -> None:
    back = _round_trip(Setpoint(actuator, sequence, position))
    assert isinstance(back, Setpoint)
    assert (back.actuator, back.sequence) == (actuator, sequence)
    assert abs(back.position - position) <= RESOLUTION / 2 + 1e-12


@settings(max_examples=200, deadline=None)
@given(actuator=_ints("ActuatorFeedback1", "ActuatorIndex"),
       sequence=_ints("ActuatorFeedback1", "Sequence"), position=_positions("ActuatorFeedback1"),
       status=st.sampled_from(NodeState), faults=st.integers(0, 15).map(Fault))
def test_feedback_round_trip(actuator: int, sequence: int, position: float, status: NodeState,
                             faults: Fault) -> None:
    back = _round_trip(Feedback(actuator, sequence, position, status, faults))
    assert isinstance(back, Feedback)
    assert (back.actuator, back.sequence, back.status, back.faults) == (
        actuator, sequence, status, faults)
    assert abs(back.position - position) <= RESOLUTION / 2 + 1e-12


@settings(max_examples=200, deadline=None)
@given(counts=_ints("TableSensor", "Counts"), sequence=_ints("TableSensor", "Sequence"),
       timestamp=_ints("TableSensor", "TimestampUs"))
def test_table_sample_round_trip(counts: int, sequence: int, timestamp: int) -> None:
    msg = TableSample(counts, sequence, timestamp)
    assert _round_trip(msg) == msg


@settings(max_examples=100, deadline=None)
@given(node=_ints("HeartbeatRIG", "NodeId"), counter=_ints("HeartbeatRIG", "Counter"),
       state=st.sampled_from(NodeState))
def test_heartbeat_round_trip(node: int, counter: int, state: NodeState) -> None:
    msg = Heartbeat(node, counter, state)
    assert _round_trip(msg) == msg


@settings(max_examples=100, deadline=None)
@given(command=st.sampled_from(CommandKind), counter=_ints("RigCommand", "Counter"),
       start=_ints("RigCommand", "StartSample"))
def test_command_round_trip(command: CommandKind, counter: int, start: int) -> None:
    msg = RigCommand(command, counter, start)
    assert _round_trip(msg) == msg


def test_counters_wrap_on_the_wire_and_unwrap() -> None:
    assert cm.decode(*cm.encode(Setpoint(1, 65536 + 5, 0.0))).sequence == 5
    assert cm.decode(*cm.encode(TableSample(0, 256 + 7, 2**32 + 9))) == TableSample(0, 7, 9)
    assert cm.unwrap(65535, 5, 16) == 65541
    assert cm.unwrap(10, 12, 16) == 12
    assert cm.unwrap(255, 255, 8) == 255  # a repeat is not a whole lap
    full, restored = list(range(65_530, 65_545)), []
    previous = full[0]
    for n in full:
        previous = cm.unwrap(previous, cm.decode(*cm.encode(Setpoint(2, n, 0.0))).sequence, 16)
        restored.append(previous)
    assert restored == full


@pytest.mark.parametrize("msg", [
    Setpoint(1, 0, 1.5),  # beyond the DBC's ±1 m
    Setpoint(1, 0, float("nan")),
    Setpoint(1, 0, float("inf")),
    Setpoint(7, 0, 0.0),
    Setpoint(0, 0, 0.0),
    Feedback(1, 0, -2.0, NodeState.FAULT),
    TableSample(2**23, 0, 0),
    Heartbeat(9, 0, NodeState.BOOT),
    RigCommand(CommandKind.START, 0, 2**32),
])
def test_out_of_range_fields_are_refused(msg: cm.RigMessage) -> None:
    with pytest.raises(ValueError):
        cm.encode(msg)


def test_not_a_message_is_a_type_error() -> None:
    with pytest.raises(TypeError):
        cm.encode("setpoint")  # type: ignore[arg-type]


@pytest.mark.parametrize(("frame_id", "data", "fragment"), [
    (0x7FF, bytes(8), "not in the rig's DBC"),
    (0x101, bytes(4), "Wrong data size"),
    (0x101, bytes.fromhex("0200000000000000"), "ActuatorIndex 2 on the id of actuator 1"),
    (0x703, bytes.fromhex("0400000000000000"), "NodeId 4 on the id of node 3"),
    (0x201, bytes.fromhex("0100000000000007"), "7 is not a valid NodeState"),
    (0x010, bytes(8), "0 is not a valid CommandKind"),
])
def test_bad_frames_are_data_errors(frame_id: int, data: bytes, fragment: str) -> None:
    with pytest.raises(DataError, match=fragment):
        cm.decode(frame_id, data)


def test_python_can_frames_over_a_virtual_bus() -> None:
    sent = [Setpoint(4, 99, -0.05), Heartbeat(cm.NODE_RIG, 1, NodeState.RUNNING),
            RigCommand(CommandKind.SAFE_STATE, 2)]
    with can.Bus(interface="virtual", channel="test_can_messages") as tx, \
            can.Bus(interface="virtual", channel="test_can_messages") as rx:
        for m in sent:
            tx.send(cm.to_can(m))
        got = [cm.from_can(rx.recv(timeout=1.0)) for _ in sent]
    assert got == sent
    with pytest.raises(DataError, match="not a classical 11-bit"):
        cm.from_can(can.Message(arbitration_id=0x101, data=bytes(8), is_extended_id=True))


# --- bus load -------------------------------------------------------------------------------

def test_frame_bits_by_hand() -> None:
    assert bl.frame_bits(8) == (111, 135)
    assert bl.frame_bits(0) == (47, 55)
    best, worst = bl.frame_bits(8)
    assert (int(1_000_000 / best), int(1_000_000 / worst)) == (9009, 7407)


def test_default_bus_load_by_hand() -> None:
    load = bl.check_bus_load(load_config())
    # 6 x 400 setpoints + 6 x 100 feedback + 1000 sensor + 8 nodes x 10 heartbeats
    assert load.frames_per_s == 2400 + 600 + 1000 + 80 == 4080
    assert load.bits_per_s("best") == 4080 * 111
    assert load.load_best == pytest.approx(0.45288)
    assert load.load_worst == pytest.approx(0.5508)
    assert load.fits
    text = load.format()
    for fragment in ("4,080 frames/s", "45.3%", "55.1%", "135-bit", "fits the 60% budget"):
        assert fragment in text


def test_a_config_over_budget_is_refused() -> None:
    c = load_config()
    busy = dataclasses.replace(c, rates=dataclasses.replace(c.rates, setpoint=500, feedback=200))
    # 3000 + 1200 + 1000 + 80 = 5280 frames/s: 58.6 % best case, 71.3 % worst case
    with pytest.raises(LimitError) as info:
        bl.check_bus_load(busy)
    message = str(info.value)
    for fragment in ("5,280 frames/s", "71.3%", "58.6% best case", "60% budget"):
        assert fragment in message
    assert not bl.bus_load(busy).fits
    assert "OVER" in bl.bus_load(busy).format()


def test_the_budget_is_held_against_the_worst_case() -> None:
    c = load_config()
    tight = dataclasses.replace(c, can=dataclasses.replace(c.can, load_budget=0.5))
    assert bl.bus_load(tight).load_best < 0.5 < bl.bus_load(tight).load_worst
    with pytest.raises(LimitError, match="55.1%"):
        bl.check_bus_load(tight)
