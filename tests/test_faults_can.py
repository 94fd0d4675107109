"""CAN faults against the in-process simulated rig (real socketcand bus, pty and HDF5).

Frames dropped, duplicated and reordered are counted and marked, never
interpolated; error frames are counted; a lost, stalled or bus-off bus aborts
the run into the safe state within a stated bound (docs/reliability.md), and
the file says `abort` and why. Reaction times are measured here, from the
instant a fault is injected to the instant the actuators entered SAFE_STATE
(on the sim's clock, the host's monotonic clock) and to the return of
`run_profile` (the file closed with its status).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from rig.profile import load_profile
from rig.run.runner import RunResult, run_profile
from rig.run.status import LiveStatus, RunControl
from rig.runfile import RunFile, open_run
from rig.wire import can_messages as cm
from rig.wire.can_messages import Fault, NodeState
from sim.rig_sim import SimRig
from sim.socketcand_server import CAN_ERR_BUSOFF, BusFaults
from tests.test_run_limits import hardware, profile_file

pytestmark = pytest.mark.usefixtures("no_leaks")

# Bounds the tests hold a reaction to: the design figure (docs/reliability.md) plus
# room for a loaded 2-core machine, where a thread may wait 0.1–0.2 s for a core.
LOAD_MARGIN_S = 0.25
LIVENESS_BOUND_S = 0.25 + 0.05  # rig.run.interlocks LIVENESS_S + one pass and the send
FEEDBACK_BOUND_S = 0.3 + 0.05  # rig.run.interlocks FEEDBACK_LIVENESS_S + one pass and the send
LOST_BUS_BOUND_S = 0.05 + 0.3 + 0.05  # receiver poll + reconnect timeout + send


def measured(test: str, **figures: float) -> None:
    """Note a measured figure: appended as a JSON line to $RIG_RELIABILITY_LOG if set
    (how docs/reliability.md's table was filled), else only shown by `pytest -s`."""
    line = json.dumps({"test": test, **{k: round(v, 4) for k, v in figures.items()}})
    print(line)
    log = os.environ.get("RIG_RELIABILITY_LOG")
    if log:
        with open(log, "a", encoding="utf-8") as f:
            f.write(line + "\n")


class At:
    """A live listener that calls `action` once, `after` s past START, on the runner's thread.

    `t` is when it fired (host monotonic s), or what `action` returned if that is a
    later time (a fault the sim can only start at its next computed grid point).
    """

    def __init__(self, after: float, action: Callable[[], object]) -> None:
        self.after, self.action = after, action
        self.t: float | None = None

    def __call__(self, status: LiveStatus) -> None:
        if self.t is None and status.phase == "running" and status.elapsed >= self.after:
            self.t = time.monotonic()
            began = self.action()
            if isinstance(began, float):
                self.t = max(self.t, began)


@dataclass
class Outcome:
    result: RunResult
    run: RunFile
    injected: float | None  # host monotonic s
    returned: float  # host monotonic s run_profile returned: the file has its status

    def safe_state_after(self, sim: SimRig) -> float:
        """s from the injection until the last of the six actuators entered SAFE_STATE."""
        times = [a.safe_state_at for a in sim.actuators]
        assert all(t is not None and t >= self.injected for t in times), times
        return max(times) - self.injected

    @property
    def closed_after(self) -> float:
        return self.returned - self.injected


def run(sim: SimRig, tmp_path: Path, *inject: At, ramp_in: float = 1.0,
        ramp_s: float = 1.0) -> Outcome:
    """One run of a hold / ramp to `ramp_in` in `ramp_s` / hold profile, with the faults
    `inject`; the outcome's injection time is the last one's."""
    spec = profile_file(tmp_path, "fault", ramp_in, ramp_s)
    result = run_profile(hardware(sim), load_profile(spec), spec.read_text(), tmp_path,
                         control=RunControl(listeners=list(inject)))
    returned = time.monotonic()
    return Outcome(result, open_run(result.path), inject[-1].t if inject else None, returned)


def assert_aborted(out: Outcome, why: str) -> None:
    assert out.result.status == "abort", out.result.reason
    assert why in out.result.reason, out.result.reason
    status = out.run.status
    assert status.exit_status == "abort" and why in status.reason


def table_timestamps(run: RunFile) -> np.ndarray:
    frames = run.can
    keep = (frames.arbitration_id == cm.TABLE_SENSOR_ID) & ~frames.is_error
    return np.array([cm.decode(cm.TABLE_SENSOR_ID, bytes(d)).timestamp_us
                     for d in frames.data[keep]])


@pytest.mark.parametrize("p", [0.001, 0.05])
def test_dropped_duplicated_reordered_frames_are_counted_and_marked_never_invented(
        sim: SimRig, tmp_path: Path, p: float) -> None:
    sim.server.faults = BusFaults(drop_prob=p, duplicate_prob=p, reorder_prob=p, seed=11)
    out = run(sim, tmp_path, ramp_s=0.5)
    stats = sim.server.stats
    assert out.result.status == "success", out.result.reason  # commands go out 3 times
    can = out.run.counters["can"]
    assert 0 <= can["lost"] <= stats.frames_dropped  # the rig never sees its own frames
    assert can["duplicates"] <= stats.frames_duplicated
    assert can["reordered"] <= stats.frames_reordered
    measured(f"can_frames_{p}", lost=can["lost"], duplicates=can["duplicates"],
             reordered=can["reordered"], dropped_on_bus=stats.frames_dropped,
             gaps_table=sum(g.count for g in out.run.gaps if g.channel == "table_u"))
    if p >= 0.05:
        assert can["lost"] > 0 and can["duplicates"] > 0 and can["reordered"] > 0, can
    # table_u holds exactly one sample per distinct sensor sample received: a duplicate is
    # not written twice, a reordered one lands in its place, nothing is filled in
    table = out.run.channels["table_u"]
    assert len(table.time) == len(np.unique(table_timestamps(out.run)))
    assert np.all(np.diff(table.time) > 0)
    # every hole in the device clock is in /gaps, with its size
    gaps = sum(g.count for g in out.run.gaps if g.channel == "table_u")
    span = round((table.time[-1] - table.time[0]) / 1e-3) + 1
    assert abs(span - (len(table.time) + gaps)) <= 2, (span, len(table.time), gaps)
    assert gaps <= can["lost"] + 2
    for i in cm.ACTUATORS:
        assert np.all(np.diff(out.run.channels[f"actuator_feedback_{i}"].time) >= 0)


def test_an_error_burst_is_counted_and_a_bus_off_aborts(sim: SimRig, tmp_path: Path) -> None:
    """A burst of protocol-error frames is logged and counted; the run goes on. An error
    frame saying bus-off means this node is off the bus: abort."""
    burst = At(0.2, lambda: sim.server.inject_error_burst(25))
    bus_off = At(0.6, lambda: sim.server.inject_error_burst(1, CAN_ERR_BUSOFF))
    out = run(sim, tmp_path, burst, bus_off, ramp_s=1.5)
    assert_aborted(out, "CAN bus off")
    measured("bus_off", safe_state_s=out.safe_state_after(sim), file_closed_s=out.closed_after)
    frames = out.run.can
    assert int(np.sum(frames.is_error)) == 26
    assert out.run.counters["can"]["crc_errors"] == 26
    assert out.safe_state_after(sim) < 0.05 + LOAD_MARGIN_S


def test_a_disconnected_bus_aborts_and_the_safe_state_still_goes_out(
        sim: SimRig, tmp_path: Path) -> None:
    """Bus-off of the CAN endpoint: every client's connection is reset. The rig aborts
    and sends SAFE_STATE over a fresh connection (the actuators' watchdog is the backstop)."""
    out = run(sim, tmp_path, At(0.3, sim.server.disconnect_clients))
    assert_aborted(out, "CAN bus lost")
    measured("can_disconnect", safe_state_s=out.safe_state_after(sim),
             file_closed_s=out.closed_after)
    assert out.safe_state_after(sim) < LOST_BUS_BOUND_S + LOAD_MARGIN_S
    assert all(a.state == NodeState.SAFE_STATE for a in sim.actuators)


def test_a_stalled_bus_aborts_within_the_liveness_bound(sim: SimRig, tmp_path: Path) -> None:
    """Nothing reaches the bus for 0.6 s (a frozen gateway): the sensor and feedback go
    silent. SAFE_STATE cannot pass a dead bus either; the actuators hold by their own
    index watchdog (WATCHDOG_HOLD) once the setpoints they need are 0.1 s late."""
    out = run(sim, tmp_path, At(0.3, lambda: sim.server.stall(0.6)))
    assert_aborted(out, "silent")
    holds = [a.hold_at for a in sim.actuators if a.hold_at is not None]
    measured("can_stall", file_closed_s=out.closed_after,
             watchdog_hold_s=max(holds) - out.injected if holds else float("nan"))
    assert out.closed_after < LIVENESS_BOUND_S + LOAD_MARGIN_S + 0.3  # + close and refit
    held = [a.hold_at is not None or a.state == NodeState.SAFE_STATE for a in sim.actuators]
    assert all(held)
    assert all(a.faults & Fault.WATCHDOG_HOLD or a.state == NodeState.SAFE_STATE
               for a in sim.actuators)
