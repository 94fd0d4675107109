"""The CAN bus load: the cyclic traffic of a configuration against its bitrate and budget.

Frame sizes come from the rig's DBC (rig.wire.can_messages); the bit counts are
those of classical CAN with 11-bit ids, bit stuffing at its best and its worst.
"""

from __future__ import annotations

from dataclasses import dataclass

from rig.config import RigConfig
from rig.errors import LimitError
from rig.wire.can_messages import ACTUATORS, NODES, database

STUFFED_OVERHEAD_BITS = 34  # SOF, 11-bit id, RTR, IDE, r0, DLC, 15-bit CRC: bit-stuffed
FIXED_OVERHEAD_BITS = 13  # CRC and ACK delimiters, ACK slot, 7-bit EOF, 3-bit intermission


def frame_bits(data_bytes: int = 8) -> tuple[int, int]:
    """(best, worst) bits a classical 11-bit data frame takes on the bus, intermission included.

    Worst case: one stuff bit after every 4 of the stuffed part but the first, so
    8 data bytes take 111 bits best, 135 worst.
    """
    stuffed = STUFFED_OVERHEAD_BITS + 8 * data_bytes
    best = stuffed + FIXED_OVERHEAD_BITS
    return best, best + (stuffed - 1) // 4


@dataclass(frozen=True)
class Stream:
    """A cyclic message: `senders` frames of `data_bytes` each, `rate` (Hz) times a second."""

    name: str
    senders: int
    rate: float
    data_bytes: int

    @property
    def frames_per_s(self) -> float:
        return self.senders * self.rate


@dataclass(frozen=True)
class BusLoad:
    """The cyclic traffic of a configuration against its bitrate (bit/s) and budget (fraction)."""

    bitrate: int
    budget: float
    streams: tuple[Stream, ...]

    @property
    def frames_per_s(self) -> float:
        return sum(s.frames_per_s for s in self.streams)

    def bits_per_s(self, case: str = "worst") -> float:
        """Bus bits per second with `case` 'best' or 'worst' bit stuffing."""
        pick = {"best": 0, "worst": 1}[case]
        return sum(s.frames_per_s * frame_bits(s.data_bytes)[pick] for s in self.streams)

    @property
    def load_best(self) -> float:
        return self.bits_per_s("best") / self.bitrate

    @property
    def load_worst(self) -> float:
        return self.bits_per_s("worst") / self.bitrate

    @property
    def fits(self) -> bool:
        return self.load_worst <= self.budget

    def format(self) -> str:
        """A table of the streams, frames/s and the load in both cases."""
        lines = [f"CAN bus load at {self.bitrate:,} bit/s (budget {self.budget:.0%} worst case)"]
        for s in self.streams:
            lines.append(f"  {s.name:<13} {s.senders} x {s.rate:>6g} Hz {s.frames_per_s:>8,.0f} "
                         f"frames/s")
        lines.append(f"  {'total':<25} {self.frames_per_s:>8,.0f} frames/s")
        for case, load in (("best", self.load_best), ("worst", self.load_worst)):
            bits = {frame_bits(s.data_bytes)[case == "worst"] for s in self.streams}
            per = "/".join(str(b) for b in sorted(bits))
            lines.append(f"  {case:<5} case, {per}-bit frames: {self.bits_per_s(case):>10,.0f} "
                         f"bit/s = {load:.1%}")
        lines.append(f"  {'fits' if self.fits else 'OVER'} the {self.budget:.0%} budget")
        return "\n".join(lines)


def bus_load(config: RigConfig) -> BusLoad:
    """The cyclic frames of `config` (commands are events and ride in the budget's headroom)."""
    db = database()

    def size(name: str) -> int:
        return db.get_message_by_name(name).length

    rates = config.rates
    streams = (
        Stream("setpoints", len(ACTUATORS), rates.setpoint, size("ActuatorSetpoint1")),
        Stream("feedback", len(ACTUATORS), rates.feedback, size("ActuatorFeedback1")),
        Stream("table sensor", 1, config.table_sensor.sample_rate, size("TableSensor")),
        Stream("heartbeats", len(NODES), rates.heartbeat, size("HeartbeatRIG")),
    )
    return BusLoad(config.can.bitrate, config.can.load_budget, streams)


def check_bus_load(config: RigConfig) -> BusLoad:
    """`bus_load(config)`, or LimitError if the worst case is over the budget."""
    load = bus_load(config)
    if not load.fits:
        raise LimitError(
            f"CAN bus load {load.frames_per_s:,.0f} frames/s is {load.load_worst:.1%} of "
            f"{load.bitrate:,} bit/s with worst-case stuffing ({load.load_best:.1%} best case), "
            f"over the {load.budget:.0%} budget; lower [rates] or raise can.load_budget")
    return load
