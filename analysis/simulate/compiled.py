"""Whether the simulator's compiled code is on disk, and compiling it with a word first.

numba compiles the integrator at its first call in a new environment (~40 s on
the 2-core machine) and caches the machine code beside the module; without a
word, `analysis fit` went quiet for those seconds on a fresh install, the
moment a new user is most likely to think it hung.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from analysis.model.report_constants import report_model
from analysis.simulate import RunSetup, motion_from_samples, simulate_runs
from analysis.simulate.kernel import simulate_jobs

COMPILE_NOTE = "compiling the simulator (first run only, ~40 s)"


def compiled_on_disk() -> bool:
    """True when numba's cache holds the batch integrator (any signature)."""
    try:
        # numba's cache index: not public API, so an unknown layout says nothing
        index = Path(simulate_jobs._cache._cache_file._index_path)
    except AttributeError:
        return True
    return index.is_file()


def warm_up(progress: Callable[[str], None] = lambda m: None) -> bool:
    """Compile (or load) the integrator now, saying so when it compiles; True if it did."""
    compiling = not compiled_on_disk()
    if compiling:
        progress(COMPILE_NOTE)
    t = np.arange(50) * 1e-3
    model = report_model("average")
    simulate_runs(model, [RunSetup(motion_from_samples(t, 0.01 * t))], [model.vector()])
    return compiling
