"""Serial faults of the mass sensor, against the in-process simulated rig.

Garbage, flipped bits and cut frames: the decoder resyncs, CRC rejects and lost
frames are counted, and each hole in mass_x is marked in /gaps (never filled
in). A port that closes mid-run or a sensor that stops sending aborts the run
into the safe state within the stated bound.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rig.wire.serial_frame import FrameDecoder
from sim.pty_sensor import SerialFaults
from sim.rig_sim import SimRig
from tests.test_faults_can import (
    LIVENESS_BOUND_S,
    LOAD_MARGIN_S,
    At,
    assert_aborted,
    measured,
    run,
)

pytestmark = pytest.mark.usefixtures("no_leaks")


def from_next_frame(sim: SimRig, fault: str) -> Callable[[], None]:
    """An action that sets a SerialFaults frame count (`fault`) to the frames sent so far."""
    def act() -> None:
        sent = sim.mass_sensor.stats.frames_sent
        sim.mass_sensor.faults = replace(sim.mass_sensor.faults, **{fault: sent})
    return act


PORT_LOST_BOUND_S = 0.05 + 0.05  # a receiver's read timeout, then one pass and the send


def test_garbage_bit_flips_and_cut_frames_are_rejected_counted_and_marked(
        sim: SimRig, tmp_path: Path) -> None:
    sim.mass_sensor.faults = SerialFaults(garbage_prob=0.02, bitflip_prob=0.02,
                                          truncate_prob=0.02, seed=5)
    out = run(sim, tmp_path, ramp_s=0.5)
    assert out.result.status == "success", out.result.reason
    serial = out.run.counters["serial"]
    sent = sim.mass_sensor.stats
    measured("serial_damage", crc_errors=serial["crc_errors"], lost=serial["lost"],
             bytes_discarded=serial["bytes_discarded"], corrupted_sent=sent.frames_corrupted)
    assert serial["crc_errors"] > 0 and serial["bytes_discarded"] > 0
    assert 0 < serial["lost"] <= sent.frames_corrupted
    # raw/serial holds only frames that passed the CRC, each once
    frames = FrameDecoder().feed(b"".join(bytes(d) for d in out.run.serial.data))
    assert len(frames) == len(out.run.serial.time)
    mass = out.run.channels["mass_x"]
    assert np.all(np.diff(mass.time) > 0)
    gaps = sum(g.count for g in out.run.gaps if g.channel == "mass_x")
    span = round((mass.time[-1] - mass.time[0]) / 1e-3) + 1
    assert abs(span - (len(mass.time) + gaps)) <= 2, (span, len(mass.time), gaps)
    assert gaps > 0
    raw_gaps = sum(g.count for g in out.run.gaps if g.channel == "raw/serial")
    assert raw_gaps == serial["lost"]


def test_the_port_closing_mid_run_aborts_into_the_safe_state(sim: SimRig,
                                                            tmp_path: Path) -> None:
    out = run(sim, tmp_path, At(0.3, from_next_frame(sim, "close_after_frames")))
    assert_aborted(out, "serial port (mass sensor) lost")
    measured("serial_closed", safe_state_s=out.safe_state_after(sim),
             file_closed_s=out.closed_after)
    assert out.safe_state_after(sim) < PORT_LOST_BOUND_S + LOAD_MARGIN_S


def test_a_sensor_that_stops_sending_aborts_within_the_liveness_bound(
        sim: SimRig, tmp_path: Path) -> None:
    out = run(sim, tmp_path, At(0.3, from_next_frame(sim, "stop_after_frames")))
    assert_aborted(out, "mass sensor silent")
    measured("serial_silent", safe_state_s=out.safe_state_after(sim),
             file_closed_s=out.closed_after)
    assert 0.2 < out.safe_state_after(sim) < LIVENESS_BOUND_S + LOAD_MARGIN_S
