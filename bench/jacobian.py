"""Benchmark of the loop refit's Jacobian: the motion's forward sensitivities
(`simulate.tangent`) against the finite differences the refits take.

    python bench/jacobian.py [--seed 101] [--effect coulomb] [--repeat 5]

One unseen campaign (`bench/unseen/generator.py`, three runs read from its CSV as
`analysis fit` reads them), the report's average constants, Eq 10's nine constants
free; the Jacobian of `refit._Evaluator` both ways, on one numba thread and on all,
each the median of `--repeat`. Printed as ratios against the finite differences of
the same run (these machines are noisy), with how far each is from converged slopes
(forward differences of step 1e-6).
"""

from __future__ import annotations

import argparse
import importlib
import sys
import tempfile
import time
from pathlib import Path

import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from analysis.blas import one_blas_thread  # noqa: E402
from analysis.identify.loading import load_runs  # noqa: E402
from analysis.identify.prepare import prepare  # noqa: E402
from analysis.model.report_constants import report_model  # noqa: E402
from bench.unseen.generator import MASS, make_campaign, write_campaign  # noqa: E402

refit = importlib.import_module("analysis.loop.refit")  # `analysis.loop.refit` is a function


def jacobian(h, runs, names, tangent: bool, step: float = refit.FD_STEP
             ) -> tuple[np.ndarray, float]:
    """The Jacobian at h and the seconds it took, the residual there already known (as
    the solver asks for it)."""
    scales = np.array([abs(h.value(n)) for n in names])
    ev = refit._Evaluator(h, runs, tuple(names), scales, list(range(len(runs))), step, tangent)
    theta = np.ones(len(names))
    ev.residual(theta)
    t = time.perf_counter()
    J = ev.jacobian(theta)
    return J, time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=101)
    ap.add_argument("--effect", default="coulomb")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    one_blas_thread()
    with tempfile.TemporaryDirectory() as d:
        write_campaign(make_campaign(args.seed, (args.effect,) if args.effect else ()), Path(d))
        runs = [prepare(r).oe for r in
                load_runs([Path(d) / f"{n}.csv" for n in "ABC"], mass=MASS).runs]
    h = refit.Hypothesis(report_model("average"))
    p = h.model.parameters()
    names = [n for n in p if n != "m" and p[n] != 0.0]
    jacobian(h, runs, names, True)  # compile (or load) outside the timing
    print(f"seed {args.seed} ({args.effect or 'clean'}), {len(names)} constants, "
          f"3 runs of {runs[0].t.size} samples")
    for threads in sorted({1, numba.config.NUMBA_NUM_THREADS}):
        numba.set_num_threads(threads)
        fd = np.median([jacobian(h, runs, names, False)[1] for _ in range(args.repeat)])
        tg = np.median([jacobian(h, runs, names, True)[1] for _ in range(args.repeat)])
        print(f"  {threads} thread(s): finite differences {1e3 * fd:.1f} ms, tangent "
              f"{1e3 * tg:.1f} ms: {fd / tg:.2f} x faster")
    converged = jacobian(h, runs, names, False, 1e-6)[0]
    size = np.linalg.norm(converged, axis=0)
    # the breakaway force's column is ~1e-6 of k1's: no fit resolves it, so it is left out
    seen = [j for j in range(len(names)) if size[j] >= 1e-3 * size.max()]
    for label, tangent in (("finite differences 0.3 %", False), ("tangent", True)):
        J = jacobian(h, runs, names, tangent)[0]
        off = np.linalg.norm(J[:, seen] - converged[:, seen], axis=0) / size[seen]
        print(f"  {label}: off converged slopes by {100 * np.median(off):.2f} % (median "
              f"column of the {len(seen)} at least 1e-3 of the largest), "
              f"{100 * off.max():.1f} % at most ({names[seen[int(np.argmax(off))]]})")


if __name__ == "__main__":
    main()
