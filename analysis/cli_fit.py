"""`analysis fit`: identify the isolator from run files or CSV, print and save the result."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from analysis.force_driven.cli import add_force_arguments, is_force_driven, run_force_fit
from analysis.identify.foreign import parse_channels
from analysis.identify.loading import load_runs
from analysis.identify.pipeline import identify
from analysis.identify.report_format import format_fit
from analysis.loop import close_identified
from analysis.loop.budget import LOOP_BUDGET
from analysis.loop.report import fit_document, format_loop
from analysis.simulate.compiled import warm_up
from rig.cli_support import LENGTH_UNIT, add_units_argument
from rig.errors import DataError
from rig.units import to_si


def add_fit_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fit", help="identify Eq 10 from base-excited runs (HDF5 or CSV t,u,x)")
    p.add_argument("files", nargs="+", type=Path, metavar="RUN.h5|CSV|MF4|TDMS")
    mass = p.add_mutually_exclusive_group()  # CSV carries no mass; a run file does
    mass.add_argument("--mass", type=float, metavar="KG",
                      help="isolated mass, kg (default: the run files' payload mass)")
    mass.add_argument("--mass-lb", type=float, metavar="LB",
                      help="isolated mass, lb (default: the run files' payload mass)")
    add_units_argument(p, None, "CSV displacements and the --report figures")
    p.add_argument("--channels", type=parse_channels, metavar="U,X",
                   help="MDF/TDMS: table and mass displacement channels (default u,x, else "
                        "table_u,mass_x; TDMS may be GROUP/CHANNEL)")
    p.add_argument("--include-aborted", action="store_true",
                   help="fit run files that did not end in success (never armed, e-stopped)")
    p.add_argument("--json", type=Path, metavar="FILE", help="write the result as JSON")
    p.add_argument("--report", type=Path, metavar="DIR",
                   help="write the report into DIR: index.html, self-contained (figures "
                        "embedded, in --units, default us), and the figures as PNG")
    p.add_argument("--no-refine", action="store_true",
                   help="stop after variable projection (no output-error refinement, no loop)")
    p.add_argument("--no-loop", action="store_true",
                   help="skip closing the loop (searching the residual for missing effects)")
    p.add_argument("--loop-budget", type=_billions, default=LOOP_BUDGET / 1e9,
                   metavar="G",
                   help="RK4 steps the loop's simulations may take, in billions, before it "
                        "stops naming effects and restarting the final fit (default "
                        f"{LOOP_BUDGET / 1e9:g}); the report says when it was spent")
    add_force_arguments(p)


def _billions(text: str) -> float:
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be a positive number of billions, not {text}")
    return value


def run_fit(args: argparse.Namespace) -> int:
    mass = (args.mass if args.mass is not None
            else float(to_si(args.mass_lb, "lbm")) if args.mass_lb is not None else None)
    if is_force_driven(args):
        return run_force_fit(args, mass)
    length = LENGTH_UNIT[args.units] if args.units else None
    loaded = load_runs(args.files, mass, length, args.include_aborted, channels=args.channels)
    for w in loaded.warnings:
        print(f"analysis: warning: {w}", file=sys.stderr)
    start = time.perf_counter()

    def progress(message: str) -> None:
        print(f"analysis fit [{time.perf_counter() - start:5.1f} s] {message}", file=sys.stderr)

    warm_up(progress)  # a fresh install compiles here, with a word, not silently mid-fit
    try:
        fit = identify(loaded.runs, refine_output_error=not args.no_refine, progress=progress)
    except ValueError as e:  # data the identification cannot use (e.g. no relative motion)
        raise DataError(f"cannot identify from {', '.join(map(str, args.files))}: {e}") from e
    print(format_fit(fit))
    loop = None
    if not (args.no_loop or args.no_refine):
        loop = close_identified(fit, progress, int(args.loop_budget * 1e9))
        print()
        print(format_loop(loop, "us"))
    if args.json:
        doc = fit_document(fit, loop).to_json_dict()  # analysis/fit_schema.py
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(doc, indent=2), encoding="utf-8")
        print(f"wrote {args.json}")
    if args.report:
        from analysis.report_page import write_report  # matplotlib only when asked

        progress("figures")
        page = write_report(fit, args.report, loop, args.files, args.units or "us")
        print(f"wrote {page}")
    return 0
