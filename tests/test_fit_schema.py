"""The fit document's one schema (analysis/fit_schema.py): a hand-made result round-trips,
the TUI's reader (rig/tui/fit_summary.py) refuses another version in one line, and a
real `analysis fit --json` document reads back through both and writes back the same."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from analysis.cli import main
from analysis.fit_schema import (
    SCHEMA_VERSION,
    AppendixA,
    ChannelSkew,
    Conditioning,
    Estimate,
    Evidence,
    FitResult,
    LoopOutcome,
    LoopStep,
    ModelTerm,
    Preparation,
    Refusal,
    ResidualTests,
    RunError,
    Unexplained,
    VariableProjection,
)
from analysis.identify.synthetic import synthetic_run
from analysis.model.model_json import covariance_from, model_json
from analysis.model.report_constants import report_model
from rig.errors import DataError
from rig.tui import fit_summary
from tests.test_analysis_fit_cli import write_csv

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

TESTS = ResidualTests(1.02, 31.5, 0.12, True, 0.0113, {"u_e": 0.01, "u2_e": 0.02, "u2_e2": 0.0},
                      "z near the dead band's edge", "0–2 Hz", {"0–2 Hz": 0.6, "above 50 Hz": 0.4})
ERR = RunError(0.004, 0.02, 0.09, 410.0, 1.7)


def tiny_result() -> FitResult:
    """Two constants, one run, one step of the loop: every record of the schema once."""
    k1 = Estimate(77370.0, 1732.3, "N/m", (73974.8, 80765.2))
    step = LoopStep("quadratic_damping", "c_q", Estimate(800.0, 3.0, "N/(m/s)^2"),
                    Evidence("score (Lagrange multiplier) χ²₁", 2113.2, 0.41, 980.0, None, "zd",
                             "damping that grows with the square of the velocity",
                             "A, B better", TESTS),
                    {"A": ERR}, {"A": RunError(0.002, None, None, None, 1.01)})
    loop = LoopOutcome((step,), ("quadratic_damping",), {"A": ERR}, {"A": ERR}, TESTS, TESTS,
                       Unexplained(False, "white"), (Refusal("preload", "t = 0.3"),),
                       (Conditioning("preload", "F0", 0.01, None, ("k2",), True),))
    return FitResult(
        parameters={"k1": k1, "F_break": Estimate(91.6, None, "N", held=True),
                    "c_q": Estimate(800.0, 3.0, "N/(m/s)^2", (794.1, 805.9))},
        runs={"A": {"k1": k1}}, error={"A": ERR},
        model=(ModelTerm("k1", "linear_spring", "k z", True),),
        identified_model=model_json(report_model("A")), estimate="joint output error",
        held=("F_break",), flagged_runs={"A": ("k1",)}, consistent_range={"F_break": (9.0, 275.0)},
        channel_skew_s={"A": ChannelSkew(1e-4, 2e-6, 3e-6, 1e-7)},
        appendix_a=AppendixA(("k1",), {"k1": 7.7e4}, {"k1": 1.7e3}, 4.1e4, ((2.0,),), (3.0,),
                             ((1.1,),), 1.0, ((1.0,),), 3001),
        variable_projection=VariableProjection({"alpha": 192.5}, {"k1": 7.7e4}, 4.0e4, 311),
        preparation={"A": Preparation("savgol", None, 2.5e-5, 2.5e-5, "quintic", 0.61)},
        loop=loop, parameters_base_model={"k1": k1})


def test_a_hand_made_result_round_trips() -> None:
    result = tiny_result()
    doc = json.loads(json.dumps(result.to_json_dict()))  # plain JSON all the way down
    assert list(doc)[:2] == ["schema_version", "parameters"] and doc["schema_version"] == 1
    assert FitResult.from_json_dict(doc) == result
    assert doc["error"]["A"]["force_rms_N"] == 410.0  # the fit table's keys …
    assert doc["loop"][0]["error_after"]["A"] == {"z": 0.002, "residual_over_noise": 1.01}
    assert "ci95" not in doc["loop"][0]["value"] and doc["parameters"]["F_break"]["held"]
    no_loop = FitResult.from_json_dict({k: v for k, v in doc.items()
                                        if k not in ("loop", "effects_added", "error_before",
                                                     "error_after", "residual_before",
                                                     "residual_after", "unexplained", "refused",
                                                     "conditioning", "parameters_base_model")})
    assert no_loop.loop is None and no_loop.parameters == result.parameters
    del doc["loop"][0]["evidence"]["F"]
    with pytest.raises(DataError, match=r"^fit JSON loop\[0\]\.evidence lacks F$"):
        FitResult.from_json_dict(doc)


def test_another_version_is_refused_in_one_line(tmp_path: Path) -> None:
    doc = tiny_result().to_json_dict() | {"schema_version": 2}
    for read in (fit_summary.summarize, FitResult.from_json_dict):
        with pytest.raises(DataError) as e:
            read(doc)
        assert str(e.value) == "fit JSON is schema version 2, this program reads version 1"
    path = tmp_path / "fit.json"
    path.write_text(json.dumps({k: v for k, v in doc.items() if k != "schema_version"}))
    with pytest.raises(DataError, match=r"fit\.json: fit JSON has no schema_version") as e:
        fit_summary.read_summary(path)
    assert "\n" not in str(e.value)
    del doc["unexplained"]
    with pytest.raises(DataError, match=r"^fit JSON document lacks 'unexplained'$"):
        fit_summary.summarize(doc | {"schema_version": 1})


def test_a_real_fit_document_reads_back_through_both_readers(tmp_path: Path) -> None:
    run = synthetic_run(report_model("A"), "A", seed=11)
    out = tmp_path / "fit.json"
    assert main(["fit", str(write_csv(tmp_path / "A.csv", run)), "--mass", str(run.mass),
                 "--json", str(out)]) == 0
    text = out.read_text()
    result = FitResult.from_json_dict(json.loads(text))
    assert result.loop is not None and result.schema_version == SCHEMA_VERSION
    assert json.dumps(result.to_json_dict(), indent=2) == text  # what was written, exactly
    assert fit_summary.SCHEMA_VERSION == SCHEMA_VERSION  # the TUI reads what analysis writes
    summary = fit_summary.read_summary(out)
    assert [c.name for c in summary.constants] == list(result.parameters)
    assert summary.after == {r: e.residual_over_noise for r, e in result.loop.error_after.items()}


def test_a_constant_the_data_did_not_determine_is_left_out_without_a_warning() -> None:
    # c1's standard error is infinite and its correlations undefined: inf x 0 gave NaN
    # with a RuntimeWarning on the user's terminal (an error here, pyproject's filterwarnings)
    std = [2.0, np.inf, 1e-3]
    corr = [[1.0, np.nan, 0.5], [np.nan, 1.0, np.nan], [0.5, np.nan, 1.0]]
    block = model_json(report_model("A"), ["k1", "c1", "delta"], covariance_from(std, corr))
    assert block["covariance"]["names"] == ["k1", "delta"]
    assert np.allclose(block["covariance"]["matrix"], [[4.0, 1e-3], [1e-3, 1e-6]], rtol=1e-12)
