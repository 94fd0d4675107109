"""rig.config: the default file loads into SI and round-trips; bad input is a named ConfigError."""

from __future__ import annotations

import copy
import math
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.config import config_to_dict, load_config, parse_config
from rig.errors import ConfigError, RigError
from rig.paths import data_file
from rig.units import INCH, POUND_FORCE, POUND_MASS

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

DEFAULT_TEXT = data_file("rig.toml").read_text(encoding="utf-8")


def default_doc() -> dict[str, Any]:
    return tomllib.loads(DEFAULT_TEXT)


def test_default_config_loads_into_si() -> None:
    c = load_config()
    assert c.backend == "sim"
    assert [a.index for a in c.table.actuators] == [1, 2, 3, 4, 5, 6]
    a3 = c.table.actuators[2]
    assert a3.name == "X3"
    assert a3.line_of_action == (-1.0, 0.0)
    assert a3.position == pytest.approx((6 * 12 * INCH, -3 * 12 * INCH))
    assert a3.piston_area == pytest.approx(12 * INCH**2)
    assert a3.stroke == pytest.approx(7 * INCH)
    assert a3.force_capacity == pytest.approx(75_000 * POUND_FORCE)
    # 330 gpm through 12 in^2: 0.020820 m^3/s / 0.0077419 m^2
    assert a3.max_velocity == pytest.approx(2.6892, abs=1e-4)
    assert a3.max_acceleration == pytest.approx(8 * 9.80665)
    assert c.table.payload_mass == pytest.approx(6000 * POUND_MASS)
    assert c.table.moving_mass == pytest.approx(13_000 * POUND_MASS)
    # the six share the report's 450,000 lb
    assert sum(a.force_capacity for a in c.table.actuators) == pytest.approx(450_000 * POUND_FORCE)
    assert c.table_sensor.sample_rate == 1000 and c.mass_sensor.sample_rate == 1000
    assert c.serial.baud == 921600
    assert (c.rates.setpoint, c.rates.feedback, c.rates.heartbeat) == (400, 100, 10)
    assert c.can.bus_kwargs() == {"interface": "socketcand", "channel": "can0",
                                  "bitrate": 1_000_000, "host": "127.0.0.1", "port": 29536}
    assert c.can.load_budget == 0.6
    assert c.source == str(data_file("rig.toml"))


def test_round_trip_through_the_document() -> None:
    c = load_config()
    doc = config_to_dict(c)
    again = parse_config(doc, "again.toml")
    assert again == c
    # the SI document states its units, and parsing does not alter it
    assert doc["table"]["actuator"][0]["piston_area"]["unit"] == "m^2"
    assert config_to_dict(again) == doc


def test_units_may_be_stated_either_way() -> None:
    doc = default_doc()
    doc["table"]["actuator"][0]["piston_area"] = {"value": 12 * INCH**2, "unit": "m^2"}
    doc["table"]["actuator"][0]["stroke"] = {"value": 7 * INCH, "unit": "m"}
    assert parse_config(doc, "si.toml") == load_config()


def test_config_is_frozen() -> None:
    c = load_config()
    with pytest.raises(AttributeError):
        c.backend = "hardware"  # type: ignore[misc]
    with pytest.raises(TypeError):
        c.can.extra["port"] = 1  # type: ignore[index]


def test_sensor_counts_round_trip() -> None:
    s = load_config().table_sensor
    counts = np.array([-3, 0, 139_700])
    assert np.allclose(s.to_si(counts), counts * 1e-6)
    assert np.array_equal(s.to_counts(s.to_si(counts)), counts)


def test_bus_kwargs_open_a_real_python_can_bus() -> None:
    doc = default_doc()
    doc["can"] = {"interface": "virtual", "channel": "test_config", "bitrate": 1_000_000,
                  "load_budget": 0.6, "extra": {"receive_own_messages": True}}
    c = parse_config(doc, "virtual.toml")
    with can.Bus(**c.can.bus_kwargs()) as bus:
        bus.send(can.Message(arbitration_id=0x101, data=bytes(8), is_extended_id=False))
        got = bus.recv(timeout=1.0)
    assert got is not None and got.arbitration_id == 0x101


def _set(path: str, value: Any) -> Callable[[dict], None]:
    """A mutation that sets the dotted `path` (list indices 0-based) of a document."""
    def mutate(doc: dict) -> None:
        *parents, last = path.split(".")
        node: Any = doc
        for p in parents:
            node = node[int(p)] if isinstance(node, list) else node[p]
        if isinstance(node, list):
            node[int(last)] = value
        else:
            node[last] = value
    return mutate


def _delete(path: str) -> Callable[[dict], None]:
    def mutate(doc: dict) -> None:
        *parents, last = path.split(".")
        node: Any = doc
        for p in parents:
            node = node[int(p)] if isinstance(node, list) else node[p]
        del node[last]
    return mutate


def _actuators(change: Callable[[list], None]) -> Callable[[dict], None]:
    def mutate(doc: dict) -> None:
        change(doc["table"]["actuator"])
    return mutate


def _all_along_x(acts: list) -> None:
    for a in acts:
        a["line_of_action"] = [1.0, 0.0]


def _q(value: Any, unit: str) -> dict:
    return {"value": value, "unit": unit}


BAD = [
    # (mutation, dotted field, message fragment)
    (_set("table.actuator.2.piston_area", _q(-2, "in^2")), "table.actuator[3].piston_area",
     "must be > 0 in^2, got -2"),
    (_set("table.actuator.0.stroke", _q(math.nan, "in")), "table.actuator[1].stroke",
     "must be a finite number, got nan"),
    (_set("table.actuator.0.stroke", _q(math.inf, "in")), "table.actuator[1].stroke",
     "must be a finite number, got inf"),
    (_set("table.payload_mass", _q(-6000, "lbm")), "table.payload_mass",
     "must be > 0 lbm, got -6000"),
    (_set("table.actuator.1.servovalve_flow", _q("330", "gpm")),
     "table.actuator[2].servovalve_flow", "must be a finite number, got '330'"),
    (_set("table.actuator.1.force_capacity", _q(True, "lb")),
     "table.actuator[2].force_capacity", "must be a finite number, got True"),
    (_set("table.actuator.0.piston_area", 12), "table.actuator[1].piston_area",
     'must be { value = …, unit = "m^2" }'),
    (_set("table.actuator.0.piston_area", {"value": 12, "unit": "in^2", "note": "x"}),
     "table.actuator[1].piston_area", "must be { value"),
    (_set("table.platform_mass", _q(7000, "lb")), "table.platform_mass.unit",
     "must be a mass unit (kg, lbm), got 'lb'"),
    (_set("table.supply_pressure", _q(3000, "furlong")), "table.supply_pressure.unit",
     "must be a pressure unit"),
    (_set("table.supply_pressure", _q(1e308, "psi")), "table.supply_pressure", "overflows"),
    (_set("table.actuator.3.stroke", _q(50, "in")), "table.actuator[4].stroke",
     "must be <= 1 m, the setpoint message's range"),
    (_set("table.actuator.4.max_acceleration", _q(0, "g")), "table.actuator[5].max_acceleration",
     "must be > 0 g, got 0"),
    (_delete("can"), "can", "missing"),
    (_delete("table.actuator.0.stroke"), "table.actuator[1].stroke", "missing"),
    (_delete("rates.feedback_hz"), "rates.feedback_hz", "missing"),
    (_set("serial", "COM1"), "serial", "must be a table, got 'COM1'"),
    (_set("colour", "red"), "colour", "unknown key"),
    (_set("table.actuator.1.pistn_area", _q(12, "in^2")), "table.actuator[2].pistn_area",
     "unknown key"),
    (_set("can.extra.channel", "can1"), "can.extra.channel", "set it in [can] itself"),
    (_actuators(lambda acts: acts.pop()), "table.actuator", "needs exactly 6"),
    (_actuators(lambda acts: acts.append(copy.deepcopy(acts[0]))), "table.actuator",
     "needs exactly 6 [[table.actuator]] tables, got 7"),
    (_set("table.actuator", {"index": 1}), "table.actuator", "needs exactly 6"),
    (_set("table.actuator.2", 3), "table.actuator[3]", "must be a table, got 3"),
    (_set("table.actuator.1.index", 5), "table.actuator[2].index", "must be 2"),
    (_set("table.actuator.0.name", ""), "table.actuator[1].name", "non-empty string"),
    (_set("table.actuator.0.line_of_action", [1.0, 1.0]), "table.actuator[1].line_of_action",
     "must be a unit vector"),
    (_set("table.actuator.0.line_of_action", [1.0, 0.0, 0.0]),
     "table.actuator[1].line_of_action", "must be a pair"),
    (_set("table.actuator.0.line_of_action", [1.0, "0"]), "table.actuator[1].line_of_action",
     "must be a finite number"),
    (_set("table.actuator.0.position", _q([7.0, 0.0], "ft")), "table.actuator[1].position",
     "lies off the 3.6576 m square platform"),
    (_actuators(_all_along_x), "table.actuator", "hold only 2 of x, y and yaw"),
    (_set("backend", "simulated"), "backend", "must be one of 'sim', 'hardware'"),
    (_set("can.bitrate", True), "can.bitrate", "must be an integer, got True"),
    (_set("can.bitrate", 2_000_000), "can.bitrate", "must be in 1..1000000, got 2000000"),
    (_set("can.load_budget", 1.5), "can.load_budget", "must be <= 1"),
    (_set("can.channel", [0]), "can.channel", "non-empty string or an integer"),
    (_delete("can.extra.port"), "can.extra", "socketcand interface needs host and port"),
    (_set("can.extra", "host=127.0.0.1"), "can.extra", "must be a table"),
    (_set("serial.baud", 115200), "serial.baud",
     "115200 baud carries 720 sensor frames/s, the mass sensor sends 1000/s"),
    (_set("sensors.table.scale", _q(0.0, "m")), "sensors.table.scale", "must not be 0"),
    (_set("sensors.mass.noise_rms", _q(-1e-6, "m")), "sensors.mass.noise_rms",
     "must be >= 0 m, got -1e-06"),
    (_set("sensors.table.sample_rate_hz", 0), "sensors.table.sample_rate_hz", "must be > 0"),
    (_set("rates.setpoint_hz", "400 Hz"), "rates.setpoint_hz", "must be a finite number"),
]


@pytest.mark.parametrize(("mutate", "field", "fragment"), BAD,
                         ids=[f"{b[1]}:{b[2][:24]}" for b in BAD])
def test_bad_config_names_the_field(mutate: Callable[[dict], None], field: str,
                                    fragment: str) -> None:
    doc = default_doc()
    mutate(doc)
    with pytest.raises(ConfigError) as info:
        parse_config(doc, "rig.toml")
    assert info.value.field == field
    assert str(info.value).startswith(f"rig.toml: {field}: ")
    assert fragment in str(info.value)


def test_message_reads_as_the_brief_says() -> None:
    doc = default_doc()
    _set("table.actuator.2.piston_area", _q(-2, "in^2"))(doc)
    with pytest.raises(ConfigError, match=r"^rig\.toml: table\.actuator\[3\]\.piston_area: "
                                          r"must be > 0 in\^2, got -2$"):
        parse_config(doc, "rig.toml")


def test_a_diagonal_actuator_is_normalised_and_round_trips() -> None:
    doc = default_doc()
    doc["table"]["actuator"][4]["line_of_action"] = [0.7071, 0.7071]  # as typed by hand
    c = parse_config(doc, "diag.toml")
    s = math.sqrt(0.5)
    assert c.table.actuators[4].line_of_action == pytest.approx((s, s), abs=1e-15)
    assert parse_config(config_to_dict(c), "again.toml") == c


@pytest.mark.parametrize(("old", "new", "field", "fragment"), [
    ('piston_area = { value = 12.0, unit = "in^2" }',
     'piston_area = { value = nan, unit = "in^2" }', "table.actuator[1].piston_area", "got nan"),
    ("bitrate = 1_000_000", 'bitrate = "fast"', "can.bitrate", "must be an integer, got 'fast'"),
    ("\n[serial]\n", "\n[serial_port]\n", "serial", "missing"),
])
def test_hostile_files_give_config_errors(tmp_path: Path, old: str, new: str, field: str,
                                          fragment: str) -> None:
    assert old in DEFAULT_TEXT
    path = tmp_path / "rig.toml"
    path.write_text(DEFAULT_TEXT.replace(old, new, 1), encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert info.value.source == str(path) and info.value.field == field
    assert fragment in str(info.value)


@pytest.mark.parametrize(("content", "fragment"), [
    (None, "no such configuration file"),
    (b"backend = \n", "not valid TOML"),
    (b"backend = '\xff\xfe'\n", "cannot read"),
])
def test_unreadable_files_give_config_errors(tmp_path: Path, content: bytes | None,
                                             fragment: str) -> None:
    path = tmp_path / "rig.toml"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(ConfigError, match=fragment) as info:
        load_config(path)
    assert str(info.value).startswith(str(path))


def _paths(node: Any, prefix: tuple = ()) -> list[tuple]:
    """Every key path in a document, sections included."""
    out = [prefix] if prefix else []
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _paths(v, prefix + (i,))
    return out


PATHS = _paths(default_doc())
TOML_VALUES = st.recursive(
    st.one_of(st.booleans(), st.integers(), st.floats(), st.text(max_size=8)),
    lambda inner: st.one_of(st.lists(inner, max_size=3),
                            st.dictionaries(st.text(max_size=6), inner, max_size=3)),
    max_leaves=6)


@settings(max_examples=300, deadline=None)
@given(path=st.sampled_from(PATHS), value=TOML_VALUES, delete=st.booleans())
def test_any_single_corruption_is_a_config_error_or_valid(path: tuple, value: Any,
                                                         delete: bool) -> None:
    doc = default_doc()
    node: Any = doc
    for p in path[:-1]:
        node = node[p]
    if delete and isinstance(node, dict):
        del node[path[-1]]
    else:
        node[path[-1]] = value
    try:
        parse_config(doc, "fuzz.toml")
    except ConfigError as e:
        assert isinstance(e, (RigError, ValueError))
        assert str(e).startswith("fuzz.toml: ")
