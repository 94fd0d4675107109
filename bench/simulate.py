"""Benchmark of the simulator: run A (3 s), one run and 1000 parameter sets.

    python bench/simulate.py

Figures are ratios against scipy's solve_ivp on the same hybrid model in the
same process (these machines are noisy); the accuracy of both is measured
against a fine-step reference so the comparison is at equal accuracy.
"""

from __future__ import annotations

import os
import time

import numpy as np

from analysis.blas import one_blas_thread
from analysis.model.report_constants import report_model  # noqa: E402
from analysis.simulate import simulate, simulate_batch  # noqa: E402
from analysis.simulate.reference import simulate_reference  # noqa: E402
from rig.profile import load_profile  # noqa: E402


def best_of(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def main() -> None:
    one_blas_thread()
    model, profile = report_model("average"), load_profile("A")
    motion = profile.motion()
    simulate(model, motion)  # compile outside the timing
    simulate_batch(model, np.tile(model.vector(), (2, 1)), motion)
    truth = simulate(model, motion, substeps=64)
    r = simulate(model, motion)
    err_kernel = np.abs(r.z - truth.z).max()

    t_kernel = best_of(lambda: simulate(model, motion), 20)
    t_ref = None
    for rtol in (1e-7, 1e-9):  # loosest solve_ivp as accurate as the kernel
        t0 = time.perf_counter()
        z_ref, _ = simulate_reference(model, motion, r.t, rtol=rtol, atol=1e-12)
        t_ref = time.perf_counter() - t0
        err_ref = np.abs(z_ref - truth.z).max()
        if err_ref <= err_kernel:
            break
    duration = profile.duration

    rng = np.random.default_rng(0)
    V = np.tile(model.vector(), (1000, 1))
    V[:, 4::4] *= rng.uniform(0.8, 1.2, (1000, V[:, 4::4].shape[1]))
    t_batch = best_of(lambda: simulate_batch(model, V, motion), 3)
    t_loop = best_of(lambda: [simulate(model, motion) for _ in range(50)], 2) / 50 * 1000

    print(f"run A, {duration:.1f} s at 1 kHz output, average constants, {os.cpu_count()} cores")
    print(f"  compiled RK4, 1 ms step:   {t_kernel * 1e3:8.3f} ms/run  "
          f"= {duration / t_kernel:7.0f}x real time   max |z err| {err_kernel:.2e} m")
    print(f"  solve_ivp DOP853 rtol={rtol:.0e}: {t_ref * 1e3:8.1f} ms/run  "
          f"= {duration / t_ref:7.1f}x real time   max |z err| {err_ref:.2e} m")
    print(f"  speed-up over solve_ivp at equal or better accuracy: {t_ref / t_kernel:,.0f}x")
    print(f"  1000 parameter sets, one parallel call: {t_batch:6.2f} s "
          f"({t_loop / t_batch:.2f}x faster than 1000 single calls, {t_loop:.2f} s)")


if __name__ == "__main__":
    main()
