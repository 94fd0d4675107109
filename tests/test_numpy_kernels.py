"""numpy's kernels for exp, power, log and tanh are chosen by the CPU's instruction sets
when numpy loads, and each set's round the last bit their own way; the project's
packages choose numpy's baseline kernels first (`rig/__init__.py`), so the same data give
the same numbers on every x86-64 CPU. Checked bit for bit against the C library, which
the baseline kernels call and whose results do not follow AVX2 or AVX-512."""

from __future__ import annotations

import math
import os
import platform
import subprocess
import sys

import numpy as np
import pytest

import rig

X86 = platform.machine().lower() in ("x86_64", "amd64")
# where the AVX-512 kernels differ from the C library's (random |x| well inside range)
FUNCTIONS = {"exp": (np.exp, math.exp, (-700.0, 700.0)),
             "log": (np.log, math.log, (1e-300, 1e300)),
             "power 1.7": (lambda x: x ** 1.7, lambda x: math.pow(x, 1.7), (0.0, 1e3)),
             "tanh": (np.tanh, math.tanh, (-20.0, 20.0))}


def _bits_differ(name: str) -> int:
    vectorised, scalar, (lo, hi) = FUNCTIONS[name]
    x = np.random.default_rng(0).uniform(lo, hi, 20_000)
    return int(np.sum(vectorised(x) != np.array([scalar(v) for v in x.tolist()])))


@pytest.mark.parametrize("name", sorted(FUNCTIONS))
def test_numpy_rounds_as_the_c_library_in_a_process_that_imported_the_project(name):
    # this process imported the project (conftest) before numpy
    assert _bits_differ(name) == 0


def test_the_kernels_are_chosen_before_numpy_loads_in_every_entry_point():
    # a fresh interpreter: numpy imported after each package, exactly as the console
    # scripts and `python -m` do, and after nothing else
    for package in ("rig", "analysis", "sim"):
        code = (f"import {package}, numpy as np, math\n"
                "x = np.random.default_rng(1).uniform(-700, 700, 20000)\n"
                "print(int(np.sum(np.exp(x) != np.array([math.exp(v) for v in x]))))")
        env = {k: v for k, v in os.environ.items() if k != "NPY_DISABLE_CPU_FEATURES"}
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             env=env, check=True, timeout=120)
        assert out.stdout.strip() == "0", (package, out.stdout, out.stderr[-500:])


def test_a_choice_the_user_made_is_left_as_it_is():
    code = "import analysis, os; print(os.environ['NPY_DISABLE_CPU_FEATURES'])"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**os.environ, "NPY_DISABLE_CPU_FEATURES": "AVX512_SPR"},
                         check=True, timeout=120)
    assert out.stdout.strip() == "AVX512_SPR"
    if X86:
        assert os.environ.get("NPY_DISABLE_CPU_FEATURES") == rig.NUMPY_KERNELS_OFF
