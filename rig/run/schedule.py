"""The run as a list of timed CAN messages: pure, no I/O, no clock (design.md §4.5).

Streaming: *buffered ahead with sample indices*. Every setpoint carries its
sample index; the actuators play sample i at t_start + i / rate, where t_start
is when START reached them. The rig enables the actuators, sends the first
`lead` samples, then START, then each later sample `lead` samples before it is
due, and STOP straight after the last sample: STOP means "no more setpoints:
play what you hold, then stay at the last one", so a late rig cannot cut the
motion short. So a late frame or a
scheduling hiccup of the rig up to lead / rate (100 ms at 400 Hz, 40 samples)
costs nothing, and an actuator that runs out of setpoints notices by index and
holds (its watchdog), rather than jumping.

`due` is seconds after START was sent; messages before START have negative due
times in send order.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from rig.geometry import ActuatorPlan
from rig.wire.can_messages import CommandKind, RigCommand, RigMessage, Setpoint

LEAD_SAMPLES = 40


@dataclass(frozen=True)
class Timed:
    """`message` to send `due` seconds after START (negative: before START)."""

    due: float
    message: RigMessage


def run_messages(plan: ActuatorPlan, lead: int = LEAD_SAMPLES) -> Iterator[Timed]:
    """ENABLE, the first `lead` samples, START, the rest paced, STOP; in send order."""
    rate, n = plan.rate, len(plan.t)
    lead = max(1, min(lead, n))
    counter = 0

    def command(kind: CommandKind, due: float, start: int = 0) -> Timed:
        nonlocal counter
        counter += 1
        return Timed(due, RigCommand(kind, counter, start))

    before = -1e-3  # prefill goes out in order, just before START
    yield command(CommandKind.ENABLE, before)
    for i in range(lead):
        yield from _sample(plan, i, before)
    yield command(CommandKind.START, 0.0, 0)
    for i in range(lead, n):
        yield from _sample(plan, i, (i - lead) / rate)
    yield command(CommandKind.STOP, max(0.0, (n - 1 - lead) / rate))


def _sample(plan: ActuatorPlan, i: int, due: float) -> Iterator[Timed]:
    for a in range(plan.extension.shape[1]):
        yield Timed(due, Setpoint(a + 1, i, float(plan.extension[i, a])))


def safe_state(counter: int = 255) -> RigCommand:
    """The command the rig sends in its `finally`: every actuator holds where it is."""
    return RigCommand(CommandKind.SAFE_STATE, counter)
