"""`analysis design`: the isolator constants that protect a given equipment best.

Reads the threats, the limits and the isolator to start from (Table 1's average
constants, or `--from` a fit's JSON), converts everything to SI, runs
`analysis.design.design.design` and prints, saves and draws its result.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from analysis.design.design import design, scales
from analysis.design.ideal import ideal_curve
from analysis.design.problem import Limits
from analysis.design.quantity import parse_quantity
from analysis.design.report import design_json, format_design
from analysis.design.search import Settings
from analysis.design.sensitivity import TOLERANCE
from analysis.design.space import EQ10, check_free, design_space
from analysis.design.threat import read_threat
from analysis.model.isolator import IsolatorModel
from analysis.model.model_json import read_model
from analysis.model.report_constants import report_model
from analysis.simulate.compiled import warm_up
from rig.cli_support import add_units_argument
from rig.errors import DataError
from rig.units import to_si, us_unit


def add_design_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("design", help="find the constants that keep the stroke within its "
                       "limit with the least peak acceleration")
    p.add_argument("--threat", action="append", required=True, metavar="A|B|C|FILE",
                   help="a base motion to protect against: A, B, C, a profile TOML, or a CSV "
                        "t [s],u [in] or t [s],a [g]; repeat for several")
    p.add_argument("--max-accel", required=True, metavar="ACCEL",
                   help="the equipment's fragility, with its unit: 0.5g, 4.9m/s^2")
    p.add_argument("--max-stroke", required=True, metavar="LENGTH",
                   help="the rattle space, with its unit: 4in, 0.1m")
    mass = p.add_mutually_exclusive_group()
    mass.add_argument("--mass-lb", type=float, metavar="LB",
                      help="the equipment's mass, lb (default: the isolator's model's)")
    mass.add_argument("--mass", type=float, metavar="KG", help="the equipment's mass, kg")
    p.add_argument("--from", dest="fit", type=Path, metavar="FIT.json",
                   help="start from the model `analysis fit --json` identified, every effect "
                        "it found included (default: Table 1's average constants)")
    p.add_argument("--free", metavar="NAMES", default=None,
                   help=f"comma-separated constants to design (default: those of "
                        f"{', '.join(EQ10)} the model has); the rest are held")
    p.add_argument("--bound", action="append", default=[], metavar="NAME=LOW:HIGH",
                   help="the box of a free constant, in --units (default: scaled by the "
                        "mass, the limits and the threats; docs/design.md)")
    add_units_argument(p, "us", "units of the output and of --bound")
    p.add_argument("--samples", type=int, default=Settings.samples, metavar="N",
                   help=f"designs in the global sample (default {Settings.samples})")
    p.add_argument("--seed", type=int, default=0, help="of the Sobol samples (default 0)")
    p.add_argument("--tolerance", type=float, default=100 * TOLERANCE, metavar="PERCENT",
                   help="how much the peaks may grow in the tolerance table (default "
                        f"{100 * TOLERANCE:g})")
    p.add_argument("--json", type=Path, metavar="FILE", help="write the result as JSON")
    p.add_argument("--report", type=Path, metavar="DIR",
                   help="write the Pareto figure and index.html into DIR")


def run_design(args: argparse.Namespace) -> int:
    limits = Limits(parse_quantity(args.max_accel, "acceleration", "--max-accel"),
                    parse_quantity(args.max_stroke, "length", "--max-stroke"))
    if args.samples < 2 or not 0 < args.tolerance < 100:
        raise DataError("--samples needs at least 2 and --tolerance a percentage in (0, 100)")
    model = read_model(args.fit).model if args.fit else report_model("average")
    mass = (args.mass if args.mass is not None
            else float(to_si(args.mass_lb, "lbm")) if args.mass_lb is not None else None)
    if mass is not None:
        if not mass > 0:
            raise DataError(f"the mass must be positive, got {mass:g} kg")
        model = model.with_parameters(m=mass)
    threats = [read_threat(spec) for spec in args.threat]
    free = _free(args.free, model)
    bounds = _bounds(args.bound, model, args.units)
    check_free(model, free, bounds)
    start = time.perf_counter()

    def progress(message: str) -> None:
        print(f"analysis design [{time.perf_counter() - start:5.1f} s] {message}",
              file=sys.stderr)

    warm_up(progress)
    progress("the ideal isolator, for the scale of the box")
    ideal = ideal_curve(threats, model.mass)
    space = design_space(model, free, scales(model.mass, threats, limits.stroke, ideal), bounds)
    result = design(model, space, threats, limits,
                    Settings(samples=args.samples, seed=args.seed), args.tolerance / 100,
                    progress, ideal)
    print(format_design(result, args.units))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(design_json(result), indent=2), encoding="utf-8")
        print(f"wrote {args.json}")
    if args.report:
        from analysis.design.figure import write_report  # matplotlib only when asked

        print(f"wrote {write_report(result, args.report, args.units)}")
    return 0


def _free(text: str | None, model: IsolatorModel) -> list[str]:
    known = model.parameters()
    if text is None:
        return [n for n in EQ10 if n in known]
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise DataError("--free names no constant")
    return list(dict.fromkeys(names))


def _bounds(specs: list[str], model: IsolatorModel, units: str
            ) -> dict[str, tuple[float, float]]:
    """--bound NAME=LOW:HIGH in the constant's --units unit, to SI."""
    out = {}
    si_units = model.units()
    for spec in specs:
        name, _, rest = spec.partition("=")
        low, _, high = rest.partition(":")
        name = name.strip()
        if name not in si_units:
            raise DataError(f"--bound {spec!r}: {name!r} is not a constant of the model")
        unit = us_unit(si_units[name]) if units == "us" else si_units[name]
        try:
            lo, hi = float(low), float(high)
        except ValueError:
            raise DataError(f"--bound {spec!r}: need NAME=LOW:HIGH, numbers in {unit}"
                            ) from None
        out[name] = (float(to_si(lo, unit)), float(to_si(hi, unit)))
    return out
