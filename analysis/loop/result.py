"""What the loop returns: each effect it added, with its evidence, and the result.

The report (`report`) renders these for people and programs; the step's residual
and signature before it are kept for the evidence figure.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from analysis.loop.conditioning import Collinearity
from analysis.loop.evidence import Diagnosis
from analysis.loop.refit import Fit


@dataclass(frozen=True)
class Step:
    """One effect the loop added: its size, the evidence for it and the errors
    before and after."""

    added: str
    parameter: str
    value: float  # SI
    std: float
    unit: str
    evidence: dict[str, object]
    error_before: dict[str, dict[str, float]]
    error_after: dict[str, dict[str, float]]
    residual_before: np.ndarray  # concatenated, for the evidence figure
    signature_before: np.ndarray


@dataclass(frozen=True)
class LoopResult:
    """The loop's outcome: the base and final fits, the effects added, the residual
    before and after, and what was refused and why."""

    base: Fit
    final: Fit
    steps: tuple[Step, ...]
    diagnosis_before: Diagnosis
    diagnosis_after: Diagnosis
    error_before: dict[str, dict[str, float]]
    error_after: dict[str, dict[str, float]]
    unexplained: bool
    description: str
    refused: tuple[dict[str, object], ...] = field(default=())
    # each force candidate not added, against the final model's terms (`conditioning`)
    conditioning: tuple[Collinearity, ...] = field(default=())

    @property
    def effects_added(self) -> list[str]:
        return [s.added for s in self.steps]

    @property
    def indistinguishable(self) -> list[Collinearity]:
        """Force candidates the final model's own terms reproduce almost entirely."""
        return [c for c in self.conditioning if c.indistinguishable]
