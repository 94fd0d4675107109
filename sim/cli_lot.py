"""`sim generate-lot`: a production lot from the simulated rig, one directory of CSV runs
per unit, a few units with an undeclared effect.

Nominally identical isolators differ (CERL TR M-226, chapters 4–5): each unit's
constants scatter around Table 1's average column, each multiplied by exp(s N(0, 1))
(log-normal: the constants stay positive, s is their relative spread). `--defect-units`
units, drawn at random, also carry every `--defect` effect (worn seals: Coulomb
friction). Every unit is measured on the same runs with its own noise draw and written
as `unit-001/A.csv`, …: nothing in the files tells which units are defective or what
their constants are. That truth goes to a separate JSON file only with `--truth FILE`,
for tests and benchmarks.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from analysis.model.isolator import IsolatorModel
from analysis.model.report_constants import report_model
from rig.cli_support import LENGTH_UNIT, add_units_argument
from rig.errors import ConfigError
from rig.units import factor
from sim.cli_generate import EPILOG
from sim.effects import Effect, parse_effect
from sim.generate import PAUSE, generate_campaign, write_run_csv

# every constant of Table 1 that is not zero there (c3 and γ are the report's absent terms)
SCATTERED = ("k1", "k2", "c1", "c2", "alpha", "beta", "delta", "F_break", "epsilon")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "generate-lot", help="simulate a lot of isolators: one directory of CSV runs per unit",
        description="Simulate N units whose constants scatter around Table 1's average, a "
                    "few with undeclared effects, and write each unit's runs as CSV into "
                    "OUT/unit-NNN/. Which units are defective is written nowhere but "
                    "--truth.", epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("count", type=int, metavar="N", help="number of units")
    p.add_argument("--scatter", type=percentage, default=0.05, metavar="S",
                   help="relative spread of each constant, e.g. 5%% or 0.05 (default 5%%)")
    p.add_argument("--defect", action="append", default=[], metavar="NAME=VALUE[,SHAPE...]",
                   help="an undeclared effect of the defective units; repeat for several")
    p.add_argument("--defect-units", type=int, default=0, metavar="K",
                   help="how many units, drawn at random, carry the defects (default 0)")
    p.add_argument("--profile", dest="runs", nargs="+", default=["A", "B", "C"],
                   metavar="PROFILE",
                   help="profiles every unit runs: A, B, C or TOML files (default A B C)")
    p.add_argument("--noise", type=float, default=0.001,
                   help="sensor noise, rms of one sample, in in (us) or m (si) "
                        "(default 0.001 in)")
    add_units_argument(p, "us", "displacements of --noise and of the CSV")
    p.add_argument("--seed", type=int, default=0, help="seed of the scatter, the draw of "
                   "defective units and the noise (default 0)")
    p.add_argument("--out", type=Path, default=Path("lot"), help="output directory")
    p.add_argument("--truth", type=Path, metavar="FILE",
                   help="also write each unit's constants and effects (JSON, SI) here")


def percentage(text: str) -> float:
    """'5%' or '0.05' → 0.05."""
    s = text.strip()
    try:
        value = float(s[:-1]) / 100.0 if s.endswith("%") else float(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a percentage: {text!r} (e.g. 5% or 0.05)"
                                         ) from None
    if not (np.isfinite(value) and 0.0 <= value < 1.0):
        raise argparse.ArgumentTypeError(f"a spread of 0 to 100 % (5% or 0.05), got {text!r}")
    return value


def scattered(base: IsolatorModel, spread: float, rng: np.random.Generator) -> IsolatorModel:
    """The base model with each SCATTERED constant × exp(spread N(0, 1))."""
    p = base.parameters()
    return base.with_parameters(**{n: p[n] * float(np.exp(spread * rng.standard_normal()))
                                   for n in SCATTERED})


def run(args: argparse.Namespace) -> int:
    if args.count < 1:
        raise ConfigError("generate-lot", "N", f"needs at least one unit, got {args.count}")
    if not 0 <= args.defect_units <= args.count:
        raise ConfigError("--defect-units", str(args.defect_units),
                          f"must be 0 to the number of units ({args.count})")
    if args.defect_units and not args.defect:
        raise ConfigError("--defect-units", str(args.defect_units), "needs --defect NAME=VALUE")
    defects = [parse_effect(s) for s in args.defect]
    seeds = np.random.SeedSequence(args.seed).spawn(args.count + 1)
    rng = np.random.default_rng(seeds[0])
    defective = set(rng.choice(args.count, args.defect_units, replace=False).tolist())
    width = max(3, len(str(args.count)))
    truth = {}
    for i in range(args.count):
        name = f"unit-{i + 1:0{width}d}"
        model = scattered(report_model("average"), args.scatter, rng)
        effects = defects if i in defective else []
        _write_unit(args, args.out / name, model, effects, int(seeds[i + 1].generate_state(1)[0]))
        truth[name] = {"constants": {n: model.parameters()[n] for n in SCATTERED},
                       "effects": {e.name: e.value for e in effects}}
    print(f"lot of {args.count} units in {args.out}: constants scattered "
          f"{100 * args.scatter:g} % around Table 1's average")
    if defective:
        print(f"{len(defective)} unit(s) carry undeclared effect(s); not recorded in the files",
              file=sys.stderr)
    if args.truth:
        args.truth.parent.mkdir(parents=True, exist_ok=True)
        args.truth.write_text(json.dumps({
            "scatter": args.scatter, "seed": args.seed, "runs": args.runs,
            "defects": args.defect, "units": truth}, indent=1), encoding="utf-8")
        print(f"wrote the truth to {args.truth}")
    return 0


def _write_unit(args: argparse.Namespace, out: Path, model: IsolatorModel,
                effects: list[Effect], seed: int) -> None:
    length = LENGTH_UNIT[args.units]
    runs = generate_campaign(args.runs, effects, model, noise=args.noise * factor(length),
                             seed=seed, pause=PAUSE)
    out.mkdir(parents=True, exist_ok=True)
    for r in runs:
        write_run_csv(r, out / f"{r.name}.csv", length)
    print(f"{out.name}: {len(runs)} runs -> {out}")
