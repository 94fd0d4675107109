"""The runner against an in-process simulated rig, configured as "hardware" (no subprocess).

A refused profile never puts a setpoint on the bus; an unconfirmed run moves
nothing; every run ends with the actuators in the safe state and the file closed;
frames the bus drops are counted as lost and marked as gaps.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from types import MappingProxyType

import can
import numpy as np
import pytest

from rig.cli import main
from rig.config import RigConfig, load_config
from rig.errors import LimitError
from rig.profile import load_profile
from rig.run.runner import run_profile
from rig.runfile import open_run
from rig.wire import can_messages as cm
from rig.wire.can_messages import NodeState
from sim.rig_sim import SimRig
from sim.socketcand_server import BusFaults

pytestmark = pytest.mark.usefixtures("no_leaks")  # every bus, port and thread closes


def hardware(rig: SimRig) -> RigConfig:
    """The default configuration pointed at `rig` as if it were the bench."""
    config = load_config()
    extra = MappingProxyType(dict(config.can.extra, port=rig.can_port))
    return replace(config, backend="hardware", can=replace(config.can, extra=extra),
                   serial=replace(config.serial, path=rig.pty_path))


def profile_file(tmp_path: Path, name: str, ramp_to_in: float, duration: float) -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(f'name = "{name}"\nunits = "in"\n[[segment]]\nhold = 0.05\n'
                    f"[[segment]]\nramp_to = {ramp_to_in}\nduration = {duration}\n"
                    "[[segment]]\nhold = 0.1\n", encoding="utf-8")
    return path


class Listener:
    """A second client on the bus that counts every setpoint frame it sees."""

    def __init__(self, rig: SimRig) -> None:
        self.bus = can.Bus(interface="socketcand", host="127.0.0.1", port=rig.can_port,
                           channel="can0")
        self.setpoints = 0

    def drain(self, seconds: float) -> int:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            msg = self.bus.recv(timeout=0.05)
            if msg is not None and cm.SETPOINT_BASE < msg.arbitration_id <= 0x106:
                self.setpoints += 1
        return self.setpoints


@pytest.mark.parametrize("name, ramp_to, duration, quantity", [
    ("too_far", 8.0, 2.0, "stroke"),
    ("too_fast", 5.5, 0.08, "velocity"),
    ("too_sharp", 1.0, 0.04, "acceleration"),
])
def test_a_profile_over_a_limit_is_refused_before_any_setpoint(
        sim: SimRig, tmp_path: Path, name: str, ramp_to: float, duration: float,
        quantity: str) -> None:
    listener = Listener(sim)
    try:
        spec = profile_file(tmp_path, name, ramp_to, duration)
        with pytest.raises(LimitError, match=rf"actuator \d {quantity} .* exceeds"):
            run_profile(hardware(sim), load_profile(spec), spec.read_text(), tmp_path)
        assert listener.drain(0.3) == 0
    finally:
        listener.bus.shutdown()
    assert all(a.setpoints_received == 0 for a in sim.actuators)
    assert list(tmp_path.glob("*.h5")) == []  # no run file: nothing started


def test_an_unconfirmed_run_aborts_with_nothing_moved(sim: SimRig, tmp_path: Path) -> None:
    spec = profile_file(tmp_path, "small", 1.0, 0.3)
    result = run_profile(hardware(sim), load_profile(spec), spec.read_text(), tmp_path,
                         confirm=lambda: False)
    assert result.status == "abort" and "did not confirm" in result.reason
    assert all(a.setpoints_received == 0 for a in sim.actuators)
    status = open_run(result.path).status
    assert status.exit_status == "abort" and "did not confirm" in status.reason
    _wait_for(lambda: all(a.state == NodeState.SAFE_STATE for a in sim.actuators))


def test_a_run_follows_the_profile_and_ends_in_the_safe_state(sim: SimRig,
                                                              tmp_path: Path) -> None:
    spec = profile_file(tmp_path, "small", 1.0, 0.3)
    profile = load_profile(spec)
    result = run_profile(hardware(sim), profile, spec.read_text(), tmp_path)
    assert result.status == "success", result.reason
    n = round(profile.duration * 400) + 1
    assert [a.setpoints_received for a in sim.actuators] == [n] * 6
    _wait_for(lambda: all(a.state == NodeState.SAFE_STATE for a in sim.actuators))
    run = open_run(result.path)
    u = run.channels["table_u"].value
    assert max(u) == pytest.approx(0.0254, abs=2e-4)  # 1 in, within the sensor noise
    assert run.meta["backend"] == "hardware"
    assert result.lost == {"can": 0, "serial": 0}


def _wait_for(condition, timeout: float = 2.0) -> None:
    end = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < end, "condition not met in time"
        time.sleep(0.01)


def test_cli_check_prints_margins_and_bus_load(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", "--profile", "C"]) == 0
    out = capsys.readouterr().out
    assert "smallest margin: actuator" in out and "fits the 60% budget" in out


def test_cli_run_refuses_before_starting_anything(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    spec = profile_file(tmp_path, "too_far", 8.0, 2.0)
    assert main(["run", "--profile", str(spec), "--yes", "--out", str(tmp_path / "runs")]) == 2
    err = capsys.readouterr().err
    assert "actuator 1 stroke" in err and "exceeds stroke limit" in err
    assert not (tmp_path / "runs").exists()  # refused before the directory is made


@pytest.mark.parametrize(("units", "peak", "limit"), [("us", "8.00 in", "7.00 in"),
                                                      ("si", "0.2032 m", "0.1778 m")])
def test_cli_check_lists_one_violation_per_line_in_the_units_asked(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], units: str, peak: str,
        limit: str) -> None:
    spec = profile_file(tmp_path, "too_far", 8.0, 2.0)
    assert main(["check", "--profile", str(spec), "--units", units]) == 2
    head, *lines = capsys.readouterr().err.splitlines()
    assert head == (f"rig: error: profile {spec}: 4 limit violations on actuators 1, 2, 3, 4; "
                    "nothing has moved")  # named by the file given, not its TOML name
    assert len(lines) == 4
    for i, line in enumerate(lines, start=1):
        assert line.startswith(f"  actuator {i} stroke {peak} exceeds stroke limit {limit} ")


def test_cli_runs_lists_files_with_status(sim: SimRig, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    spec = profile_file(tmp_path, "small", 1.0, 0.3)
    run_profile(hardware(sim), load_profile(spec), spec.read_text(), tmp_path,
                confirm=lambda: False)
    assert main(["runs", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "abort" in out and "1 run files in" in out and " s " in out


def test_dropped_can_frames_are_counted_and_marked_as_gaps(sim: SimRig, tmp_path: Path) -> None:
    sim.server.faults = BusFaults(drop_prob=0.01, seed=7)
    spec = profile_file(tmp_path, "small", 1.0, 0.3)
    result = run_profile(hardware(sim), load_profile(spec), spec.read_text(), tmp_path)
    dropped = sim.server.stats.frames_dropped
    assert dropped > 10
    assert 0 < result.lost["can"] <= dropped  # setpoints dropped on the way out are not seen
    run = open_run(result.path)
    assert run.counters["can"]["lost"] == result.lost["can"]
    gaps = [g for g in run.gaps if g.channel == "table_u"]
    assert gaps and sum(g.count for g in gaps) <= result.lost["can"]
    t = run.channels["table_u"].time
    assert np.all(np.diff(t) > 0)
    # the table's samples are 1 ms apart except across a gap
    assert np.sum(np.diff(t) > 1.5e-3) <= len(gaps) + 5
