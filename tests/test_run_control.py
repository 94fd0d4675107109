"""The run's control surface (rig.run.status): e-stop from another thread, live listeners.

Against the in-process simulated rig of test_run_limits (real socketcand bus,
real pty, real HDF5): an e-stop mid-run aborts into the safe state and the file
says why; a listener that raises is dropped and logging goes on.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from rig.profile import load_profile
from rig.run.runner import run_profile
from rig.run.status import LiveStatus, RunControl
from rig.runfile import open_run
from rig.wire.can_messages import NodeState
from sim.rig_sim import SimRig
from tests.test_run_limits import _wait_for, hardware, profile_file

pytestmark = pytest.mark.usefixtures("no_leaks")


def test_emergency_stop_mid_run_aborts_into_the_safe_state(sim: SimRig, tmp_path: Path) -> None:
    spec = profile_file(tmp_path, "long", 1.0, 3.0)
    control = RunControl()
    seen: list[LiveStatus] = []
    pressed: list[float] = []

    def press_when_moving(status: LiveStatus) -> None:
        seen.append(status)
        if status.phase == "running" and status.elapsed > 0.5 and not pressed:
            pressed.append(time.monotonic())
            threading.Thread(target=control.emergency_stop).start()

    control.listeners.append(press_when_moving)
    result = run_profile(hardware(sim), load_profile(spec), spec.read_text(), tmp_path,
                         control=control)
    assert result.status == "abort" and "emergency stop" in result.reason
    assert pressed and result.duration < 0.3 + 0.5 + 1.0  # baseline + 0.5 s run + margin
    _wait_for(lambda: all(a.state == NodeState.SAFE_STATE for a in sim.actuators))
    status = open_run(result.path).status
    assert status.exit_status == "abort" and "emergency stop" in status.reason
    last = seen[-1]
    assert last.phase == "ended" and last.status == "abort"


def test_listeners_see_the_motion_and_a_failing_one_does_not_stop_the_run(
        sim: SimRig, tmp_path: Path) -> None:
    spec = profile_file(tmp_path, "small", 1.0, 0.5)
    control = RunControl()
    seen: list[LiveStatus] = []

    def broken(_: LiveStatus) -> None:
        raise RuntimeError("display crashed")

    control.listeners += [broken, seen.append]
    result = run_profile(hardware(sim), load_profile(spec), spec.read_text(), tmp_path,
                         control=control)
    assert result.status == "success", result.reason
    assert broken not in control.listeners
    phases = [s.phase for s in seen]
    assert {"baseline", "running", "settling", "ended"} <= set(phases)
    # ~20 Hz over ~1.2 s of run; a loaded machine may publish less often, never more
    assert 10 <= len(seen) <= 40
    running = [s for s in seen if s.phase == "settling"][-1]
    t, u = running.table_u
    assert len(t) > 100 and np.nanmax(u) == pytest.approx(0.0254, abs=1e-3)  # the 1 in ramp
    assert all(a.status in {"RUNNING", "ENABLED", "SAFE_STATE"} for a in running.actuators)
    assert np.isfinite(running.actuators[0].setpoint)
    assert running.frames["can"] > 0 and running.frames_per_s > 100
