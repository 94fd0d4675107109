"""The console scripts of the foundation: in-process, and one real subprocess."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from analysis.cli import main as analysis_main
from rig.cli import main as rig_main
from sim.cli import main as sim_main


def test_sim_response_prints_peaks_in_us_units(capsys):
    assert sim_main(["response", "--profile", "A"]) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.startswith("relative displacement z"))
    peak_in = abs(float(line.split()[3]))
    assert 2.0 < peak_in < 6.0 and " in " in line
    assert "in/s^2" in out and " g)" in out


def test_sim_response_csv_in_si_matches_us(tmp_path, capsys):
    si, us = tmp_path / "si.csv", tmp_path / "us.csv"
    assert sim_main(["response", "--profile", "C", "--units", "si", "--out", str(si)]) == 0
    assert sim_main(["response", "--profile", "C", "--units", "us", "--out", str(us)]) == 0
    with open(si) as f:
        header_si = next(csv.reader(f))
    with open(us) as f:
        header_us = next(csv.reader(f))
    assert header_si[:3] == ["t [s]", "u [m]", "x [m]"] and header_us[1] == "u [in]"
    a_si = np.loadtxt(si, delimiter=",", skiprows=1)
    a_us = np.loadtxt(us, delimiter=",", skiprows=1)
    assert a_si.shape == (3001, len(header_si))
    np.testing.assert_allclose(a_us[:, 3] * 0.0254, a_si[:, 3], rtol=1e-12, atol=1e-15)
    assert "wrote 3001 samples" in capsys.readouterr().out


@pytest.mark.parametrize("argv,needle", [
    (["response", "--profile", "nowhere.toml"], "no such profile"),
    (["response", "--profile", "A", "--constants", "Z"], "invalid choice"),
])
def test_sim_bad_input_is_one_line(argv, needle, capsys):
    with pytest.raises(SystemExit) if "invalid" in needle else _nothing():
        code = sim_main(argv)
        assert code == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err


class _nothing:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_analysis_constants_and_rig_profile(capsys):
    assert analysis_main(["constants", "--units", "si"]) == 0
    assert "N/(m/s)" in capsys.readouterr().out
    assert rig_main(["profile", "--profile", "C"]) == 0
    out = capsys.readouterr().out
    assert "ramp to +5.500 in over 0.120 s" in out and "5.71 g" in out


@pytest.mark.slow
# the whole main job (campaign, fit with the loop, predict, design): 250-284 s on a
# 2-core EPYC, against the suite's 300 s per test
@pytest.mark.timeout(1200)
def test_installed_console_scripts_run_the_main_job(tmp_path):
    """README's main job as a person types it: a campaign on the simulated rig, then the fit."""
    readme = (Path(__file__).parents[1] / "README.md").read_text(encoding="utf-8")
    line = next(ln for ln in readme.splitlines() if "rig campaign" in ln and "pip install ." in ln)
    assert "analysis fit runs/*.h5 --mass-lb 6000 --report report --json report/fit.json" in line
    bin_dir = Path(sys.executable).parent
    assert (bin_dir / "rig").exists(), "the package's console scripts are not installed"
    camp = subprocess.run([str(bin_dir / "rig"), "campaign", "--yes", "--out", "runs"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert camp.returncode == 0, camp.stderr
    assert "campaign: 3/3 runs succeeded" in camp.stdout
    files = sorted((tmp_path / "runs").glob("*.h5"))
    assert len(files) == 3
    fit = subprocess.run([str(bin_dir / "analysis"), "fit", *map(str, files), "--mass-lb", "6000",
                          "--report", "report", "--json", "report/fit.json"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert fit.returncode == 0, fit.stderr
    assert "Traceback" not in fit.stderr
    assert "identified isolator" in fit.stdout and "closing the loop" in fit.stdout
    assert (tmp_path / "report" / "index.html").exists()
    doc = json.loads((tmp_path / "report" / "fit.json").read_text())
    assert {"parameters", "effects_added", "error_before", "error_after", "loop"} <= set(doc)
    # then the README's next two: predict and design with the isolator just identified
    for line in (ln for ln in readme.splitlines() if ln.strip().startswith(
            ("sim response --model report/fit.json", "analysis design --threat A --threat"))):
        argv = line.split()
        done = subprocess.run([str(bin_dir / argv[0]), *argv[1:]], cwd=tmp_path,
                              capture_output=True, text=True, timeout=300, check=False)
        assert done.returncode == 0 and "Traceback" not in done.stderr, line + done.stderr
        assert "peak" in done.stdout or "optimum" in done.stdout, done.stdout
    assert (tmp_path / "report" / "design" / "index.html").is_file()  # both ran: none skipped
