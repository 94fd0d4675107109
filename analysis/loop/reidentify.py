"""Each force candidate identified from the data again, not refitted from the base's valley.

The base fit has absorbed what a missing effect does into Eq 10's constants: a
large dry friction becomes c2 tanh(βż) with the dead band closed (δ → 0), for
then the two are the same force, and output error refitted from there with the
friction added sees a look-alike of c2 and stays. What sets the friction apart
is the dead band — Eq 10 has only c1 ż inside it, friction acts there too — and
only a fit that searches δ again with the friction in the model can see it.

So each candidate whose force is a function of (z, ż) — a regressor, the
report's appendix A with one more column — is identified by variable projection
(`analysis.identify.varpro.project`): α, β and δ searched, every linear
coefficient and the candidate's solved at each point, from the measured z, ż, ẍ.
Equation error has no valleys along the coefficients, so the start it gives the
output-error refit has never seen the base's compromise; and its σ² with and
without the candidate, both with the shapes searched, ranks the candidates by
what the data say rather than by a linearisation at the base fit.

Stateful terms (hysteresis, warm fluid) and sensor effects have no regressor of
(z, ż) alone; they keep the loop's other starts.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from analysis.identify.pipeline import LINEAR
from analysis.identify.varpro import Data, project
from analysis.loop.candidates import Candidate
from analysis.model.isolator import IsolatorModel
from analysis.model.terms import kind

SHAPES = ("alpha", "beta", "delta")


@dataclass(frozen=True)
class Reidentified:
    """A model identified by equation error with the candidate in it, and its σ² (N²)."""

    model: IsolatorModel
    sigma2: float


MIN_MOVING = 100  # samples with relative motion an identification by equation error needs


def moving(zd: np.ndarray, stop_velocity: float) -> np.ndarray | None:
    """Which samples have relative motion (appendix A drops rest); None where fewer than
    MIN_MOVING do (a stop velocity a fit has raised past nearly every sample's speed):
    then there is nothing to identify by equation error."""
    mask = np.abs(zd) > max(2.0 * stop_velocity, 1e-3)
    return mask if np.count_nonzero(mask) >= MIN_MOVING else None


def moving_data(z: Sequence[np.ndarray], zd: Sequence[np.ndarray],
                xdd: Sequence[np.ndarray], stop_velocity: float) -> Data | None:
    """The runs' samples with relative motion, stacked; None where too few move (`moving`)."""
    z, zd, xdd = (np.concatenate(list(v)) for v in (z, zd, xdd))
    mask = moving(zd, stop_velocity)
    return None if mask is None else Data(z[mask], zd[mask], xdd[mask])


def base_projection(model: IsolatorModel, data: Data) -> Reidentified:
    """Eq 10 (the model's own force terms) with α, β, δ searched: what a candidate must beat."""
    free = [t.name for t in model.terms if t.name in LINEAR or t.coef != 0.0]
    proj = project(model, data, SHAPES, free=free, signed=_signed(model, free))
    return Reidentified(proj.model, proj.fit.sigma2)


def with_candidate(model: IsolatorModel, c: Candidate, param: str, data: Data
                   ) -> Reidentified | None:
    """The model with the candidate's term, identified by equation error; None where the
    candidate has no regressor of (z, ż) or no shape keeps the springs and dampers
    positive (the projection then stays at its start: nothing was identified)."""
    if not c.term_kind or kind(c.term_kind).has_state or param not in model.parameters():
        return None
    free = [t.name for t in model.terms if t.name in LINEAR or t.coef != 0.0 or t.name == param]
    signed = _signed(model, free) + ([param] if c.sign == 0 else [])
    proj = project(model, data, SHAPES, free=free, signed=signed)
    if not np.isfinite(proj.fit.sigma2) or np.any(
            [v <= 0 for n, v in proj.fit.as_dict().items() if n not in signed]):
        return None
    return Reidentified(proj.model, proj.fit.sigma2)


def _signed(model: IsolatorModel, free: Sequence[str]) -> list[str]:
    """Effects already added whose sign is free (an offset, an asymmetry): not required > 0."""
    return [n for n in free if n not in LINEAR and model.term(n).kind in
            ("extension_damper", "compression_spring", "force_offset", "cubic_spring")]
