"""`sim serve` and the pure parts of a run: commands, clock fit, servo, actuator controller."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import can
import numpy as np
import pytest
import serial

from rig.config import load_config
from rig.geometry import actuator_plan
from rig.profile import load_profile
from rig.run.clock_fit import ClockFit
from rig.run.schedule import LEAD_SAMPLES, run_messages
from rig.wire import can_messages as cm
from rig.wire.can_messages import CommandKind, Fault, NodeState, RigCommand, Setpoint, TableSample
from rig.wire.serial_frame import FrameDecoder
from sim.devices import ActuatorController, table_sample
from sim.plant import ServoAxis


@pytest.mark.parametrize("counts, seq, ts", [(0, 0, 0), (-1, 255, 2**32 - 1),
                                             (8388607, 17, 123456), (-8388608, 300, 2**33 + 5)])
def test_fast_table_frame_matches_the_dbc(counts: int, seq: int, ts: int) -> None:
    msg = table_sample(counts, seq, ts)
    assert (msg.arbitration_id, bytes(msg.data)) == cm.encode(TableSample(counts, seq, ts))


def test_run_messages_enable_prefill_start_stream_stop() -> None:
    config = load_config()
    plan = actuator_plan(config, load_profile("A"))
    msgs = list(run_messages(plan))
    kinds = [m.message.command for m in msgs if isinstance(m.message, RigCommand)]
    assert kinds == [CommandKind.ENABLE, CommandKind.START, CommandKind.STOP]
    start = next(i for i, m in enumerate(msgs) if getattr(m.message, "command", None)
                 == CommandKind.START)
    assert start == 1 + 6 * LEAD_SAMPLES  # the prefill goes before START
    setpoints = [m.message for m in msgs if isinstance(m.message, Setpoint)]
    assert len(setpoints) == 6 * len(plan.t)
    assert [s.sequence for s in setpoints[::6]] == list(range(len(plan.t)))
    dues = [m.due for m in msgs]
    assert dues == sorted(dues) and msgs[start].due == 0.0
    # each sample goes out LEAD_SAMPLES before the actuators play it
    i = 100
    assert msgs[2 + 6 * i].due == pytest.approx((i - LEAD_SAMPLES) / plan.rate)  # after START
    assert setpoints[6 * 200].position == pytest.approx(plan.extension[200, 0])


def test_clock_fit_recovers_offset_and_drift_despite_a_latency_tail() -> None:
    rng = np.random.default_rng(3)
    device = 4000.0 + np.arange(6000) * 1e-3
    latency = 1e-4 + rng.exponential(3e-3, device.size)
    latency[2000:2600] += np.linspace(0.15, 0.0, 600)  # a starved sender catching up
    host = 12.5 + device * (1 - 30e-6) + latency
    fit = ClockFit()
    for d, h in zip(device, host):
        fit.add(d, h)
    model = fit.refit()
    error = model.to_host(device) - (12.5 + device * (1 - 30e-6))
    assert model.rate == pytest.approx(1 - 30e-6, abs=5e-6)
    assert np.max(np.abs(error)) < 2e-4  # the smallest latency, 0.1 ms, and a little


def test_clock_fit_unwraps_the_32_bit_microsecond_counter() -> None:
    fit = ClockFit()
    assert fit.device_seconds(2**32 - 10) == pytest.approx((2**32 - 10) * 1e-6)
    assert fit.device_seconds(5) == pytest.approx((2**32 + 5) * 1e-6)


def test_servo_axis_lags_and_respects_its_velocity_limit() -> None:
    axis = ServoAxis(max_velocity=1.0)
    for _ in range(10):
        axis.step(1.0, 1e-3)
    assert axis.position == pytest.approx(0.010)  # rate-limited: 1 m/s for 10 ms
    slow = ServoAxis(max_velocity=100.0)
    slow.step(1e-3, 5e-3)  # one time constant, the target ramping 0 -> 1 mm over it
    assert slow.position == pytest.approx(1e-3 * np.exp(-1))  # r - sτ + sτ e^(-1)
    # following a ramp: lag sτ behind it, at the ramp's own velocity, with no jumps
    ramp = ServoAxis(max_velocity=100.0)
    s, dt = 0.5, 1e-3
    v = []
    for k in range(1, 200):
        ramp.step(s * k * dt, dt)
        v.append(ramp.velocity)
    assert ramp.position == pytest.approx(s * 199 * dt - s * 0.005, abs=1e-9)
    assert v[-1] == pytest.approx(s, rel=1e-9)
    assert np.max(np.abs(np.diff(v))) < 0.2 * s  # smooth: 1 - e^(-dt/τ) of s at most


def _frame(msg) -> can.Message:
    return cm.to_can(msg)


def test_actuator_controller_plays_indexed_setpoints_then_stops_or_holds() -> None:
    act = ActuatorController(1, rate=100.0)
    act.on_frame(_frame(RigCommand(CommandKind.ENABLE, 1)))
    for i in range(5):
        act.on_frame(_frame(Setpoint(1, i, 0.001 * i)))
    act.on_frame(_frame(RigCommand(CommandKind.START, 2, 0)))
    assert act.target(10.0) == 0.0  # START takes effect here
    assert act.target(10.015) == pytest.approx(0.0015)  # between samples 1 and 2
    assert act.target(10.04) == pytest.approx(0.004)  # the last sample it has
    assert act.faults == Fault.NONE  # not yet late by WATCHDOG_S
    assert act.target(10.3) == pytest.approx(0.004)  # starved: holds …
    assert act.faults & Fault.WATCHDOG_HOLD  # … and says so
    act.on_frame(_frame(RigCommand(CommandKind.ENABLE, 3)))
    act.on_frame(_frame(Setpoint(1, 0, 0.002)))
    act.on_frame(_frame(RigCommand(CommandKind.START, 4, 0)))
    act.on_frame(_frame(RigCommand(CommandKind.STOP, 5)))
    act.target(0.0)
    assert act.target(0.5) == pytest.approx(0.002) and act.faults == Fault.NONE
    assert act.state == NodeState.ENABLED
    act.on_frame(_frame(RigCommand(CommandKind.SAFE_STATE, 6)))
    assert act.state == NodeState.SAFE_STATE


def test_sim_serve_process_speaks_can_and_serial_and_stops_cleanly(tmp_path: Path) -> None:
    state = tmp_path / "state.json"
    proc = subprocess.Popen([sys.executable, "-m", "sim", "serve", "--state-file", str(state),
                             "--effect", "quadratic_damping=100"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        end = time.monotonic() + 60
        while not state.exists():
            assert proc.poll() is None and time.monotonic() < end, proc.stderr.read()
            time.sleep(0.05)
        ends = json.loads(state.read_text())
        assert ends["can"]["host"] == "127.0.0.1" and ends["pid"] == proc.pid
        bus = can.Bus(interface="socketcand", host="127.0.0.1", port=ends["can"]["port"],
                      channel=ends["can"]["channel"])
        try:
            ids = _receive_ids(bus, 1.0)
        finally:
            bus.shutdown()
        assert ids.count(cm.TABLE_SENSOR_ID) > 600, len(ids)  # 1 kHz, on a loaded machine
        assert {cm.FEEDBACK_BASE + i for i in range(1, 7)} <= set(ids)
        with serial.Serial(ends["serial"]["path"], 921600, timeout=0.05) as port:
            port.reset_input_buffer()
            frames = []
            end = time.monotonic() + 0.5
            decoder = FrameDecoder()
            while time.monotonic() < end:
                frames += decoder.feed(port.read(max(1, port.in_waiting)))
        assert len(frames) > 250, decoder.stats
    finally:
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert "mass sensor on /dev/pts/" in out
    assert not state.exists()


def test_sim_serve_names_an_unknown_effect() -> None:
    proc = subprocess.run([sys.executable, "-m", "sim", "serve", "--effect", "gremlins=1"],
                          capture_output=True, text=True, timeout=60, check=False)
    assert proc.returncode == 2 and "gremlins" in proc.stderr


def _receive_ids(bus: can.BusABC, seconds: float) -> list[int]:
    ids = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        msg = bus.recv(timeout=0.05)
        if msg is not None:
            ids.append(msg.arbitration_id)
    return ids


def test_a_slow_compile_does_not_leave_the_plant_catching_up(monkeypatch) -> None:
    """The integrator is compiled before the rig's clock starts. A cold compile (90 s on
    a 2-core EPYC) made after it left the plant's grid that far behind, and the first
    run's sensors silent past the liveness limit while it caught up."""
    import sim.rig_sim as rig_sim

    compile_s = 0.5
    real = rig_sim.warm_up

    def slow_warm_up(model) -> None:
        time.sleep(compile_s)  # what a cold numba cache costs, scaled down
        real(model)

    monkeypatch.setattr(rig_sim, "warm_up", slow_warm_up)
    began = time.monotonic()
    with rig_sim.SimRig(load_config()) as rig:
        ready = time.monotonic()
        # the grid starts after the compile, and is a chunk or so ahead of now, not behind
        assert rig.t0 >= began + compile_s
        assert rig.plant.computed_until >= ready - 0.05
