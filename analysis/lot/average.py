"""How well the lot's average predicts each unit: the unit's runs simulated with the
lot-average constants and compared with what was measured.

The task a lot sends to a worker once every unit is fitted and the family judged. It
uses `analysis fit`'s own preparation (the table motion estimated from the table
sensor's samples) and its error measure (`run_error`: residual RMS over the mass
sensor's noise, 1 for a right model; NRMSE of z), with the unit's own mass. Run files
whose table channel was fitted a time offset (`channel_skew`) are predicted without it:
the offset belongs to the unit's own fit.
"""

from __future__ import annotations

from pathlib import Path

from analysis.identify.loading import load_runs
from analysis.identify.pipeline import run_error, start_model
from analysis.identify.prepare import prepare
from analysis.lot.unit import FitOptions, UnitSpec, one_core
from analysis.model.isolator import IsolatorModel


def average_model(average: dict[str, float], mass: float) -> IsolatorModel:
    """Eq 10 (the report's structure) with the lot's average constants, for this mass."""
    return start_model(mass).with_parameters(**average)


def predict_unit(spec: UnitSpec, options: FitOptions, average: dict[str, float]
                 ) -> dict[str, dict[str, float]]:
    """run → {"residual_over_noise", "nrmse_z"} of the unit's runs under the lot average."""
    one_core()
    loaded = load_runs([Path(f) for f in spec.files], options.mass, options.units,
                       options.include_aborted)
    model = average_model(average, loaded.runs[0].mass)
    out = {}
    for run in loaded.runs:
        e = run_error(model, prepare(run))
        out[run.name] = {"residual_over_noise": e.residual_over_noise, "nrmse_z": e.z}
    return out
