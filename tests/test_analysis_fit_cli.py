"""`analysis fit` end to end: CSV in both unit systems, run files, bad input, a subprocess."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from analysis.cli import main
from analysis.identify.loading import load_runs
from analysis.identify.synthetic import synthetic_run
from analysis.model.report_constants import report_model
from rig.errors import DataError
from rig.runfile import RunInfo, RunWriter

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

INCH = 0.0254


@pytest.fixture(scope="module")
def run_a():
    return synthetic_run(report_model("A"), "A", seed=11)


def write_csv(path: Path, run, units: str = "m", header: str = "t,u,x") -> Path:
    scale = INCH if units == "in" else 1.0
    data = np.column_stack([run.t, run.u / scale, run.x / scale])
    np.savetxt(path, data, delimiter=",", header=header, comments="", fmt="%.10g")
    return path


def fit_json(tmp_path: Path, *args: str) -> dict:
    out = tmp_path / "fit.json"
    assert main(["fit", *args, "--json", str(out)]) == 0
    return json.loads(out.read_text())


def test_csv_round_trip_in_both_unit_systems(tmp_path: Path, run_a) -> None:
    si = write_csv(tmp_path / "a_m.csv", run_a, "m")
    us = write_csv(tmp_path / "a_in.csv", run_a, "in")
    for path, units in ((si, None), (us, "in")):
        back = load_runs([path], run_a.mass, units).runs[0]
        np.testing.assert_allclose(back.u, run_a.u, rtol=0, atol=1e-9)  # 10 digits of 0.14 m
        np.testing.assert_allclose(back.x, run_a.x, rtol=0, atol=1e-9)
        assert back.t[1] - back.t[0] == pytest.approx(1e-3)
    mass_lb = run_a.mass / 0.45359237
    a = fit_json(tmp_path, str(si), "--mass", str(run_a.mass), "--no-refine")
    b = fit_json(tmp_path, str(us), "--units", "us", "--mass-lb", str(mass_lb), "--no-refine")
    # the files differ in their 10th digit, which the shape search carries to ~1e-5;
    # a unit slip would show as 2.5 % or more
    for n in ("k1", "k2", "c1", "c2", "alpha", "beta", "delta"):
        assert a["parameters"][n]["value"] == pytest.approx(b["parameters"][n]["value"],
                                                            rel=1e-4)
    assert a["parameters"]["k1"]["unit"] == "N/m"


def test_header_units_are_read_and_must_agree(tmp_path: Path, run_a) -> None:
    path = write_csv(tmp_path / "a.csv", run_a, "in", header="t [s],u [in],x [in]")
    back = load_runs([path], run_a.mass).runs[0]
    np.testing.assert_allclose(back.x, run_a.x, atol=1e-9)
    with pytest.raises(DataError, match=r"column u is in in but --units says si \(m\)"):
        load_runs([path], run_a.mass, "m")


def test_full_fit_prints_both_tables_and_writes_json(tmp_path: Path, run_a, capsys) -> None:
    name = "20261124T181852_A"  # a rig run's name: its column must not run into the next
    path = write_csv(tmp_path / f"{name}.csv", run_a)
    doc = fit_json(tmp_path, str(path), "--mass", str(run_a.mass))
    out = capsys.readouterr()
    assert "lb/in" in out.out and "N/m" in out.out and "resid/noise" in out.out
    assert "output error" in out.err  # progress lines go to stderr
    assert {"parameters", "runs", "error", "model", "appendix_a"} <= set(doc)
    truth = report_model("A").parameters()
    assert doc["parameters"]["k1"]["value"] == pytest.approx(truth["k1"], rel=0.01)
    assert doc["parameters"]["F_break"]["held"] is True
    # one definition of a run's errors in the fit's table and the loop's lines: on a clean
    # run the loop's base refit barely moves the model, so the two agree (two definitions
    # had read NRMSE ẍ 8.6 % and 11.1 %, force 524 N and 436 N for one run)
    err, base = doc["error"][name], doc["error_before"][name]
    assert base["xdd"] == pytest.approx(err["nrmse_xdd"], rel=0.05)
    assert base["force_rms"] == pytest.approx(err["force_rms_N"], rel=0.05)
    loop_line = next(ln for ln in out.out.splitlines() if f"run {name}: NRMSE" in ln)
    assert "force RMS" in loop_line and loop_line.rstrip().split()[-4] != "N" and " lb" in loop_line
    assert 0.9 < err["residual_over_noise"] < 1.1
    assert err["nrmse_z"] < 0.01 and err["force_rms_N"] > 0
    assert [t["name"] for t in doc["model"]][:4] == ["k1", "k2", "c1", "c2"]
    assert np.asarray(doc["appendix_a"]["A"]).shape == (4, 4)


def test_a_rig_runs_long_name_keeps_its_column(tmp_path: Path, run_a, capsys) -> None:
    """Run files are named by their start time: the header ran '± 95 %run 2026…'."""
    names = ["20261124T181852_A", "20261124T182015_B"]
    run_b = synthetic_run(report_model("A"), "B", seed=12)
    files = [str(write_csv(tmp_path / f"{n}.csv", r)) for n, r in zip(names, (run_a, run_b))]
    assert main(["fit", *files, "--mass", str(run_a.mass), "--no-loop"]) == 0
    out = capsys.readouterr().out
    head = next(ln for ln in out.splitlines() if ln.startswith("constant"))
    assert re.search(rf"± 95 %\s+run {names[0]}\s+run {names[1]}\s+varpro", head), head
    for n in names:  # the errors table's rows too
        assert re.search(rf"^{n}\s+\d", out, re.M), out


BAD_CSV = {
    "missing column": ("t,u,y\n" + "".join(f"{i / 1000},0,0\n" for i in range(300)),
                       "no column 'x'"),
    "duplicate time": ("t,u,x\n" + "".join(f"{min(i, 150) / 1000 if i != 151 else 0.15},0,0\n"
                                           for i in range(300)), "duplicate time"),
    "decreasing time": ("t,u,x\n" + "".join(f"{(i if i != 100 else 50) / 1000},0,0\n"
                                            for i in range(300)), "decreasing time"),
    "NaN": ("t,u,x\n" + "".join(f"{i / 1000},0,{'nan' if i == 7 else 0}\n" for i in range(300)),
            "row 9, column x: nan"),
    "text": ("t,u,x\n" + "".join(f"{i / 1000},0,{'abc' if i == 3 else 0}\n"
                                 for i in range(300)), "'abc' is not a number"),
    "too short": ("t,u,x\n" + "".join(f"{i / 1000},0,0\n" for i in range(50)),
                  "50 samples, need at least 200"),
    "no motion": ("t,u,x\n" + "".join(f"{i / 1000},0,0\n" for i in range(400)),
                  "cannot identify"),
}


@pytest.mark.parametrize("case", sorted(BAD_CSV))
def test_bad_csv_is_one_line_and_exit_2(tmp_path: Path, capsys, case: str) -> None:
    text, message = BAD_CSV[case]
    path = tmp_path / "bad.csv"
    path.write_text(text)
    assert main(["fit", str(path), "--mass", "2721.6", "--no-refine"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("analysis: error: ") and message in err


def test_usage_errors_exit_2(tmp_path: Path, run_a, capsys) -> None:
    path = write_csv(tmp_path / "a.csv", run_a)
    with pytest.raises(SystemExit) as e:  # argparse: not a unit it knows
        main(["fit", str(path), "--mass", "1", "--units", "ft"])
    assert e.value.code == 2
    # a base-excited file needs the mass (a force-driven one may identify it)
    assert main(["fit", str(path)]) == 2
    assert "--mass" in capsys.readouterr().err
    assert main(["fit", str(tmp_path / "none.csv"), "--mass", "1"]) == 2
    assert "no such file" in capsys.readouterr().err
    assert main(["fit", str(path), "--mass", "-3"]) == 2


def test_uneven_clock_is_resampled_with_a_warning(tmp_path: Path, run_a) -> None:
    t = run_a.t + np.random.default_rng(0).uniform(-2e-4, 2e-4, run_a.t.size)
    t[0], t[-1] = run_a.t[0], run_a.t[-1]
    path = tmp_path / "jitter.csv"
    np.savetxt(path, np.column_stack([t, run_a.u, run_a.x]), delimiter=",", header="t,u,x",
               comments="", fmt="%.10g")
    loaded = load_runs([path], run_a.mass)
    assert "resampled linearly at 1 ms" in loaded.warnings[0]
    assert np.allclose(np.diff(loaded.runs[0].t), 1e-3)


def write_runfile(path: Path, run, complete: bool = True) -> Path:
    with RunWriter(path, RunInfo("A", 'name = "A"\n', "sim")) as w:
        w.samples("table_u", run.t, run.u)
        w.samples("mass_x", run.t + 2e-4, run.x)  # its own clock, 0.2 ms later
    if not complete:
        with h5py.File(path, "r+") as f:
            f.attrs["complete"] = False
            f.attrs["exit_status"] = "abort"
            f.attrs["reason"] = "operator stop"
    return path


def test_runfile_is_read_onto_one_grid(tmp_path: Path, run_a) -> None:
    back = load_runs([write_runfile(tmp_path / "A.h5", run_a)], run_a.mass).runs[0]
    assert back.name == "A" and back.t[0] == pytest.approx(2e-4)
    np.testing.assert_allclose(back.u, np.interp(back.t, run_a.t, run_a.u))
    np.testing.assert_allclose(back.x, run_a.x[:back.t.size])


def test_the_table_motion_is_fitted_to_the_table_sensors_own_samples(tmp_path: Path) -> None:
    """Two sensor clocks 65 ppm apart, the table's samples 0.82 of a sample off x's at the
    start: interpolated onto x's instants, u's noise is a weighted mean of two samples
    whose weights drift through the run (0.85 σ at the start, σ near the end). The table
    motion is fitted to the samples as taken: the noise read is the sensor's, the fit
    a step pulse at the noise (on u interpolated: σ read 7–12 % low over five draws,
    and a rig campaign's run B fell back to the smoothing spline for it)."""
    from analysis.identify.prepare import prepare
    from analysis.simulate import simulate
    from rig.profile import load_profile

    model, prof = report_model("average"), load_profile("B")
    rng = np.random.default_rng(3)
    sigma = 25.4e-6
    r = simulate(model, prof.motion(), duration=prof.duration, dt=1e-3)
    tu = -0.82e-3 + 1e-3 * (1 - 65e-6) * np.arange(r.t.size + 1)
    u = prof.sample(tu)[0] + sigma * rng.standard_normal(tu.size)
    path = tmp_path / "B.h5"
    with RunWriter(path, RunInfo("B", 'name = "B"\n', "sim")) as w:
        w.samples("table_u", tu, u)
        w.samples("mass_x", r.t, r.x + sigma * rng.standard_normal(r.t.size))
    run = load_runs([path], model.mass).runs[0]
    t_own, u_own = run.table_channel()
    np.testing.assert_allclose(t_own, tu, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(u_own, u)
    table = prepare(run).table
    assert table.method == "step-pulse fit"
    assert table.sigma == pytest.approx(sigma, rel=0.05)
    assert 0.9 < table.residual_over_noise < 1.1


def test_incomplete_runfile_is_refused(tmp_path: Path, run_a, capsys) -> None:
    path = write_runfile(tmp_path / "A.h5", run_a, complete=False)
    assert main(["fit", str(path), "--mass", "2721.6", "--include-aborted"]) == 2
    assert "run is not complete (exit status abort: operator stop)" in capsys.readouterr().err


def test_subprocess_smoke(tmp_path: Path, run_a) -> None:
    path = write_csv(tmp_path / "A.csv", run_a)
    r = subprocess.run([sys.executable, "-m", "analysis.cli", "fit", str(path), "--mass-lb",
                        "6000", "--no-refine"], check=False, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert "k1" in r.stdout and "lb/in" in r.stdout


def test_report_writes_figures_and_one_page(tmp_path: Path, run_a) -> None:
    path = write_csv(tmp_path / "A.csv", run_a)
    out = tmp_path / "report"
    assert main(["fit", str(path), "--mass", str(run_a.mass), "--no-refine",
                 "--report", str(out)]) == 0
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert pngs == ["forces.png", "profile_alpha_beta.png", "response_A.png"]
    page = (out / "index.html").read_text()
    assert all(name in page for name in pngs) and "lb/in" in page
    assert all((out / n).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for n in pngs)
