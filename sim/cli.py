"""`sim`: the simulated rig and the model's noise-free responses."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from analysis.blas import one_blas_thread
from analysis.model.model_json import IdentifiedModel, read_model
from analysis.model.report_constants import RUNS, report_model
from analysis.predict import DRAWS, base_motion, predict
from rig.cli_support import add_units_argument, guarded, older_spelling
from rig.errors import DataError
from sim import cli_generate, cli_lot, serve
from sim.response import format_prediction, write_csv, write_plot


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sim", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("response", help="response of the report's or an identified model",
                       description="Simulate Eq 10 with dead band and static friction "
                                   "(CERL TR M-226), with Table 1's constants or an "
                                   "identified model (effects included), for a base motion; "
                                   "print the peaks, with an identified model's band.")
    p.add_argument("--profile", dest="motion", default="A",
                   help="A, B, C, a profile TOML file, or a CSV of the table displacement "
                        "('t [s],u [in]') or base acceleration ('t [s],a [g]') (default A)")
    for older in ("--motion", "--run"):
        p.add_argument(older, dest="motion", action=older_spelling("--profile"),
                       help=argparse.SUPPRESS)
    model = p.add_mutually_exclusive_group()
    model.add_argument("--constants", default="average", choices=RUNS,
                       help="Table 1 column to use (default average)")
    model.add_argument("--model", type=Path, metavar="FIT.json",
                       help="the identified model of `analysis fit --json`")
    p.add_argument("--band", type=float, default=95.0, metavar="PERCENT",
                   help="with --model: band of the peaks from the fit's covariance "
                        "(default 95; 0: none)")
    p.add_argument("--draws", type=int, default=DRAWS,
                   help=f"draws from the covariance for the band (default {DRAWS})")
    p.add_argument("--seed", type=int, default=0, help="seed of the draws (default 0)")
    add_units_argument(p, "us", "units of what is printed and written")
    p.add_argument("--out", type=Path, help="write every sample to this CSV file")
    p.add_argument("--plot", type=Path, metavar="PNG", help="write a figure of the response")
    cli_generate.add_parser(sub)
    cli_lot.add_parser(sub)
    serve.add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    return guarded(_main, argv, "sim")


def _main(argv: Sequence[str] | None) -> int:
    args = build_parser().parse_args(argv)
    if args.command != "serve":  # numerical work by our choice (analysis.blas); serve is not
        one_blas_thread()
    if args.command == "response":
        return run_response_command(args)
    elif args.command == "generate":
        return cli_generate.run(args)
    elif args.command == "generate-lot":
        return cli_lot.run(args)
    elif args.command == "serve":
        return serve.run(args)
    return 0


def run_response_command(args: argparse.Namespace) -> int:
    if not 0.0 <= args.band < 100.0:
        raise DataError(f"--band is a percentage below 100, got {args.band}")
    if args.model is not None:
        identified = read_model(args.model)
        what = f"identified model of {args.model} ({identified.source or 'no source'})"
    else:
        identified = IdentifiedModel(report_model(args.constants))
        what = f"Table 1 constants '{args.constants}'"
    drive = base_motion(args.motion)
    p = predict(identified, drive, level=args.band if args.model else 0.0, draws=args.draws,
                seed=args.seed)
    r = p.response
    print(f"{drive.source}; {what}; {r.t[-1] - r.t[0]:.2f} s at {1 / (r.t[1] - r.t[0]):.0f} Hz")
    print(format_prediction(p, args.units))
    if args.out:
        write_csv(r, args.out, args.units)
        print(f"wrote {len(r.t)} samples to {args.out}")
    if args.plot:
        write_plot(p, args.plot, args.units, f"{drive.source}\n{what}")
        print(f"wrote {args.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
