"""Benchmark of closing the loop: wall time, and a confusion table over seeded campaigns.

    python bench/loop.py [--quick] [--seeds N] [--out FILE.json]

1. Wall time of `close_loop` on runs A, B, C (3 s each, 1 kHz) with one undeclared
   effect (Coulomb friction, 167 N), from the report's average constants, as seconds
   and as a ratio to one simulation of the three runs measured in the same process.
   Target: ≤ 5 s on these 2 cores.
2. Confusion table: every effect of the library at two magnitudes (the size that
   changes the peak mass acceleration by ~5 %, and twice that) × two sensor noise
   levels (the rig's 25.4 µm, and 4×), plus clean campaigns, over N seeds. Each
   loop's first effect is classed as named correctly / wrong (another effect first)
   / missed (nothing added) / false positive (something added to a clean campaign).
   `--quick`: one magnitude, one noise level, one seed.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter
from pathlib import Path

import numba
import numpy as np
from scipy.signal import savgol_filter

from analysis.blas import one_blas_thread
from analysis.loop import LoopRun, close_loop
from analysis.model.report_constants import report_model
from analysis.simulate import simulate
from rig.profile import load_profile
from sim.effects import parse_effect
from sim.generate import SENSOR_NOISE, generate_campaign

# the size that moves the peak mass acceleration of run A, B or C by ~5 % (measured
# with the simulator by bisection); the sensor effects by their own measure
FIVE_PERCENT = {
    "coulomb_friction": 167.0, "asymmetric_damping": 560.0, "quadratic_damping": 284.0,
    "cubic_stiffness": 8.2e5, "asymmetric_stiffness": 4840.0, "preload": 520.0,
    "force_offset": 181.0, "thermal_damping_drift": -464.0, "hysteresis": 7400.0,
    "sensor_gain": 0.05, "sensor_delay": 0.004,
}


def campaign(effects: list[str], seed: int, noise: float = SENSOR_NOISE) -> list[LoopRun]:
    runs = []
    for g in generate_campaign(effects=[parse_effect(e) for e in effects], seed=seed,
                               noise=noise):
        dt = g.t[1] - g.t[0]
        xd = savgol_filter(g.x, 41, 3, deriv=1, delta=dt)
        xdd = savgol_filter(g.x, 41, 3, deriv=2, delta=dt)
        ud = savgol_filter(g.u, 41, 3, deriv=1, delta=dt)
        runs.append(LoopRun.from_measurement(g.name, g.t, g.u, g.x, xd - ud, xdd))
    return runs


def wall_time(repeat: int = 2) -> dict[str, float]:
    runs = campaign([f"coulomb_friction={FIVE_PERCENT['coulomb_friction']}"], seed=1)
    model = report_model("average")
    close_loop(model, runs)  # compile and warm every cache first
    motions = [load_profile(p).motion() for p in "ABC"]

    def sim3() -> None:
        for m in motions:
            simulate(model, m, duration=3.0)

    base = min(_timed(sim3) for _ in range(5))
    loop = min(_timed(lambda: close_loop(model, runs)) for _ in range(repeat))
    work = _simulation_work(lambda: close_loop(model, runs))
    print(f"close_loop, 3 runs x 3 s at 1 kHz, one effect: {loop:.2f} s (target 5 s) = "
          f"{loop / base:.0f} x one simulation of the 3 runs ({base * 1e3:.1f} ms); "
          f"{work['rows']} run-simulations in {work['rounds']} rounds on {work['cores']} cores",
          flush=True)
    return {"loop_s": loop, "simulation_s": base, **work}


def _simulation_work(fn) -> dict[str, int]:
    """Run-simulations (rows x runs) and parallel rounds the loop's predictions take."""
    refit_module = sys.modules["analysis.loop.refit"]
    batch, runs = refit_module.simulate_batch, refit_module.simulate_runs
    cores = max(numba.get_num_threads(), 1)
    work = {"rows": 0, "rounds": 0, "cores": cores}

    def count(rows: int) -> None:  # one call's rows share the cores
        work["rows"] += rows
        work["rounds"] += -(-rows // cores)

    def counted(model, vectors, *args, **kwargs):
        count(np.atleast_2d(vectors).shape[0])
        return batch(model, vectors, *args, **kwargs)

    def counted_runs(model, setups, vectors, *args, **kwargs):
        count(sum(np.atleast_2d(v).shape[0] for v in vectors))
        return runs(model, setups, vectors, *args, **kwargs)

    refit_module.simulate_batch, refit_module.simulate_runs = counted, counted_runs
    try:
        fn()
    finally:
        refit_module.simulate_batch, refit_module.simulate_runs = batch, runs
    return work


def _timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def confusion(seeds: int, quick: bool) -> dict[str, object]:
    magnitudes = (1.0,) if quick else (1.0, 2.0)
    noises = (1.0,) if quick else (1.0, 4.0)
    rows, counts = [], Counter()
    cases = [(name, g, n, s) for name in FIVE_PERCENT for g in magnitudes for n in noises
             for s in range(seeds)]
    cases += [("", 0.0, n, s) for n in noises for s in range(max(seeds, 3 if quick else 5))]
    start = time.perf_counter()
    for i, (name, gain, noise, seed) in enumerate(cases, start=1):
        effects = [f"{name}={gain * FIVE_PERCENT[name]:g}"] if name else []
        t = time.perf_counter()
        result = close_loop(report_model("average"),
                            campaign(effects, seed=100 + seed, noise=noise * SENSOR_NOISE))
        added = result.effects_added
        if not name:
            verdict = "false positive" if added else "clean"
        elif not added:
            verdict = "missed"
        else:
            verdict = "named" if added[0] == name else "wrong"
        counts[(name or "(none)", verdict)] += 1
        rows.append({"effect": name or "(none)", "magnitude": gain, "noise": noise, "seed": seed,
                     "added": added, "verdict": verdict,
                     "after_over_noise": result.diagnosis_after.residual_over_noise,
                     "seconds": time.perf_counter() - t})
        print(f"[{i}/{len(cases)} {time.perf_counter() - start:5.0f} s] "
              f"{name or '(none)':<22} x{gain:g} noise x{noise:g} seed {seed}: "
              f"{verdict:<14} added {added} after "
              f"{result.diagnosis_after.residual_over_noise:.2f} x noise", flush=True)
    verdicts = ("named", "wrong", "missed", "clean", "false positive")
    print(f"\n{'effect':<24}" + "".join(f"{v:>15}" for v in verdicts))
    for name in [*FIVE_PERCENT, "(none)"]:
        print(f"{name:<24}" + "".join(f"{counts[(name, v)]:>15}" for v in verdicts))
    return {"rows": rows}


def main() -> None:
    one_blas_thread()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one magnitude, noise, seed")
    parser.add_argument("--seeds", type=int, default=1, help="noise seeds per case")
    parser.add_argument("--out", type=Path, help="write every loop's outcome as JSON")
    args = parser.parse_args()
    out = {"wall_time": wall_time(), **confusion(args.seeds, args.quick)}
    if args.out:
        args.out.write_text(json.dumps(out, indent=1), encoding="utf-8")


if __name__ == "__main__":
    main()
