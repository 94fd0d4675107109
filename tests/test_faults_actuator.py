"""Actuator faults: a stuck valve, a stalled feedback stream, and delivery stalls that must
not trip anything. In-process simulated rig, plus the interlock on its own (rig.run.interlocks).

Feedback carries the servo tick of its measurement (the setpoint index being played),
so the following error is judged against exactly that setpoint: a stuck valve is
caught as soon as the setpoints have moved 1 in away from it (plus the servo-lag
allowance), and a feedback delivered 0.35 s late is still judged correctly.
"""

from __future__ import annotations

import re
import threading
import time
from pathlib import Path

import can
import numpy as np
import pytest

from rig.config import load_config
from rig.geometry import actuator_plan
from rig.profile import load_profile
from rig.run import runner
from rig.run.interlocks import (
    FEEDBACK_LIVENESS_S,
    FOLLOWING_LIMIT_M,
    START_GRACE_S,
    Interlocks,
)
from rig.wire import can_messages as cm
from rig.wire.can_messages import CommandKind, Feedback, NodeState, RigCommand, Setpoint
from sim.devices import ActuatorController
from sim.rig_sim import SimRig
from tests.test_faults_can import (
    FEEDBACK_BOUND_S,
    LOAD_MARGIN_S,
    At,
    assert_aborted,
    measured,
    run,
)
from tests.test_run_limits import hardware, profile_file

pytestmark = pytest.mark.usefixtures("no_leaks")


FEEDBACK_PERIOD_S = 0.01  # 100 Hz (data/rig.toml)
PASS_AND_SEND_S = 0.05  # one pass of the runner's loop and the SAFE_STATE send


def test_a_stuck_valve_trips_the_following_interlock_naming_the_actuator(
        sim: SimRig, tmp_path: Path) -> None:
    """Actuator 3 stops mid-ramp while claiming RUNNING; all six go to the safe state.

    Judged as the rig can be: the feedback that trips it is the first whose own
    setpoints (less the servo-lag allowance) are 1 in from where the valve stuck, and
    the six are safe within one pass and the send of that frame reaching the bus.
    Not from the instant the setpoints moved away: that adds the in-process simulated
    rig's own lateness in putting a feedback on the bus, which shares this process's
    GIL with the rig (0.003-0.30 s measured on a 2-core host), where a real
    controller's feedback leaves on its hardware clock.
    """
    unix_minus_monotonic = time.time() - time.monotonic()  # bus stamps are Unix time
    out = run(sim, tmp_path, At(0.25, lambda: sim.stick_valve(3)), ramp_in=3.0, ramp_s=0.6)
    assert_aborted(out, "actuator 3 following error")
    assert all(a.state == NodeState.SAFE_STATE for a in sim.actuators)
    tripped = re.search(r"at setpoint (\d+) \(t = ([\d.]+) s\)", out.result.reason)
    assert tripped, out.result.reason
    tick, stamp = int(tripped[1]), float(tripped[2])  # the tripping feedback's tick, bus s
    # the first tick a feedback could trip on: its setpoint window all 1 in from the piston
    stuck_at = float(out.run.channels["actuator_feedback_3"].value[-1])  # m, as reported
    plan = actuator_plan(hardware(sim), load_profile(profile_file(tmp_path, "fault", 3.0, 0.6)))
    watch = Interlocks(plan.rate)
    watch.start(plan, 0.0)
    stuck_from = sim.actuators[2].tick(out.injected)  # the servo tick it stuck at
    first = next((k for k in range(max(stuck_from, 0), len(plan.t))
                  if watch.following_error(3, k, stuck_at) > FOLLOWING_LIMIT_M), None)
    assert first is not None, "the setpoints never moved 1 in from the stuck valve"
    per_feedback = round(plan.rate * FEEDBACK_PERIOD_S)  # ticks between two feedbacks
    # one tick either side for the 1 µm resolution of the reported position
    assert first - 1 <= tick <= first + per_feedback, (tick, first)
    # the rig's reaction: from the tripping frame on the bus to the last actuator safe
    frames = out.run.can
    stamped = frames.time[frames.arbitration_id == cm.FEEDBACK_BASE + 3]
    on_bus = stamped[np.argmin(np.abs(stamped - stamp))]  # the reason rounds it to 1 ms
    on_bus_monotonic = float(out.run.meta["start_unix"]) + on_bus - unix_minus_monotonic
    reaction = max(a.safe_state_at for a in sim.actuators) - on_bus_monotonic
    measured("stuck_valve", frame_to_safe_s=reaction, after_stick_s=out.safe_state_after(sim),
             file_closed_s=out.closed_after)
    # the file's start_unix and the rig's mapping of bus stamps agree to well under 5 ms
    assert -0.005 < reaction < PASS_AND_SEND_S + LOAD_MARGIN_S


def test_a_stalled_feedback_stream_aborts_naming_the_actuator(sim: SimRig,
                                                             tmp_path: Path) -> None:
    out = run(sim, tmp_path, At(0.3, lambda: sim.stall_feedback(4)))
    assert_aborted(out, "actuator 4 feedback silent")
    measured("feedback_stall", safe_state_s=out.safe_state_after(sim),
             file_closed_s=out.closed_after)
    assert FEEDBACK_LIVENESS_S - FEEDBACK_PERIOD_S < out.safe_state_after(sim)
    assert out.safe_state_after(sim) < FEEDBACK_BOUND_S + LOAD_MARGIN_S


class _StallingBus:
    """The rig's own bus, whose receive path stalls once for `seconds` when armed: the
    rig's process descheduled, as on a loaded CI machine. Sending is not delayed."""

    def __init__(self, bus: can.BusABC, seconds: float) -> None:
        self._bus, self.seconds, self.armed = bus, seconds, False

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if self.armed:
            self.armed = False
            time.sleep(self.seconds)
        return self._bus.recv(timeout)

    def __getattr__(self, name: str) -> object:
        return getattr(self._bus, name)


def test_a_receive_stall_during_the_ramp_trips_nothing(sim: SimRig, tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """0.35 s without a single frame read (longer than every liveness limit), then the
    backlog at once: the horizons wait for it, the ticks place every feedback."""
    buses: list[_StallingBus] = []

    def stalling_open_bus(config: object) -> _StallingBus:
        buses.append(_StallingBus(runner_open_bus(config), 0.35))
        return buses[-1]

    runner_open_bus = runner.open_bus
    monkeypatch.setattr(runner, "open_bus", stalling_open_bus)
    out = run(sim, tmp_path, At(0.0, lambda: setattr(buses[0], "armed", True)), ramp_s=0.4)
    assert out.result.status == "success", out.result.reason
    assert not buses[0].armed  # it did stall
    assert out.run.counters["can"]["lost"] == 0


def _plan(tmp_path: Path, ramp_in: float = 3.0, ramp_s: float = 0.6):
    path = profile_file(tmp_path, "unit", ramp_in, ramp_s)
    return actuator_plan(load_config(), load_profile(path))


def test_following_error_is_judged_by_tick_not_by_arrival(tmp_path: Path) -> None:
    """Feedback arriving 0.35 s late (stamped then) is judged against its own setpoint;
    a position 1 in off that setpoint trips at once, naming the actuator."""
    plan = _plan(tmp_path)
    watch = Interlocks(plan.rate)
    watch.start(plan, start_t=10.0)
    for k in range(0, len(plan.t), 4):  # every feedback 0.35 s late, on the true path
        late = 10.0 + k / plan.rate + 0.35
        watch.feedback(late, Feedback(1, k % 65536, float(plan.extension[k, 0]),
                                      NodeState.RUNNING))
    assert watch.faults == []
    k = 120  # mid-ramp: held where it was 20 ticks (50 ms) earlier is within the lag
    watch.feedback(10.3, Feedback(3, k, float(plan.extension[k - 20, 2]), NodeState.RUNNING))
    assert watch.faults == []
    off = float(plan.extension[k - 20:k + 2, 2].max()) + 0.026  # beyond every lagged setpoint
    watch.feedback(10.31, Feedback(3, k, off, NodeState.RUNNING))
    assert watch.faults and watch.faults[0].startswith("actuator 3 following error 26.0 mm")


def test_ticks_unwrap_across_the_16_bit_counter(tmp_path: Path) -> None:
    plan = _plan(tmp_path)
    watch = Interlocks(plan.rate)
    watch.start(plan, start_t=0.0)
    # 170 s into a long run the tick has wrapped (65536 at 400 Hz is 164 s)
    assert watch._unwrap(70000 % 65536, 70000 / plan.rate + 0.3) == 70000
    assert watch._unwrap(65533, 0.01) == -3  # a feedback measured just before START


def test_start_and_liveness_rules(tmp_path: Path) -> None:
    plan = _plan(tmp_path)
    watch = Interlocks(plan.rate)
    watch.start(plan, start_t=1.0)
    for i in range(1, 7):
        state = NodeState.ENABLED if i == 5 else NodeState.RUNNING
        watch.feedback(1.05, Feedback(i, 20, float(plan.extension[20, i - 1]), state))
    for source, stream in (("table", "can"), ("mass", "serial")):
        watch.sensor(source, 1.05)
        watch.reached(stream, 1.05)
    assert watch.check(1.05, since=1.0) is None
    watch.reached("can", 1.0 + START_GRACE_S + 0.01)
    assert "actuator 5 not RUNNING 0.25 s after START (it reports ENABLED)" in watch.check(
        1.3, since=1.0)


def test_silence_is_measured_up_to_what_the_rig_has_processed() -> None:
    """The rig's own backlog is not a silent sensor; a stream with nothing past a frame is."""
    watch = Interlocks(400.0)
    for i in range(1, 7):
        watch.feedback(0.5, Feedback(i, 0, 0.0, NodeState.ENABLED))
    for source, stream in (("table", "can"), ("mass", "serial")):
        watch.sensor(source, 0.5)
        watch.reached(stream, 0.5)
    assert watch.check(0.9, since=0.0) is None  # 0.4 s later, but nothing handled since
    watch.reached("can", 0.8)  # the bus has moved on 0.3 s without the table sensor
    assert watch.check(0.9, since=0.0).startswith("table sensor silent for 0.30 s")
    assert "the rig cannot keep up" in Interlocks(400.0).check(1.2, since=0.1)


def test_an_actuator_never_plays_a_grid_point_before_start_arrived() -> None:
    """The plant computes ahead, and after a stall it computes the past: START acts only
    from its arrival, and the servo tick counts the run from there."""
    now = [100.0]
    act = ActuatorController(1, rate=400.0, clock=lambda: now[0])
    act.on_frame(cm.to_can(RigCommand(CommandKind.ENABLE, 1)))
    for i in range(40):
        act.on_frame(cm.to_can(Setpoint(1, i, 0.001 * i)))
    act.on_frame(cm.to_can(RigCommand(CommandKind.START, 2, 0)))
    assert act.target(99.9) == 0.0 and act.started_at is None  # the past: still holding
    assert act.target(100.01) == pytest.approx(0.004)  # 4 samples after arrival
    assert act.started_at == 100.0
    assert act.tick(100.0) == 0 and act.tick(100.0101) == 4 and act.tick(99.9887) == -5
    assert act.tick(100.0501) == 20


class _StartOnRelease:
    """The controller's lock, which lets a START in (as the server thread would) the
    first time it is released: the worst moment for a feedback being built."""

    def __init__(self, act: ActuatorController) -> None:
        self.act, self.inner, self.pending = act, threading.Lock(), True

    def __enter__(self) -> None:
        self.inner.acquire()

    def __exit__(self, *exc: object) -> None:
        self.inner.release()
        if self.pending:
            self.pending = False
            self.act.on_frame(cm.to_can(RigCommand(CommandKind.START, 2, 0)))


def test_a_feedback_never_pairs_a_running_state_with_a_tick_from_before_start() -> None:
    now = [100.0]
    act = ActuatorController(1, rate=400.0, clock=lambda: now[0])
    act.on_frame(cm.to_can(RigCommand(CommandKind.ENABLE, 1)))
    now[0] = 100.5  # the tick before START counts from the controller's own origin
    act._lock = _StartOnRelease(act)  # type: ignore[assignment]
    frame = cm.from_can(act.feedback(100.5, 0.0))
    assert act.state == NodeState.RUNNING  # START did come in while it was being built
    before = ActuatorController(1, rate=400.0).tick(100.5) % (1 << 16)  # its own origin
    after = 0  # START's sample, at the instant it arrived
    assert (frame.status, frame.sequence) in ((NodeState.ENABLED, before),
                                              (NodeState.RUNNING, after)), frame


def test_sim_faults_parse_from_the_command_line() -> None:
    from rig.errors import ConfigError
    from sim.faults import parse_faults

    f = parse_faults(["can_drop=0.01", "can_seed=3", "serial_bitflip=0.5",
                      "stuck_valve=3@0.25", "stalled_feedback=2"])
    assert (f.bus.drop_prob, f.bus.seed, f.serial.bitflip_prob) == (0.01, 3, 0.5)
    assert (f.stuck_valve.actuator, f.stuck_valve.after_start_s) == (3, 0.25)
    assert (f.stalled_feedback.actuator, f.stalled_feedback.after_start_s) == (2, 0.0)
    for bad in ("gremlins=1", "can_drop=2", "can_drop=x", "stuck_valve=9@1", "stuck_valve"):
        with pytest.raises(ConfigError, match="--fault"):
            parse_faults([bad])
