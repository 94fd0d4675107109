"""One vocabulary across rig, sim and analysis: --profile for a table motion, --units
us|si for units; the older spellings still work and say what to use (issue: a day at
the bench, item 4)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from analysis.cli import main as analysis_main
from analysis.identify.synthetic import synthetic_run
from analysis.model.report_constants import report_model
from rig.cli import main as rig_main
from rig.units import INCH
from sim.cli import main as sim_main

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)


def test_every_profile_is_chosen_with_profile(tmp_path: Path, capsys) -> None:
    assert rig_main(["profile", "--profile", "A"]) == 0
    assert rig_main(["check", "--profile", "A"]) == 0
    assert sim_main(["response", "--profile", "A"]) == 0
    assert sim_main(["generate", "--profile", "A", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "A.csv").is_file()
    assert "older spelling" not in capsys.readouterr().err


@pytest.mark.parametrize(("argv", "older", "new"), [
    (["rig", "profile", "A"], "rig profile A", "rig profile --profile A"),
    (["sim", "response", "--run", "A"], "--run", "--profile"),
    (["sim", "response", "--motion", "A"], "--motion", "--profile"),
    (["sim", "response", "--profile", "A", "--units", "in"], "--units in", "--units us"),
])
def test_the_older_spellings_work_and_name_the_new(capsys, argv, older, new) -> None:
    main = {"rig": rig_main, "sim": sim_main}[argv[0]]
    assert main(argv[1:]) == 0
    captured = capsys.readouterr()
    assert f"{older} is the older spelling of {new}" in captured.err
    assert "peaks" in captured.out or "profile A" in captured.out


def test_units_are_a_system_everywhere(capsys) -> None:
    for main, argv in ((analysis_main, ["constants"]), (rig_main, ["profile", "--profile", "C"]),
                       (rig_main, ["check", "--profile", "C"]),
                       (sim_main, ["response", "--profile", "C"])):
        assert main([*argv, "--units", "si"]) == 0
        si = capsys.readouterr().out
        assert main([*argv, "--units", "us"]) == 0
        us = capsys.readouterr().out
        assert si != us and " in" in us, argv
    with pytest.raises(SystemExit):  # a unit that is no system: argparse's usage error
        rig_main(["profile", "--profile", "C", "--units", "ft"])


def test_fit_reads_us_as_inches_not_microseconds(tmp_path: Path, capsys) -> None:
    run = synthetic_run(report_model("A"), "A", seed=11)
    path = tmp_path / "A.csv"
    np.savetxt(path, np.column_stack([run.t, run.u / INCH, run.x / INCH]), delimiter=",",
               header="t,u,x", comments="", fmt="%.10g")
    out = tmp_path / "fit.json"
    assert analysis_main(["fit", str(path), "--units", "us", "--mass-lb", "6000", "--no-refine",
                          "--json", str(out)]) == 0
    assert "k1" in capsys.readouterr().out and out.is_file()
    # si: the same inches read as metres are refused as beyond the table's travel
    assert analysis_main(["fit", str(path), "--units", "si", "--mass-lb", "6000",
                          "--no-refine"]) == 2
