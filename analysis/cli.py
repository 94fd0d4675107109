"""`analysis`: identify an isolator from logged runs and print the report's constants."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from analysis.blas import one_blas_thread
from analysis.cli_fit import add_fit_parser, run_fit
from analysis.design.cli import add_design_parser, run_design
from analysis.force_driven.datasets import add_datasets_parser, run_datasets
from analysis.lot.cli import add_lot_parser, run_lot_command
from analysis.model.report_constants import format_table1
from rig.cli_support import add_units_argument, guarded


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="analysis", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("constants", help="print the report's Table 1")
    add_units_argument(p, "us", "units of the table")
    add_fit_parser(sub)
    add_datasets_parser(sub)
    add_design_parser(sub)
    add_lot_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    one_blas_thread()
    return guarded(_main, argv, "analysis")


def _main(argv: Sequence[str] | None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "constants":
        print(format_table1(args.units))
    elif args.command == "fit":
        return run_fit(args)
    elif args.command == "datasets":
        return run_datasets(args)
    elif args.command == "design":
        return run_design(args)
    elif args.command == "lot":
        return run_lot_command(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
