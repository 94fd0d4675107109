"""The loop's work budget, counted in the simulator's RK4 steps rather than in seconds.

A few campaigns make every refit of the loop dear (a Bouc–Wen loop with a dry friction
beside it, whose stick–slip events each cost a dozen trial steps to locate, and four
effects and their shape constants free): an unseen Bouc–Wen loop with a sensor gain
(seed 5436) ran past ten minutes, its third and fourth effects and the final fit's
restarts each taking minutes, and what a person at the bench wants then is the answer
so far and the word that the search stopped short. Counted in the RK4 steps every
prediction took (`BatchResponse.rk4_steps`; the simulations are nearly all of the
loop's time, and a step costs about the same whatever the model), the budget stops
the search at the same place on a fast machine and a slow one: the effects named and
the residual do not follow the machine's speed, only the time does.

The count is per thread, so units of a lot fitted side by side in threads spend their
own budgets.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

# RK4 steps one loop may take: 4–7 minutes of one core of a 2-core AMD EPYC (1.9–3.4 M
# steps/s). The most a campaign of the unseen benchmark named right took: 532 M
# (Bouc–Wen + gain 5402, whose final fit's restarts take it from 1.50 to 1.06 x noise;
# stopped at 0.4 G it ended at 1.50), then 318 M (Bouc–Wen 805). Seed 5436 had taken
# 831 M by the end of its fourth effect, and its final fit's polish and restarts went
# on past ten minutes
LOOP_BUDGET = 800_000_000

_count = threading.local()


def spend(steps: int) -> None:
    """Count `steps` RK4 steps taken on this thread."""
    _count.spent = getattr(_count, "spent", 0) + int(steps)


def spent() -> int:
    """RK4 steps counted on this thread so far."""
    return getattr(_count, "spent", 0)


@dataclass
class Budget:
    """What one loop may still spend: `steps` from the count when it was made."""

    steps: int = LOOP_BUDGET
    start: int = 0

    @classmethod
    def starting_now(cls, steps: int = LOOP_BUDGET) -> Budget:
        return cls(steps, spent())

    def used(self) -> int:
        return spent() - self.start

    def exhausted(self) -> bool:
        return self.used() >= self.steps
