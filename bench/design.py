"""Benchmark of `analysis design`: wall time and simulations of a design over runs A, B, C.

    python bench/design.py [--seeds N] [--out FILE.json]

Two designs against the report's three step pulses with 0.5 g of fragility and 4 in
of rattle space, from Table 1's average constants (mass 6000 lb): Eq 10's six
constants free, and the same with the dead band δ free too. Each is timed from the
ideal isolator's curve (which scales the box) to the tolerances (what `analysis
design` does between reading its inputs and printing), and its simulations are
counted by stage. The baseline, measured in the same process because these two
cores are shared: the time of one parallel call that simulates 256 designs under
the three threats, per simulation; the ratio of the design's wall time to its
simulations at that rate is its overhead. The load average is printed first:
another job on the machine slows everything here alike; the CPU time is what the
design costs on its own (on two idle cores the wall time would be about half of
it: the simulations keep both busy).
`--seeds N`: the design N times with other Sobol seeds, for the spread of the
optimum's acceleration.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from analysis.blas import one_blas_thread
from analysis.design.design import design, scales
from analysis.design.ideal import ideal_curve
from analysis.design.objective import Evaluator
from analysis.design.problem import Limits
from analysis.design.search import Settings
from analysis.design.space import EQ10, design_space
from analysis.design.threat import read_threat
from analysis.model.report_constants import report_model
from analysis.simulate.compiled import warm_up
from rig.units import STANDARD_GRAVITY, to_si

LIMITS = Limits(to_si(0.5, "g"), to_si(4.0, "in"))


def per_simulation(space, threats) -> float:
    """s per simulation in one call of 256 designs under every threat."""
    rows = space.rows(space.values(np.random.default_rng(0).random((256, len(space.bounds)))))
    evaluate = Evaluator(space.model, threats)
    t = time.perf_counter()
    evaluate(rows)
    return (time.perf_counter() - t) / evaluate.simulations


def one(free: tuple[str, ...], seed: int = 0) -> dict:
    model = report_model("average")
    threats = [read_threat(r) for r in "ABC"]
    box = scales(model.mass, threats, LIMITS.stroke, ideal_curve(threats, model.mass))
    rate = per_simulation(design_space(model, free, box), threats)
    t, cpu = time.perf_counter(), time.process_time()
    ideal = ideal_curve(threats, model.mass)  # as `analysis design` does: it scales the box
    space = design_space(model, free, scales(model.mass, threats, LIMITS.stroke, ideal))
    r = design(model, space, threats, LIMITS, Settings(seed=seed), ideal=ideal)
    wall, cpu = time.perf_counter() - t, time.process_time() - cpu
    n = sum(r.simulations.values())
    return {"free": list(free), "seed": seed, "wall_s": wall, "cpu_s": cpu, "simulations": n,
            "by_stage": r.simulations, "local_rounds": r.rounds,
            "s_per_simulation": rate, "overhead": wall / (n * rate),
            "peak_accel_g": float(r.archive.worst_accel[r.optimum] / STANDARD_GRAVITY),
            "peak_stroke_in": float(r.archive.worst_stroke[r.optimum] / 0.0254),
            "ideal_g": r.ideal_accel / STANDARD_GRAVITY, "feasible": r.feasible}


def main() -> None:
    one_blas_thread()
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=1)
    p.add_argument("--out", type=Path)
    args = p.parse_args()
    warm_up()
    print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} (1 min) at start")
    results = []
    for free in (EQ10, EQ10 + ("delta",)):
        for seed in range(args.seeds):
            r = one(free, seed)
            results.append(r)
            stages = ", ".join(f"{k} {v}" for k, v in r["by_stage"].items())
            print(f"free {','.join(free)} seed {seed}: {r['wall_s']:.1f} s "
                  f"({r['cpu_s']:.1f} s of CPU), "
                  f"{r['simulations']} simulations ({stages}), {r['local_rounds']} rounds; "
                  f"{r['s_per_simulation'] * 1e3:.2f} ms per simulation in one call of 256 "
                  f"designs x 3 threats, overhead {r['overhead']:.2f}x; optimum "
                  f"{r['peak_accel_g']:.3f} g at {r['peak_stroke_in']:.3f} in "
                  f"(ideal isolator {r['ideal_g']:.3f} g)")
    print(f"load average {os.getloadavg()[0]:.2f} (1 min) at the end")
    if args.out:
        args.out.write_text(json.dumps(results, indent=2), encoding="utf-8")


if __name__ == "__main__":
    main()
