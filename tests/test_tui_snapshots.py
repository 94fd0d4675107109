"""Snapshots of the TUI's static screens at 80 x 24 (pytest-textual-snapshot).

Regenerate after an intended change with `pytest tests/test_tui_snapshots.py
--snapshot-update` and look at the SVGs in tests/__snapshots__/. Everything shown
is fixed: the default configuration, a relative output directory, run files
written with fixed names and contents (tests.test_tui_support.write_run).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from rig.config import load_config
from rig.tui.app import RigApp
from tests.test_tui_support import write_run

SIZE = (80, 24)


@pytest.fixture
def in_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.chdir(tmp_path)  # the screens show the output directory: keep it "runs"
    return tmp_path


def test_setup_with_profile_a_and_its_margins(snap_compare, in_tmp: Path) -> None:
    assert snap_compare(RigApp(load_config(), Path("runs")), terminal_size=SIZE)


def test_setup_in_si_units(snap_compare, in_tmp: Path) -> None:
    assert snap_compare(RigApp(load_config(), Path("runs"), profile="C"), press=["u"],
                        terminal_size=SIZE)


def test_runs_of_a_fixed_directory(snap_compare, in_tmp: Path) -> None:
    for name, status in (("20250101T000000_A", "success"), ("20250101T000100_B", "abort"),
                         ("20250101T000200_C", "success")):
        write_run(Path("runs") / f"{name}.h5", status)
    assert snap_compare(RigApp(load_config(), Path("runs")), press=["3", "down"],
                        terminal_size=SIZE)
