"""The unseen benchmark's scoring (bench/loop_unseen.py `score`): a campaign is "not
exact only by an effect the fit reports not testable" where every effect it missed is
one the fit's own conditioning report says its runs cannot tell from its terms, and it
named nothing that is not there."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/ is not installed
from bench.loop_unseen import score  # noqa: E402


def _row(truth, named, not_testable=()):
    return {"seed": 1, "effects": [], "truth": list(truth), "named": list(named),
            "not_testable": list(not_testable), "wall": 1.0, "residual_after": 1.0}


def test_a_miss_counts_as_not_testable_only_when_the_fit_said_so():
    rows = [
        _row(["preload"], [], ["preload"]),  # missed, declared: counted
        _row(["preload"], []),  # missed, not declared
        _row(["sensor_delay", "preload"], ["sensor_delay"], ["preload"]),  # counted
        _row(["preload"], ["force_offset"], ["preload"]),  # a wrong name beside it
        _row(["preload"], ["preload"], ["cubic_stiffness"]),  # exact
        _row([], [], ["preload"]),  # clean
    ]
    s = score(rows)
    assert s["exact"] == 2
    assert s["missed_not_testable"] == 2
