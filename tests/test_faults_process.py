"""Process faults: kill -9 of the rig, kill -9 of the simulated rig, Ctrl-C of the rig.

The rig runs as a real `rig run` process. For kill -9 and Ctrl-C of the rig the
simulated rig lives in this test process (a SimRig, configured as "hardware"
through a TOML file), so the tests see what the actuators did and when; for
kill -9 of the sim, `rig run` starts `sim serve` itself, as in production.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import pytest

from rig.paths import data_file
from rig.runfile import open_run, read_status
from rig.wire.can_messages import Fault, NodeState
from sim.rig_sim import SimRig
from tests.test_faults_can import LOAD_MARGIN_S, measured
from tests.test_run_limits import profile_file

pytestmark = pytest.mark.slow

RIG = [sys.executable, "-m", "rig.cli"]
ACTUATOR_HOLD_BOUND_S = 0.1 + 0.1  # the setpoints' lead, then the actuators' WATCHDOG_S


def bench_config(sim: SimRig, path: Path) -> Path:
    """data/rig.toml pointed at `sim` as if it were the bench (backend "hardware")."""
    text = data_file("rig.toml").read_text(encoding="utf-8")
    for old, new in (('backend = "sim"', 'backend = "hardware"'),
                     ("port = 29536", f"port = {sim.can_port}"),
                     ('path = "/dev/ttyUSB0"', f'path = "{sim.pty_path}"')):
        assert old in text
        text = text.replace(old, new)
    path.write_text(text, encoding="utf-8")
    return path


def start_rig(args: list[str]) -> tuple[subprocess.Popen, list[str]]:
    """`rig run …` as a process; returns it once it printed START, with the lines so far."""
    proc = subprocess.Popen([*RIG, "run", "--yes", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    deadline = time.monotonic() + 120
    while not any("START:" in line for line in lines):
        line = proc.stdout.readline()
        assert line and time.monotonic() < deadline, (lines, proc.stderr.read())
        lines.append(line)
    return proc, lines


def run_file(lines: list[str]) -> Path:
    return Path(next(line for line in lines if "logging to" in line).split("logging to ")[1]
                .strip())


def test_kill_9_of_the_rig_leaves_a_recoverable_file_and_the_table_holds(
        sim: SimRig, tmp_path: Path) -> None:
    spec = profile_file(tmp_path, "long", 1.0, 2.0)
    proc, lines = start_rig(["--profile", str(spec), "--config",
                             str(bench_config(sim, tmp_path / "bench.toml")),
                             "--out", str(tmp_path)])
    time.sleep(0.5)
    proc.kill()
    killed, killed_unix = time.monotonic(), time.time()
    proc.communicate(timeout=30)
    path = run_file(lines)
    deadline = time.monotonic() + 2
    while not all(a.faults & Fault.WATCHDOG_HOLD for a in sim.actuators):
        assert time.monotonic() < deadline, [a.faults for a in sim.actuators]
        time.sleep(0.01)
    hold = max(a.hold_at for a in sim.actuators) - killed
    assert read_status(path).state == "crashed"
    done = subprocess.run([*RIG, "recover", str(path)], capture_output=True, text=True,
                          timeout=60, check=False)
    assert done.returncode == 0 and done.stderr == "", done.stderr
    assert done.stdout.count("\n") == 1 and "crashed, incomplete" in done.stdout, done.stdout
    with h5py.File(path, "r") as f:  # plainly readable now, by any HDF5 tool
        assert f.attrs["complete"] == False  # noqa: E712 - numpy bool
    run = open_run(path)
    assert run.status.state == "crashed" and "recovered" in run.status.reason
    # raw frames are in up to the last flush (every 0.1 s) of what the rig had processed
    # (its receive queue may be a few hundred ms behind on a loaded machine); decoded
    # sensor samples wait HOLD_S (0.5 s) more for the clock fit: the raw frames hold them
    kill_t = killed_unix - float(run.meta["start_unix"])
    raw_end = run.can.time[-1]
    measured("kill_rig_loss", raw_can_s=kill_t - raw_end, raw_serial_s=kill_t - run.serial.time[-1],
             table_u_s=kill_t - run.channels["table_u"].time[-1])
    assert raw_end > kill_t - 0.1 - 0.5, (raw_end, kill_t)
    assert run.serial.time[-1] > kill_t - 0.1 - 0.5
    assert run.channels["table_u"].time[-1] > raw_end - 0.5 - 0.1 - 0.1
    measured("kill_rig", actuators_hold_s=hold)
    assert hold < ACTUATOR_HOLD_BOUND_S + LOAD_MARGIN_S
    again = subprocess.run([*RIG, "recover", str(tmp_path / "nothing.h5")],
                           capture_output=True, text=True, timeout=60, check=False)
    assert again.returncode == 2 and again.stderr.count("\n") == 1
    assert "nothing.h5" in again.stderr and "Traceback" not in again.stderr


def test_ctrl_c_aborts_in_order_into_the_safe_state(sim: SimRig, tmp_path: Path) -> None:
    spec = profile_file(tmp_path, "long", 1.0, 2.0)
    proc, lines = start_rig(["--profile", str(spec), "--config",
                             str(bench_config(sim, tmp_path / "bench.toml")),
                             "--out", str(tmp_path)])
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    sent = time.monotonic()
    out, err = proc.communicate(timeout=30)
    safe = max(a.safe_state_at for a in sim.actuators) - sent
    assert proc.returncode == 1, (out, err)
    assert "Traceback" not in err and "interrupted by the operator (Ctrl-C)" in out
    assert all(a.state == NodeState.SAFE_STATE for a in sim.actuators)
    status = open_run(run_file(lines)).status
    assert status.exit_status == "abort" and status.complete
    assert status.reason == "interrupted by the operator (Ctrl-C)"
    measured("sigint", safe_state_s=safe)
    assert 0 < safe < 0.05 + LOAD_MARGIN_S


def test_kill_9_of_the_sim_aborts_the_rig_cleanly(tmp_path: Path) -> None:
    spec = profile_file(tmp_path, "long", 1.0, 2.0)
    proc, lines = start_rig(["--profile", str(spec), "--out", str(tmp_path)])
    sim_pid = int(next(line for line in lines if "sim serve running" in line)
                  .split("pid ")[1].rstrip(")\n"))
    path = run_file(lines)
    time.sleep(0.3)
    os.kill(sim_pid, signal.SIGKILL)
    killed = time.monotonic()
    while read_status(path).state == "running":
        assert time.monotonic() - killed < 5, "the rig did not notice"
        time.sleep(0.005)
    in_file = time.monotonic() - killed
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 1 and "Traceback" not in err, (out, err)
    status = read_status(path)
    assert status.state == "abort" and "lost" in status.reason, status.reason
    assert ": abort in " in out
    measured("kill_sim", abort_in_file_s=in_file)
    assert in_file < 0.1 + 0.3 + LOAD_MARGIN_S  # + the end of the run: finish and close


def test_a_fault_given_to_sim_serve_reaches_the_rig_through_the_cli(tmp_path: Path) -> None:
    """`rig run --sim-arg=--fault --sim-arg=stuck_valve=3@0.3`: the production topology
    (rig and `sim serve` as processes), the fault configured on the sim's command line."""
    spec = profile_file(tmp_path, "long", 3.0, 1.0)
    done = subprocess.run([*RIG, "run", "--yes", "--profile", str(spec), "--out", str(tmp_path),
                           "--sim-arg=--fault", "--sim-arg=stuck_valve=3@0.3"],
                          capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr
    assert ": abort in " in done.stdout and "actuator 3 following error" in done.stdout
    path = next(tmp_path.glob("*_long.h5"))
    assert "actuator 3 following error" in read_status(path).reason
