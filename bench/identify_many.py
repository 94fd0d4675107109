"""The README's main job over many campaigns: are the error bars honest, is the verdict stable?

    python bench/identify_many.py [--seeds N] [--work DIR] [--reuse]

For each seed: `rig campaign --yes` on the simulated rig (its own process, CAN and
serial, the sensors' noise seeded), then `analysis fit runs/*.h5 --mass-lb 6000
--json` — the commands a user runs, nothing in-process. The simulated rig's
isolator is Table 1's average column (`sim serve --constants average`, the
default), so each fitted constant can be checked against it:

* coverage: the share of (campaign, constant) pairs whose stated 95 % interval
  contains the rig's value (a right error bar: 95 %; the issue asks 90–99 %);
* the worst |estimate − truth| in standard errors and relative;
* how often each constant is held, and that every held one is said to be held;
* the effects the loop added (on a clean rig: none) and residual / noise.

`--reuse` fits campaigns already in DIR/sN instead of running them again.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from analysis.model.report_constants import report_model
from rig.units import to_si

NAMES = ("k1", "k2", "c1", "c2", "alpha", "beta", "delta", "F_break", "epsilon")
Z95 = 1.959963984540054


def campaign(out: Path, seed: int) -> float:
    t = time.perf_counter()
    subprocess.run(["rig", "campaign", "--yes", "--out", str(out), "--sim-arg=--seed",
                    f"--sim-arg={seed}"], check=True, capture_output=True)
    return time.perf_counter() - t


def fit(runs: Path, out: Path) -> tuple[dict, float]:
    t = time.perf_counter()
    subprocess.run(["analysis", "fit", *map(str, sorted(runs.glob("*.h5"))), "--mass-lb",
                    "6000", "--json", str(out)], check=True, capture_output=True)
    return json.loads(out.read_text()), time.perf_counter() - t


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=20)
    p.add_argument("--work", type=Path, default=Path("bench_identify_many"))
    p.add_argument("--reuse", action="store_true", help="fit campaigns already in --work")
    args = p.parse_args()
    truth = report_model("average").with_parameters(m=float(to_si(6000, "lbm"))).parameters()
    rows = []
    for seed in range(1, args.seeds + 1):
        d = args.work / f"s{seed}"
        t_run = 0.0 if args.reuse and any(d.glob("*.h5")) else campaign(d, seed)
        doc, t_fit = fit(d, d / "fit.json")
        base = doc.get("parameters_base_model", doc["parameters"])
        z, rel, held, covered = {}, {}, [], []
        for n in NAMES:
            e = base[n]
            rel[n] = e["value"] / truth[n] - 1
            if e.get("held"):
                held.append(n)
                continue
            if e["std"] is None:
                raise SystemExit(f"seed {seed}: {n} neither held nor given a std")
            z[n] = (e["value"] - truth[n]) / e["std"]
            covered.append(abs(z[n]) <= Z95)
        res = [v["residual_over_noise"] for v in doc["error"].values()]
        rows.append({"seed": seed, "z": z, "rel": rel, "held": held, "covered": covered,
                     "effects": doc.get("effects_added", []), "res": res, "t_run": t_run,
                     "t_fit": t_fit})
        worst = max(z, key=lambda n: abs(z[n]))
        print(f"seed {seed:3d}: resid/noise {', '.join(f'{r:.2f}' for r in res)}; "
              f"held {','.join(held) or '-'}; worst {worst} {z[worst]:+.1f} σ "
              f"({rel[worst]:+.2%}); covered {sum(covered)}/{len(covered)}; effects "
              f"{','.join(rows[-1]['effects']) or 'none'}; fit {t_fit:.1f} s", flush=True)
    pairs = [c for r in rows for c in r["covered"]]
    print(f"\n{len(rows)} campaigns, {len(pairs)} (campaign, constant) pairs with an "
          f"error bar: 95 % interval covers the rig's value in {np.mean(pairs):.1%}")
    print(f"{'constant':<9}{'covered':>9}{'held':>6}{'max |z|':>9}{'max |rel|':>11}"
          f"{'median rel':>12}")
    for n in NAMES:
        zs = [abs(r["z"][n]) for r in rows if n in r["z"]]
        rels = [r["rel"][n] for r in rows if n in r["z"]]
        cov = [abs(r["z"][n]) <= Z95 for r in rows if n in r["z"]]
        nh = sum(n in r["held"] for r in rows)
        if zs:
            print(f"{n:<9}{np.mean(cov):>9.0%}{nh:>6}{max(zs):>9.1f}"
                  f"{max(map(abs, rels)):>11.3%}{np.median(rels):>+12.3%}")
        else:
            print(f"{n:<9}{'—':>9}{nh:>6}")
    added = sum(bool(r["effects"]) for r in rows)
    print(f"effects added on {added}/{len(rows)} clean campaigns; resid/noise "
          f"{min(min(r['res']) for r in rows):.2f}–{max(max(r['res']) for r in rows):.2f}; "
          f"fit + loop wall p50 {np.median([r['t_fit'] for r in rows]):.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
