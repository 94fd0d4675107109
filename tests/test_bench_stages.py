"""Where the unseen benchmark says the time goes: each progress line of `analysis fit`
claimed by its stage (bench/loop_unseen.py `stage_seconds`)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/ is not installed
from bench.loop_unseen import PROGRESS, START_UP, stage_seconds, stage_table

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

# the progress lines of one campaign (unseen seed 403), as the CLI prints them, with the
# times the benchmark saw them at
LINES = [
    (2.2, "analysis fit [  0.0 s] differentiating, estimating the table motion, dropping rest"),
    (2.9, "analysis fit [  0.7 s] appendix A: least squares at the report's alpha, beta, delta"),
    (3.1, "analysis fit [  0.9 s] variable projection over alpha, beta, delta"),
    (3.4, "analysis fit [  1.2 s] output error: all runs"),
    (5.6, "analysis fit [  3.5 s]   residual 60.3 x noise: output error again from alpha "
          "11.25 1/m"),
    (9.6, "analysis fit [  7.4 s]   residual 60.3 x noise: output error again from alpha "
          "63.25 1/m"),
    (20.2, "analysis fit [ 18.0 s]   held (not determined by these runs): F_break, k1"),
    (20.3, "analysis fit [ 18.1 s] run A: variable projection, output error"),
    (21.1, "analysis fit [ 19.0 s] run B: variable projection, output error"),
    (24.4, "analysis fit [ 22.2 s]   residual 60.3 x noise: output error again from run A's "
           "own fit"),
    (25.0, "analysis fit [ 22.8 s] loop: refitting the base model"),
    (27.6, "analysis fit [ 25.4 s] loop: equation error over every candidate (BIC)"),
    (31.5, "analysis fit [ 29.3 s] loop: equation error names asymmetric_stiffness (BIC -234)"),
    (31.5, "analysis fit [ 29.3 s] loop: refitting with asymmetric_stiffness"),
    (42.8, "analysis fit [ 40.6 s] loop: validating asymmetric_stiffness on held-out runs"),
]


def _seconds(wall: float) -> dict[str, float]:
    return stage_seconds([(t, PROGRESS.match(line).group(1)) for t, line in LINES], wall)


def test_each_stage_lasts_until_the_next_begins_and_the_last_until_the_process_ends():
    s = _seconds(wall=43.5)
    assert s[START_UP] == pytest.approx(2.2)
    assert s["identification: equation error"] == pytest.approx(3.4 - 2.2)
    assert s["identification: joint fit"] == pytest.approx(5.6 - 3.4)
    # the "held" line continues the α starts; the next α start is the same stage
    assert s["identification: other alpha starts"] == pytest.approx(20.3 - 5.6)
    assert s["identification: each run alone"] == pytest.approx(24.4 - 20.3)
    assert s["identification: a run's own start"] == pytest.approx(25.0 - 24.4)
    assert s["loop: base refit"] == pytest.approx(27.6 - 25.0)
    assert s["loop: naming"] == pytest.approx(31.5 - 27.6)
    assert s["loop: candidate refit"] == pytest.approx(42.8 - 31.5)
    assert s["loop: validation"] == pytest.approx(43.5 - 42.8)
    assert sum(s.values()) == pytest.approx(43.5)


def test_the_table_gives_each_stage_its_share_of_all_campaigns():
    rows = [{"stages": _seconds(43.5)}, {"stages": {START_UP: 3.0, "loop: naming": 4.0}}]
    table = stage_table(rows).splitlines()
    start = next(line for line in table if line.startswith(f"| {START_UP} |"))
    assert start == f"| {START_UP} | 2 | 5 | 10 % | 2.6 s |"  # 5.2 of 50.5 s
    assert table[2].startswith(f"| {START_UP} |")  # start-up first, then in fit order
    assert table[-1].startswith("| loop: validation | 1 |")
