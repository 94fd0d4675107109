"""`sim generate`: a campaign of measured runs as CSV, with undeclared effects."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from analysis.model.report_constants import RUNS, report_model
from rig.cli_support import LENGTH_UNIT, add_units_argument, older_spelling
from rig.units import factor
from sim.effects import EFFECTS, parse_effect
from sim.generate import PAUSE, generate_campaign, write_run_csv

EPILOG = "effects (VALUE in SI; the run files do not record them):\n" + "\n".join(
    f"  {e.name:<24}{e.unit:<12}{e.meaning}" for e in EFFECTS.values())


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "generate", help="simulate a campaign of runs and write them as CSV (t,u,x)",
        description="Simulate runs back to back on the model, measure them with noisy "
                    "optical sensors and write one CSV per run. Effects given with --effect "
                    "change the isolator or the mass sensor and are written nowhere.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--profile", dest="runs", nargs="+", default=["A", "B", "C"],
                   metavar="PROFILE", help="profiles: A, B, C or TOML files (default A B C)")
    p.add_argument("--runs", dest="runs", nargs="+", action=older_spelling("--profile"),
                   help=argparse.SUPPRESS)
    p.add_argument("--effect", action="append", default=[], metavar="NAME=VALUE[,SHAPE...]",
                   help="add an undeclared effect; repeat for several")
    p.add_argument("--constants", default="average", choices=RUNS,
                   help="Table 1 column of the base isolator (default average)")
    p.add_argument("--noise", type=float, default=0.001,
                   help="sensor noise, rms of one sample, in in (us) or m (si) "
                        "(default 0.001 in)")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    p.add_argument("--pause", type=float, default=PAUSE, help="rest between runs, s")
    add_units_argument(p, "us", "displacements of --noise and of the CSV")
    p.add_argument("--out", type=Path, default=Path("runs"), help="output directory")


def run(args: argparse.Namespace) -> int:
    effects = [parse_effect(s) for s in args.effect]
    length = LENGTH_UNIT[args.units]
    runs = generate_campaign(args.runs, effects, report_model(args.constants),
                             noise=args.noise * factor(length), seed=args.seed,
                             pause=args.pause)
    args.out.mkdir(parents=True, exist_ok=True)
    for r in runs:
        path = args.out / f"{r.name}.csv"
        write_run_csv(r, path, length)
        print(f"run {r.name}: {len(r.t)} samples, {r.t[-1]:.2f} s at "
              f"{1 / (r.t[1] - r.t[0]):.0f} Hz -> {path}")
    if effects:
        print(f"{len(effects)} undeclared effect(s) injected; not recorded in the files",
              file=sys.stderr)
    return 0
