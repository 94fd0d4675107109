"""`analysis lot`: identify every unit of a production lot on Dask and say which units
are out of family, and why."""

from __future__ import annotations

import argparse
import contextlib
import json
import signal
import sys
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

from analysis.blas import one_blas_thread
from analysis.lot.cluster import connect
from analysis.lot.report import format_lot, lot_json
from analysis.lot.schedule import Progress, run_lot
from analysis.lot.store import UnitStore
from analysis.lot.unit import FitOptions, find_units
from rig.cli_support import LENGTH_UNIT, add_units_argument, guarded
from rig.units import to_si


def add_lot_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "lot", help="identify every unit of a lot on Dask; say which are out of family",
        description="Fit each unit as `analysis fit` does (identification and the loop), one "
                    "task per unit on a Dask cluster; then the lot: each constant's mean, std "
                    "and CV, the lot-average model and how well it predicts each unit, and "
                    "the units out of family (constants by a robust distance, effects the "
                    "others do not have). Each unit's result is kept as it arrives: run the "
                    "same command again after an interruption and only the missing units "
                    "are fitted. See docs/lot.md.")
    p.add_argument("dirs", nargs="+", type=Path, metavar="DIR",
                   help="one directory of run files (HDF5 or CSV) per unit; a directory "
                        "holding only such directories is a lot of them")
    mass = p.add_mutually_exclusive_group()
    mass.add_argument("--mass", type=float, metavar="KG",
                      help="isolated mass, kg (default: each unit's run files' payload mass)")
    mass.add_argument("--mass-lb", type=float, metavar="LB",
                      help="isolated mass, lb (default: each unit's run files' payload mass)")
    add_units_argument(p, None, "CSV displacements")
    p.add_argument("--include-aborted", action="store_true",
                   help="fit run files that did not end in success")
    p.add_argument("--json", type=Path, metavar="FILE", help="write the lot as JSON")
    p.add_argument("--report", type=Path, metavar="DIR",
                   help="write the spread figures and index.html into DIR")
    p.add_argument("--results", type=Path, metavar="DIR",
                   help="where each unit's result is kept (default: FILE.units/ beside "
                        "--json, else DIR/units/ in --report, else ./lot-units/)")
    p.add_argument("--refit", action="store_true",
                   help="fit every unit again, even those whose result is kept")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="run on an existing Dask cluster (tcp://host:8786); its workers "
                            "must read the unit directories by these paths")
    where.add_argument("--workers", type=int, metavar="N",
                       help="worker processes of the local cluster (default: one per core)")


def results_dir(args: argparse.Namespace) -> Path:
    if args.results is not None:
        return args.results
    if args.json is not None:
        return args.json.with_name(args.json.stem + ".units")
    if args.report is not None:
        return args.report / "units"
    return Path("lot-units")


def run_lot_command(args: argparse.Namespace) -> int:
    """Exit 0 when the lot was judged (out-of-family and failed units are findings), 1 when
    no unit could be fitted."""
    mass = (args.mass if args.mass is not None
            else float(to_si(args.mass_lb, "lbm")) if args.mass_lb is not None else None)
    options = FitOptions(mass, LENGTH_UNIT[args.units] if args.units else None,
                         args.include_aborted)
    specs = find_units(args.dirs, options)
    store = UnitStore(results_dir(args))
    start = time.perf_counter()
    where = args.scheduler or ("a local cluster of " + (f"{args.workers} worker process(es)"
                                                       if args.workers else "one worker per core"))
    _say(start, f"{len(specs)} units; results kept in {store.directory}; running on {where}")
    try:
        with _terminate_as_interrupt(), connect(args.scheduler, args.workers) as client:
            lot = run_lot(client, specs, options, store, args.refit,
                          lambda p: _say(start, _progress_line(p)))
    except KeyboardInterrupt:
        print(f"analysis lot: interrupted; the units fitted so far are kept in "
              f"{store.directory}: run the same command again to finish the lot",
              file=sys.stderr)
        raise
    print(format_lot(lot))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        kept = {s.name: str(store.path(s.name)) for s in specs}
        args.json.write_text(json.dumps(lot_json(lot, kept), indent=1), encoding="utf-8")
        print(f"wrote {args.json}")
    if args.report:
        from analysis.lot.report_html import write_lot_report  # matplotlib only when asked

        print(f"wrote {write_lot_report(lot, args.report)}")
    return 0 if any(r.ok for r in lot.units.values()) else 1


def _say(start: float, message: str) -> None:
    print(f"analysis lot [{time.perf_counter() - start:6.1f} s] {message}", file=sys.stderr,
          flush=True)


def _progress_line(p: Progress) -> str:
    if p.message:
        return p.message
    eta = "" if p.eta is None else f", ETA {_duration(p.eta)}"
    head = (f"{'fitted' if p.phase == 'fit' else 'predicted by the lot average'}: {p.done} "
            f"done, {p.failed} failed, {p.remaining} remaining{eta}")
    u = p.unit
    if u is None:
        return head
    what = (f"{', '.join(u.effects) or 'no effect'}" if u.ok else f"failed: {u.reason}")
    return f"{head} — {u.unit} ({u.seconds:.1f} s): {what}"


def _duration(seconds: float) -> str:
    m, s = divmod(round(seconds), 60)
    return f"{m} min {s:02d} s" if m else f"{s} s"


@contextlib.contextmanager
def _terminate_as_interrupt() -> Iterator[None]:
    """SIGTERM (kill, a batch system's time limit) as Ctrl-C: the cluster is shut down and
    its worker processes with it, and what was fitted stays kept."""
    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    try:
        previous = signal.signal(signal.SIGTERM, interrupt)
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def main(argv: Sequence[str] | None = None) -> int:
    """`python -m analysis.lot.cli DIR ...`: the same as `analysis lot DIR ...`."""
    one_blas_thread()
    parser = argparse.ArgumentParser(prog="analysis")
    add_lot_parser(parser.add_subparsers(dest="command"))
    return guarded(lambda a: run_lot_command(parser.parse_args(["lot", *(a or [])])),
                   sys.argv[1:] if argv is None else argv, "analysis")


if __name__ == "__main__":
    sys.exit(main())
