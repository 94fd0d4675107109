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


def probe(cache: Path) -> str:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    done = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                          env=env, timeout=600, check=False)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_the_first_run_says_it_compiles_and_the_next_does_not(tmp_path: Path) -> None:
    cache = tmp_path / "numba"  # an empty cache: a new environment
    assert probe(cache) == f"False True [{COMPILE_NOTE!r}]"
    assert probe(cache) == "True True []"
