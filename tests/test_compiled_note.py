"""A fresh environment compiles the simulator with a word first (issue: a day at the bench)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from analysis.simulate.compiled import COMPILE_NOTE

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

PROBE = ("from analysis.simulate.compiled import compiled_on_disk, warm_up; "
         "before = compiled_on_disk(); said = []; warm_up(said.append); "
         "print(before, compiled_on_disk(), said)")


# the simulated rig's first call, made before it serves (a recorded run: forces, states,
# its start state handed over): what it compiles after the batch did
RECORDED = ("from analysis.simulate.kernel import simulate_one; "
            "from analysis.model.report_constants import report_model; "
            "from sim.plant import warm_up; warm_up(report_model('average')); "
            "print(len(simulate_one.stats.cache_misses), len(simulate_one.stats.cache_hits))")


def probe(cache: Path, code: str = PROBE) -> str:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=env, timeout=600, check=False)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_the_first_run_says_it_compiles_and_the_next_does_not(tmp_path: Path) -> None:
    cache = tmp_path / "numba"  # an empty cache: a new environment
    assert probe(cache) == f"False True [{COMPILE_NOTE!r}]"
    assert probe(cache) == "True True []"
    # the batch `analysis fit` runs and the recorded run of `sim` share one compiled
    # integrator: no second compile in full (70-100 s cold) at the first `sim` command
    # after a fit, or the first fit after a `sim serve`
    assert probe(cache, RECORDED) == "0 1"
