"""`analysis fit --force COLUMN --position COLUMN`: the force-driven CSV layout.

The flags are added to `analysis fit` (analysis/cli_fit.py); with them every file
is read as force-driven, the mass is optional (identified when not given) and the
fit is the stepwise loop of analysis.force_driven.identify.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from analysis.force_driven.identify import VALIDATIONS, close_force_loop
from analysis.force_driven.loading import load_force_record
from analysis.force_driven.model import base_terms
from analysis.force_driven.prepare import METHODS, prepare
from analysis.force_driven.report import force_loop_json, format_force_loop
from rig.cli_support import LENGTH_UNIT
from rig.errors import DataError


def _length(args: argparse.Namespace) -> str | None:
    """The displacement unit of the files: --units us|si, or None (the header's, else m)."""
    return LENGTH_UNIT[args.units] if args.units else None


def add_force_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("force-driven CSV (a force moves the mass; other rigs, EMPS)")
    g.add_argument("--force", metavar="COLUMN", help="force column, N (with --position)")
    g.add_argument("--position", metavar="COLUMN",
                   help="displacement column (m, or --units) (with --force)")
    g.add_argument("--stiffness", action="store_true",
                   help="the base model has a linear spring (a mass on a spring)")
    g.add_argument("--cutoff", type=float, metavar="HZ",
                   help="Butterworth cutoff on the position (default: chosen from the data)")
    g.add_argument("--decimate", type=int, metavar="N",
                   help="decimation factor (default: keeps 0.4 x the cutoff); the force error "
                        "is measured over the band it keeps")
    g.add_argument("--derivatives", choices=METHODS, default="auto",
                   help="central differences (EMPS recipe) or spectral (near-Nyquist data)")
    g.add_argument("--heldout", type=Path, action="append", metavar="CSV",
                   help="a record the loop validates on (default: blocked 4-fold "
                        "cross-validation within the files)")
    g.add_argument("--validation", choices=VALIDATIONS, default="force",
                   help="held-out check: relative force error, or simulated position "
                        "(for output benchmarks such as Silverbox)")


def is_force_driven(args: argparse.Namespace) -> bool:
    """True with both --force and --position; DataError with only one of them."""
    given = (args.force is not None, args.position is not None)
    if any(given) and not all(given):
        raise DataError("--force and --position go together (force-driven CSV); give both "
                        "or neither")
    return all(given)


def run_force_fit(args: argparse.Namespace, mass: float | None) -> int:
    """Load, prepare, fit the base model, close the loop; print and optionally write JSON."""
    if mass is not None and not mass > 0:
        raise DataError(f"--mass must be positive, got {mass}")
    records = [load_force_record(f, args.force, args.position, _length(args)) for f in args.files]
    prepared = [prepare(r, args.cutoff, args.decimate, args.derivatives) for r in records]
    heldout = [prepare(load_force_record(f, args.force, args.position, _length(args)),
                       args.cutoff, args.decimate, args.derivatives)
               for f in (args.heldout or [])]
    loop = close_force_loop(prepared, base_terms(mass is not None, args.stiffness), mass,
                            heldout=heldout, validation=args.validation)
    print(format_force_loop(loop, prepared))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(force_loop_json(loop, prepared), indent=2),
                             encoding="utf-8")
        print(f"wrote {args.json}")
    if getattr(args, "report", None):
        print("analysis: --report is not available for force-driven files (use --json)")
    return 0
