"""`sim`: the simulated rig and the model's noise-free responses."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from analysis.model.report_constants import RUNS
from rig.cli_support import guarded
from sim import cli_generate, serve
from sim.response import format_peaks, run_response, write_csv


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sim", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("response", help="noise-free response of the report's model to a run",
                       description="Simulate Eq 10 with dead band and static friction "
                                   "(CERL TR M-226) for a base motion; print the peaks.")
    p.add_argument("--run", default="A", help="A, B, C or a profile TOML file (default A)")
    p.add_argument("--constants", default="average", choices=RUNS,
                   help="Table 1 column to use (default average)")
    p.add_argument("--units", default="us", choices=("us", "si"),
                   help="report's units (in, lb, s) or SI (default us)")
    p.add_argument("--out", type=Path, help="write every sample to this CSV file")
    cli_generate.add_parser(sub)
    serve.add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    return guarded(_main, argv, "sim")


def _main(argv: Sequence[str] | None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "response":
        r = run_response(args.run, args.constants)
        print(f"run {args.run}, Table 1 constants '{args.constants}', "
              f"{r.t[-1]:.2f} s at {1 / (r.t[1] - r.t[0]):.0f} Hz")
        print(format_peaks(r, args.units))
        if args.out:
            write_csv(r, args.out, args.units)
            print(f"wrote {len(r.t)} samples to {args.out}")
    elif args.command == "generate":
        return cli_generate.run(args)
    elif args.command == "serve":
        return serve.run(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
