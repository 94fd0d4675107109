"""A production lot on Dask: units per minute with 1 and 2 workers, what the scheduler
costs, peak memory per worker, whether the verdict is right, and a kill halfway.

    python bench/lot.py [--units 100] [--defective 5] [--work DIR] [--skip KIND ...]

1. `sim generate-lot N --scatter 5% --defect coulomb_friction=150 --defect-units K
   --truth` into DIR/lot (kept and reused when it is there with the same N and K).
2. plain loop: every unit fitted in this process, one after the other, one core
   (`fit_unit`, as a worker runs it): the baseline without a scheduler.
3. 1 worker, 2 workers: the lot on a local cluster (`run_lot`, a fresh results
   directory each, so every unit is fitted); units per minute of the fit phase, their
   ratio (the scaling), and each worker process's peak RSS (`ru_maxrss`).
4. overhead: the 1-worker lot's fit phase against the plain loop, per unit.
5. verdict: every defective unit out of family with its effect, no healthy unit out.
6. kill: `analysis lot` (2 workers) killed with SIGKILL once a third of the units are
   kept, then run again: it must fit only the units not kept, and give the same lot.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

from analysis.blas import one_blas_thread
from analysis.lot.cluster import connect
from analysis.lot.schedule import run_lot
from analysis.lot.store import UnitStore
from analysis.lot.unit import FitOptions, find_units, fit_unit
from rig.units import to_si
from sim import cli_lot

MASS = float(to_si(6000, "lbm"))
EFFECT = "coulomb_friction"


def generate(work: Path, units: int, defective: int) -> dict:
    lot, truth = work / "lot", work / "truth.json"
    if truth.exists():
        doc = json.loads(truth.read_text())
        if (len(doc["units"]) == units
                and sum(bool(u["effects"]) for u in doc["units"].values()) == defective):
            return doc
    shutil.rmtree(lot, ignore_errors=True)
    parser = argparse.ArgumentParser(prog="sim")
    cli_lot.add_parser(parser.add_subparsers(dest="command"))
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        cli_lot.run(parser.parse_args([
            "generate-lot", str(units), "--scatter", "5%", "--defect", f"{EFFECT}=150",
            "--defect-units", str(defective), "--seed", "1", "--out", str(lot), "--truth",
            str(truth)]))
    return json.loads(truth.read_text())


def plain_loop(specs, options) -> float:
    start = time.perf_counter()
    for s in specs:
        fit_unit(s, options)
    return time.perf_counter() - start


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def on_cluster(specs, options, workers: int, results: Path):
    """The lot on a local cluster of `workers`: fit-phase seconds, the lot, peak RSS (MB)."""
    shutil.rmtree(results, ignore_errors=True)
    marks = {}

    def progress(p):  # the fit phase ends at the first prediction
        if p.phase == "predict" and "fit" not in marks:
            marks["fit"] = time.perf_counter()

    with connect(None, workers) as client:
        client.run(peak_rss_mb)  # every worker up before the clock starts
        start = time.perf_counter()
        lot = run_lot(client, specs, options, UnitStore(results), progress=progress)
        rss = sorted(client.run(peak_rss_mb).values())
    return marks.get("fit", time.perf_counter()) - start, lot, rss


def verdict(lot, truth: dict) -> tuple[bool, str]:
    bad = sorted(u for u, t in truth["units"].items() if t["effects"])
    out = lot.family.out_of_family
    named = all(EFFECT in lot.units[u].effects for u in bad)
    ok = sorted(out) == bad and named and all(r.ok for r in lot.units.values())
    return ok, (f"out of family {out} (defective {bad}); effect named in each: {named}; "
                f"failed: {[u for u, r in lot.units.items() if not r.ok]}")


def kill_and_resume(work: Path, units: int) -> str:
    results = work / "kill.units"
    shutil.rmtree(results, ignore_errors=True)
    argv = [sys.executable, "-m", "analysis.lot.cli", str(work / "lot"), "--mass-lb", "6000",
            "--workers", "2", "--results", str(results), "--json", str(work / "kill.json")]
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    while len(list(results.glob("unit-*.json"))) < max(1, units // 3):
        time.sleep(0.5)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    kept = {p.stem for p in results.glob("unit-*.json")}
    start = time.perf_counter()
    subprocess.run(argv, check=True, capture_output=True)
    doc = json.loads((work / "kill.json").read_text())
    refit = set(doc["lot"]["fitted_in_this_run"])
    right = refit == set(doc["units"]) - kept
    return (f"killed (SIGKILL) with {len(kept)} of {units} units kept; the rerun fitted "
            f"{len(refit)} in {time.perf_counter() - start:.0f} s, "
            f"{'exactly the missing ones' if right else 'NOT only the missing ones'}; "
            f"out of family {doc['lot']['out_of_family']}")


def main() -> int:
    one_blas_thread()
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--units", type=int, default=100)
    p.add_argument("--defective", type=int, default=5)
    p.add_argument("--work", type=Path, default=Path("bench_lot"))
    p.add_argument("--skip", nargs="*", default=[], choices=("plain", "1", "2", "kill"))
    args = p.parse_args()
    truth = generate(args.work, args.units, args.defective)
    options = FitOptions(mass=MASS)
    specs = find_units([args.work / "lot"], options)
    n = len(specs)
    print(f"lot of {n} units ({args.defective} with {EFFECT}) in {args.work / 'lot'}")
    plain = None
    if "plain" not in args.skip:
        load = os.getloadavg()[0]
        plain = plain_loop(specs, options)
        print(f"plain loop, 1 core: {plain:.0f} s, {60 * n / plain:.2f} units/min; load "
              f"average before {load:.1f}, after {os.getloadavg()[0]:.1f}", flush=True)
    rate = {}
    for workers in (1, 2):
        if str(workers) in args.skip:
            continue
        load = os.getloadavg()[0]
        seconds, lot, rss = on_cluster(specs, options, workers, args.work / f"w{workers}")
        rate[workers] = 60 * n / seconds
        ok, text = verdict(lot, truth)
        # a fit that takes longer with more workers shared its core with something
        per_unit = sum(r.seconds for r in lot.units.values()) / n
        print(f"{workers} worker(s): fit phase {seconds:.0f} s, {rate[workers]:.2f} units/min; "
              f"a unit's fit {per_unit:.2f} s in its worker; load average before "
              f"{load:.1f}, after {os.getloadavg()[0]:.1f}; peak RSS per worker "
              f"{', '.join(f'{m:.0f}' for m in rss)} MB; verdict "
              f"{'right' if ok else 'WRONG'}: {text}", flush=True)
        if workers == 1 and plain:
            print(f"  scheduler overhead against the plain loop: {seconds - plain:+.0f} s "
                  f"({100 * (seconds / plain - 1):+.1f} %, {(seconds - plain) / n:+.2f} s per "
                  "unit)", flush=True)
    if len(rate) == 2:
        print(f"scaling: 2 workers fit {rate[2] / rate[1]:.2f}x the units per minute of 1")
    if "kill" not in args.skip:
        print(kill_and_resume(args.work, n))
    return 0


if __name__ == "__main__":
    sys.exit(main())
