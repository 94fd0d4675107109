"""The force-driven loop on the measured benchmarks in shared/datasets (EMPS, Silverbox).

The datasets live beside the repository (CI clones it with `shared/` next to it).
If they are missing these tests FAIL, they do not skip. Both recipes run on the
full defined sections (EMPS ~1 s, Silverbox ~5 s), so the numbers asserted here
are the ones docs/datasets.md reports (`analysis datasets all`).

`analysis fit` on the raw EMPS training CSV (the user's path: no held-out record, the
preparation chosen from the data) is checked against the same figures.

Margins: the EMPS figures are deterministic (same preparation and OLS as the
benchmark's MATLAB script), so the published ones are checked to their last
printed digit; the loop's own figures get ~1 % margins, enough for BLAS and
scipy-version rounding, far below any change of model. Silverbox margins are
wider (5–10 %) because the simulation integrates over 40 000 samples.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from analysis.cli import main
from analysis.force_driven import datasets as ds

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

ROOT = Path(__file__).resolve().parents[2] / "shared" / "datasets"


def test_datasets_are_present():
    for name in ("emps/emps_train_DATA_EMPS.csv.gz", "emps/emps_test_DATA_EMPS_PULSES.csv.gz",
                 "silverbox/silverbox_SNLS80mV.csv.gz"):
        assert (ROOT / name).is_file(), f"missing {ROOT / name} (shared/ beside the repo)"


@pytest.fixture(scope="module")
def emps():
    return ds.emps(ROOT)


@pytest.fixture(scope="module")
def silverbox():
    return ds.silverbox(ROOT)


def test_emps_reproduces_the_published_models(emps):
    pub = ds.EMPS_PUBLISHED
    # the same preparation, columns and least squares: the published figures to 4 decimals
    assert 100 * emps.symmetric.relative_error == pytest.approx(
        pub["symmetric"]["relerr_pct"], abs=6e-5)
    assert 100 * emps.directional.relative_error == pytest.approx(
        pub["direction_dependent"]["relerr_pct"], abs=6e-5)
    assert 100 * emps.cross_test["symmetric"] == pytest.approx(
        pub["symmetric"]["cross_test_pct"], abs=6e-5)
    p = emps.symmetric.parameters()
    for key, name in (("M", "mass"), ("Fv", "viscous"), ("Fc", "coulomb_friction"),
                      ("offset", "force_offset")):
        assert p[name] == pytest.approx(pub["symmetric"][key], abs=6e-5), key
    for key, value in emps.directional_as_published().items():
        assert value == pytest.approx(pub["direction_dependent"][key], abs=6e-5), key


def test_emps_loop_finds_coulomb_then_direction_dependent_friction(emps):
    loop = emps.loop
    assert loop.effects_added[:2] == ["coulomb_friction", "asymmetric_damping"]
    # Measured, and explained in docs/datasets.md: after Coulomb friction the offset passes
    # every test (it cuts the residual by 67 %) but the direction-dependent friction cuts
    # more (81 %); once that is in, the offset is no longer significant (p = 0.17). The
    # published direction-dependent model says the same: (Fc+ - Fc-)/2 = -0.24 N.
    assert "force_offset" not in loop.effects_added
    offset = [r for r in loop.refused if r["candidate"] == "force_offset"]
    assert any(r["round"] == 2 and "asymmetric_damping cuts more" in r["reason"] for r in offset)
    assert any(r["round"] >= 3 and "not significant" in r["reason"] for r in offset)
    # before (mass + viscous) and after, on the identification record, as fractions
    assert loop.base.relative_error == pytest.approx(0.17983, rel=0.01)
    assert loop.steps[1].error_after == pytest.approx(0.031179, rel=0.01)  # M, Fv, Fc, c_ext
    # after: within 20 % of the published 3.11 % (measured 3.00 %, with quadratic damping)
    published = ds.EMPS_PUBLISHED["direction_dependent"]["relerr_pct"] / 100
    assert abs(loop.final.relative_error - published) < 0.2 * published
    assert loop.final.relative_error <= published
    # each step predicts the pulse record better: 17.8 % -> 5.3 %
    assert all(s.heldout_after < s.heldout_before for s in loop.steps)
    assert loop.heldout_after < 0.35 * loop.heldout_before
    # the flexibility the rigid model lacks (PROVENANCE §3.5) is left unexplained, not forced
    assert loop.unexplained


TRAIN = ROOT / "emps" / "emps_train_DATA_EMPS.csv.gz"
EMPS_EFFECTS = ["coulomb_friction", "asymmetric_damping", "quadratic_damping"]


def _fit_emps_train(tmp_path, *flags: str) -> dict:
    """`analysis fit` on the raw EMPS training CSV, as a user runs it; its JSON."""
    out = tmp_path / "fit.json"
    assert main(["fit", str(TRAIN), "--force", "force_N", "--position", "qm_m", *flags,
                 "--json", str(out)]) == 0
    return json.loads(out.read_text())


def test_emps_cli_default_path_adds_the_benchmarks_three_effects(emps, tmp_path, capsys):
    # no held-out record, no preparation given: blocked 4-fold cross-validation within the
    # record, Butterworth 171.3 Hz (Cp), spectral derivatives, decimation by 5
    doc = _fit_emps_train(tmp_path)
    assert doc["effects_added"] == EMPS_EFFECTS
    # the spring predicts the backward strokes 6 % better and the forward strokes 3 % worse
    stiff = [r["reason"] for r in doc["refused"] if r["candidate"] == "asymmetric_stiffness"]
    assert any("worse while moving forwards" in r for r in stiff), stiff
    # The benchmark's figure (3.0015 %, `analysis datasets emps`) is over 0-40 Hz; the default
    # path keeps 0-80 Hz, and says so. Doubling the band, at either preparation, raises the
    # figure of these three effects by 12-16 % (3.002 -> 3.495 % at 100 Hz central, 2.927 ->
    # 3.278 % at 171.3 Hz spectral; docs/datasets.md), hence 20 %. Measured: 3.278 %.
    bench = emps.loop.final.relative_error
    assert doc["error_band_hz"] == pytest.approx(80.0)
    assert bench <= doc["error_after"] <= 1.2 * bench
    assert "the force error is over 0-80 Hz" in capsys.readouterr().out


def test_emps_cli_at_the_benchmarks_band_reaches_its_figure(emps, tmp_path):
    bench = emps.loop.final.relative_error
    # the same band as the benchmark, cutoff and derivatives still chosen from the data:
    # measured 2.967 % (-1.2 %); the rest is the 171.3 Hz Butterworth against 100 Hz
    doc = _fit_emps_train(tmp_path, "--decimate", "10")
    assert doc["effects_added"] == EMPS_EFFECTS
    assert doc["error_band_hz"] == pytest.approx(40.0)
    assert doc["error_after"] == pytest.approx(bench, rel=0.03)
    # the recipe's own preparation: the same rows and least squares, so the same figure
    doc = _fit_emps_train(tmp_path, "--cutoff", "100", "--decimate", "10",
                          "--derivatives", "central")
    assert doc["effects_added"] == EMPS_EFFECTS
    assert doc["error_after"] == pytest.approx(bench, rel=1e-6)


def test_silverbox_finds_the_cubic_stiffness(silverbox):
    loop = silverbox.loop
    assert loop.effects_added[0] == "cubic_stiffness"
    step = loop.steps[0]
    assert step.value > 0 and step.std < 0.01 * step.value  # hardening, well determined
    # quadratic damping cuts the equation error but makes the simulated output worse
    assert any(r["candidate"] == "quadratic_damping" and "held-out" in r["reason"]
               for r in loop.refused)
    before, after = silverbox.simulation_before, silverbox.simulation_after
    # measured: linear 14.46 / 6.63 / 6.99 mV, with the cubic 1.70 / 0.92 / 0.94 mV
    assert before["arrow (full)"] == pytest.approx(14.46e-3, rel=0.05)
    assert after["arrow (full)"] < 2.0e-3
    for name in ds.SILVERBOX_TESTS:
        assert after[name] < before[name] / 6, name


def test_datasets_command_writes_json(tmp_path, capsys):
    out = tmp_path / "emps.json"
    assert main(["datasets", "emps", "--data-dir", str(ROOT), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "| symmetric: M, Fv, Fc, offset | 4.0834 % | 4.0834 %" in text
    doc = json.loads(out.read_text())["emps"]
    for key in ("parameters", "error_before", "error_after", "effects_added", "loop",
                "unexplained", "model", "published"):
        assert key in doc


def test_missing_datasets_directory_is_a_one_line_error(tmp_path, capsys):
    assert main(["datasets", "emps", "--data-dir", str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "no datasets directory" in err


def test_datasets_are_found_from_an_installed_package(tmp_path, monkeypatch):
    """An installed package's own path leads into site-packages: the data are found
    from the environment or the working tree, and the error says where it looked."""
    monkeypatch.setattr(ds, "SOURCE_TREE_DATA", tmp_path / "site-packages" / "nothing")
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    monkeypatch.delenv(ds.DATA_ENV, raising=False)
    with pytest.raises(ds.DataError) as e:
        ds.data_dir()
    assert str(work / "shared" / "datasets") in str(e.value) and ds.DATA_ENV in str(e.value)
    monkeypatch.setenv(ds.DATA_ENV, str(ROOT))
    assert ds.data_dir() == ROOT.resolve()
    monkeypatch.delenv(ds.DATA_ENV)
    (tmp_path / "shared").symlink_to(ROOT.parent)  # shared/ beside the working directory
    assert ds.data_dir() == (tmp_path / "shared" / "datasets").resolve()
