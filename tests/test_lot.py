"""`analysis lot` and `sim generate-lot`: a small simulated lot (8 units, 2 with worn seals,
1 with a corrupt file) on an in-process Dask cluster, resumed, and through worker
processes killed halfway; the robust distance, the family's verdicts and the store on
their own."""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from analysis.lot import schedule
from analysis.lot.cli import main
from analysis.lot.distance import robust_distances
from analysis.lot.family import judge_lot
from analysis.lot.store import UnitStore
from analysis.lot.unit import OK, Estimate, FitOptions, UnitResult, find_units, fit_unit
from analysis.model.model_json import model_from_json
from rig.units import to_si
from sim import cli_lot

MASS = float(to_si(6000, "lbm"))
SEED = 3  # units 5 and 8 carry the defect
DEFECT = 150.0  # N of Coulomb friction: worn rod seals


def generate_lot(*argv: str) -> int:
    """`sim generate-lot ARGV` in this process."""
    p = argparse.ArgumentParser(prog="sim")
    cli_lot.add_parser(p.add_subparsers(dest="command"))
    return cli_lot.run(p.parse_args(["generate-lot", *argv]))


def lot_main(*argv: str) -> tuple[int, str]:
    """`analysis lot ARGV` in this process: exit code and stdout."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(list(argv))
    return code, out.getvalue()


@dataclass(frozen=True)
class Lot:
    root: Path
    units: Path
    truth: dict
    defective: list[str]
    corrupt: str


@pytest.fixture(scope="module")
def lot(tmp_path_factory: pytest.TempPathFactory) -> Lot:
    root = tmp_path_factory.mktemp("lot")
    with contextlib.redirect_stdout(io.StringIO()):
        assert generate_lot("8", "--scatter", "5%", "--defect", f"coulomb_friction={DEFECT}",
                            "--defect-units", "2", "--seed", str(SEED), "--out",
                            str(root / "units"), "--truth", str(root / "truth.json")) == 0
    truth = json.loads((root / "truth.json").read_text())
    defective = sorted(u for u, t in truth["units"].items() if t["effects"])
    corrupt = next(u for u in sorted(truth["units"]) if u not in defective)
    b = root / "units" / corrupt / "B.csv"
    b.write_text("\n".join(b.read_text().splitlines()[:41]) + "\n0.041000,0.001,\n")  # cut
    return Lot(root, root / "units", truth, defective, corrupt)


@pytest.fixture(scope="module")
def cluster():
    from dask.distributed import LocalCluster

    with LocalCluster(processes=False, n_workers=1, threads_per_worker=2,
                      dashboard_address=None) as c:
        yield c


@pytest.fixture(scope="module")
def first(lot: Lot, cluster) -> dict:
    """The lot through the CLI in this process, on the in-process cluster (--scheduler)."""
    out = lot.root / "first"
    code, text = lot_main(str(lot.units), "--mass-lb", "6000", "--json", str(out / "lot.json"),
                          "--report", str(out / "report"), "--scheduler",
                          cluster.scheduler_address)
    assert code == 0
    return {"doc": json.loads((out / "lot.json").read_text()), "text": text, "out": out}


@pytest.mark.slow
def test_defective_units_flagged_with_their_effect_corrupt_one_reported(lot: Lot, first):
    doc = first["doc"]
    assert lot.defective == ["unit-005", "unit-008"]
    assert doc["lot"]["out_of_family"] == lot.defective
    assert doc["lot"]["failed"] == [lot.corrupt]
    assert doc["lot"]["in_family"] == sorted(set(lot.truth["units"]) - set(lot.defective)
                                             - {lot.corrupt})
    for u in lot.defective:
        unit = doc["units"][u]
        assert list(unit["effects"]) == ["coulomb_friction"]
        assert unit["effects"]["coulomb_friction"]["value"] == pytest.approx(DEFECT, rel=0.1)
        assert [r.split(" ")[0] for r in unit["reasons"]] == ["coulomb_friction"] or (
            unit["reasons"][0].startswith("coulomb_friction")
            and unit["reasons"][1].startswith("constants off the lot's"))
    reason = doc["units"][lot.corrupt]["reason"]
    assert reason.startswith("B.csv: row 42, column x") and "\n" not in reason
    text = first["text"]
    assert f"{lot.corrupt}: B.csv: row 42" in text and "out of family:" in text
    assert all(f"  {u}: coulomb_friction" in text for u in lot.defective)


@pytest.mark.slow
def test_each_units_constants_and_the_lot_spread_recovered(lot: Lot, first):
    doc = first["doc"]
    family = doc["lot"]["in_family"]
    for u in family:  # a worn unit's constants are the loop's business (docs/loop.md)
        fitted, true = doc["units"][u]["constants"], lot.truth["units"][u]["constants"]
        for n in ("k1", "k2", "c1", "c2", "alpha", "beta", "delta"):
            assert fitted[n]["value"] == pytest.approx(true[n], rel=0.02), (u, n)
    for n in ("k1", "c1", "c2"):
        spread = doc["spread"]["family"][n]
        true = [lot.truth["units"][u]["constants"][n] for u in family]
        assert spread["mean"] == pytest.approx(np.mean(true), rel=0.002)
        assert spread["std"] == pytest.approx(np.std(true, ddof=1), rel=0.1)
        assert spread["cv"] == pytest.approx(spread["std"] / spread["mean"])
        assert doc["average"][n] == spread["mean"]
    # 5 % apart, a unit is many noise levels from the lot average; the worn ones farther
    worst = {u: max(r["residual_over_noise"] for r in doc["units"][u]["lot_average"].values())
             for u in family + lot.defective}
    assert min(worst.values()) > 3.0
    assert min(worst[u] for u in lot.defective) > max(worst[u] for u in family)
    model = model_from_json(doc)  # `sim response --model lot.json` reads the lot average
    assert model.model.parameters()["k1"] == pytest.approx(doc["average"]["k1"])
    assert (first["out"] / "report" / "spread.png").stat().st_size > 10_000
    page = (first["out"] / "report" / "index.html").read_text()
    assert all(f"<tr class='out'><td class='l'>{u}</td>" in page for u in lot.defective)


@pytest.mark.slow
def test_resume_fits_only_the_missing_units(lot: Lot, first, cluster):
    """A rerun after an interruption: units with no result, or half a file, are fitted;
    the rest are read back, and the lot comes out the same."""
    kept = lot.root / "resume"
    shutil.copytree(first["out"] / "lot.units", kept)
    clean = first["doc"]["lot"]["in_family"]
    (kept / f"{clean[0]}.json").unlink()
    (kept / f"{lot.corrupt}.json").unlink()
    half = (kept / f"{clean[1]}.json").read_text()
    (kept / f"{clean[1]}.json").write_text(half[:len(half) // 2])
    options = FitOptions(mass=MASS)
    from dask.distributed import Client

    with Client(cluster) as client:
        result = schedule.run_lot(client, find_units([lot.units], options), options,
                                  UnitStore(kept))
    assert sorted(result.fitted) == sorted([clean[0], clean[1], lot.corrupt])
    assert result.family.out_of_family == lot.defective
    for u, r in result.units.items():
        assert r.to_json()["constants"] == first["doc"]["units"][u]["constants"]
        if r.ok:
            assert result.predictions[u] == first["doc"]["units"][u]["lot_average"]


def _wait_for(predicate, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > end:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.5)


@pytest.mark.slow
@pytest.mark.timeout(1500)
def test_worker_processes_killed_halfway_then_finished_give_the_same_lot(lot: Lot, first):
    """The CLI in its own process, 2 worker processes: SIGTERM once two units are kept
    shuts the cluster down; the same command again fits only the rest, and every unit
    comes out as on the in-process cluster."""
    import psutil

    out = lot.root / "processes"
    argv = [sys.executable, "-m", "analysis.lot.cli", str(lot.units), "--mass-lb", "6000",
            "--workers", "2", "--json", str(out / "lot.json")]
    kept = out / "lot.units"
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _wait_for(lambda: len(list(kept.glob("unit-*.json"))) >= 2 or proc.poll() is not None,
                  900, "two units kept")
        children = psutil.Process(proc.pid).children(recursive=True)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert "interrupted; the units fitted so far are kept" in err
    _wait_for(lambda: not any(c.is_running() and c.status() != psutil.STATUS_ZOMBIE
                              for c in children), 30, "the worker processes to end")
    done_before = {p.stem for p in kept.glob("unit-*.json")}
    assert 2 <= len(done_before) < 8
    r = subprocess.run(argv, capture_output=True, text=True, timeout=1200, check=False)
    assert r.returncode == 0, r.stderr
    assert f"{len(done_before)} unit(s) kept from an earlier run" in r.stderr
    doc = json.loads((out / "lot.json").read_text())
    assert set(doc["lot"]["fitted_in_this_run"]) == set(lot.truth["units"]) - done_before
    assert doc["lot"]["out_of_family"] == lot.defective
    for u, unit in doc["units"].items():
        assert unit["constants"] == first["doc"]["units"][u]["constants"], u
        assert unit["effects"] == first["doc"]["units"][u]["effects"], u
        assert unit["worker"].split(":")[1] != str(os.getpid())


# ---- the parts on their own: no fits -------------------------------------------------


def test_distance_flags_healthy_units_about_as_often_as_it_says():
    """Lots of healthy units (normal, correlated constants): a unit of the lot flagged in
    about FAMILY_ALPHA = 1 % of lots, few units (MAD) or many (OGK)."""
    rng = np.random.default_rng(5)
    cov = np.eye(8)
    cov[0, 1] = cov[1, 0] = 0.8  # k1 and k2 of a lot move together
    for n, method in ((8, "mad"), (40, "ogk")):
        flagged = 0
        for _ in range(200):
            v = 1e4 * (1 + 0.05 * rng.multivariate_normal(np.zeros(8), cov, n))
            d = robust_distances(v, 1e-4 * v)
            flagged += bool(d.outside.any())
        assert d.method == method
        assert flagged <= 8, (n, flagged)  # 2 expected; 8 is beyond 4 σ of binomial


def test_distance_names_an_outlier_and_sees_across_a_correlation():
    rng = np.random.default_rng(6)
    cov = np.eye(6)
    cov[0, 1] = cov[1, 0] = 0.9
    v = 1e3 * (1 + 0.05 * rng.multivariate_normal(np.zeros(6), cov, 60))
    v[3, 2] *= 1.5  # some 10 σ in one constant
    v[7, 0] *= 1.08  # +1.6 σ in k1 and −1.6 σ in k2: across a 0.9 correlation
    v[7, 1] *= 0.92
    d = robust_distances(v, np.zeros_like(v))
    assert d.method == "ogk"
    assert np.flatnonzero(d.outside).tolist() == [3, 7]
    assert abs(d.z[3, 2]) > 5 and np.all(np.abs(d.z[7]) < 3)


def _unit(name: str, effects: dict[str, float] = (), k1: float = 7e4, unexplained: str = ""
          ) -> UnitResult:
    rng = np.random.default_rng(int(name[1:]))
    constants = {"m": Estimate(MASS, None, "kg"),
                 "k1": Estimate(k1 * (1 + 0.03 * rng.standard_normal()), 10.0, "N/m"),
                 "c1": Estimate(6e3 * (1 + 0.03 * rng.standard_normal()), 1.0, "N/(m/s)"),
                 "F_break": Estimate(91.6, None, "N", held=True)}
    return UnitResult(name, f"/lot/{name}", "f", OK, constants=constants,
                      effects={e: Estimate(v, 1.0, "N") for e, v in dict(effects).items()},
                      residual_over_noise={"A": 1.0}, unexplained=unexplained)


def test_family_names_effects_the_others_lack_and_lack_of_the_familys_own():
    units = [_unit(f"u{i:02d}", {"thermal_damping_drift": -300.0} if i < 9 else {})
             for i in range(12)]
    units[1] = _unit("u01", {"thermal_damping_drift": -300.0, "coulomb_friction": 150.0})
    units[2] = _unit("u02", {"thermal_damping_drift": -300.0}, unexplained="at z > 0")
    units[3] = _unit("u03", {"thermal_damping_drift": -300.0}, k1=14e4)  # twice as stiff
    f = judge_lot(units)
    assert f.common == ("thermal_damping_drift",)
    assert f.out_of_family == ["u01", "u03", "u09", "u10", "u11"]
    assert f.verdicts["u01"].reasons == ("coulomb_friction 150 ± 1 N (1 of 12 units)",)
    assert f.verdicts["u02"].notes[0].startswith("unexplained residual: up to 1.00 x noise")
    assert f.verdicts["u03"].reasons[0].startswith("constants off the lot's: k1 +")
    lacks = "lacks thermal_damping_drift, which 9 of 12 units have"
    assert f.verdicts["u10"].reasons == (lacks,)
    assert f.judged == ("k1", "c1") and f.spread["F_break"].n == 0
    assert f.spread["k1"].n == 7 and f.average["k1"] == pytest.approx(7e4, rel=0.05)


def test_store_reuses_a_result_only_for_the_same_files_and_options(tmp_path: Path):
    unit = tmp_path / "lot" / "u1"
    unit.mkdir(parents=True)
    (unit / "A.csv").write_text("t,u,x\n")
    (tmp_path / "lot" / "notes").mkdir()  # no run files: not a unit of the lot
    options = FitOptions(mass=MASS)
    [spec] = find_units([tmp_path / "lot"], options)
    assert spec.name == "u1" and [Path(f).name for f in spec.files] == ["A.csv"]
    store = UnitStore(tmp_path / "kept")
    result = fit_unit(spec, options)  # an empty CSV: failed, with why
    assert not result.ok and result.reason == "A.csv: time has 0 samples, need at least 200"
    store.save(result)
    assert store.load(spec) == result
    assert store.load(find_units([unit], FitOptions(mass=2 * MASS))[0]) is None
    (unit / "A.csv").write_text("t,u,x\n0,0,0\n")
    assert store.load(find_units([unit], options)[0]) is None  # the file changed
    store.path("u1").write_text("{")
    assert store.load(spec) is None
    assert not list((tmp_path / "kept").glob(".*.tmp"))
    empty = tmp_path / "empty"
    empty.mkdir()
    [nothing] = find_units([empty], options)
    assert fit_unit(nothing, options).reason.startswith("no run files (*.h5, *.hdf5, *.csv)")


def test_a_task_that_dies_is_reported_and_not_kept(tmp_path: Path, cluster, monkeypatch):
    def crash(spec, options):
        raise RuntimeError("worker lost")

    monkeypatch.setattr(schedule, "fit_unit", crash)
    (tmp_path / "u1").mkdir()
    options = FitOptions(mass=MASS)
    store = UnitStore(tmp_path / "kept")
    from dask.distributed import Client

    with Client(cluster) as client:
        results, fitted = schedule.fit_units(client, find_units([tmp_path / "u1"], options),
                                             options, store)
    assert results["u1"].reason.startswith("task failed (RuntimeError: worker lost)")
    assert fitted == ("u1",) and not store.path("u1").exists()


def test_generate_lot_writes_nothing_that_tells_the_defective_units(tmp_path: Path):
    with contextlib.redirect_stdout(io.StringIO()):
        for out in ("a", "b"):
            assert generate_lot("3", "--defect", "coulomb_friction=150", "--defect-units", "1",
                                "--profile", "A", "--seed", "1", "--out", str(tmp_path / out)) == 0
        assert generate_lot("3", "--profile", "A", "--seed", "1", "--out", str(tmp_path / "t"),
                            "--truth", str(tmp_path / "truth.json")) == 0
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*"))
    assert [str(f) for f in files] == ["unit-001", "unit-001/A.csv", "unit-002",
                                       "unit-002/A.csv", "unit-003", "unit-003/A.csv"]
    heads = {(tmp_path / "a" / f).read_text().splitlines()[0] for f in files if f.suffix}
    assert heads == {"t [s],u [in],x [in]"}
    for f in files:  # the same seed, the same lot
        if f.suffix:
            assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes()
    truth = json.loads((tmp_path / "truth.json").read_text())
    k1 = [u["constants"]["k1"] for u in truth["units"].values()]
    assert len(set(k1)) == 3 and all(u["effects"] == {} for u in truth["units"].values())
    assert cli_lot.percentage("5%") == cli_lot.percentage("0.05") == 0.05
    with pytest.raises(argparse.ArgumentTypeError, match="5% or 0.05"):
        cli_lot.percentage("5")
