"""`rig`: the test-rig controller: profiles, limit checks, runs."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from rig import cli_files, cli_run
from rig.cli_support import add_units_argument, guarded
from rig.errors import ConfigError
from rig.profile import load_profile
from rig.tui import cli as tui_cli
from rig.units import from_si


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rig", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("profile", help="show a table motion profile and its peaks")
    p.add_argument("--profile", dest="profile_flag", metavar="PROFILE",
                   help="A, B, C or a profile TOML file")
    p.add_argument("profile", nargs="?", help=argparse.SUPPRESS)  # the older spelling
    add_units_argument(p, "us", "units of what is printed")
    cli_run.add_parsers(sub)
    cli_files.add_parsers(sub)
    tui_cli.add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    return guarded(_main, argv, "rig")


def _main(argv: Sequence[str] | None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "profile":
        return cmd_profile(args)
    if args.command == "tui":
        return tui_cli.cmd_tui(args)
    done = cli_run.dispatch(args)
    return (cli_files.dispatch(args) or 0) if done is None else done


def cmd_profile(args: argparse.Namespace) -> int:
    if args.profile and args.profile_flag:
        raise ConfigError("rig profile", "", "give the profile once, as --profile")
    if args.profile:
        print(f"note: rig profile {args.profile} is the older spelling of rig profile "
              f"--profile {args.profile}; it still works", file=sys.stderr)
    spec = args.profile_flag or args.profile
    if not spec:
        raise ConfigError("rig profile", "", "which profile? --profile A|B|C|FILE.toml")
    print(format_profile(spec, args.units))
    return 0


def format_profile(spec: str, units: str) -> str:
    p = load_profile(spec)
    length = "in" if units == "us" else "m"
    conv = (lambda v, u: from_si(v, u)) if units == "us" else (lambda v, u: v)
    lines = [f"profile {p.name}: {p.description}", f"duration {p.duration:.3f} s"]
    t = 0.0
    for i, seg in enumerate(p.segments, start=1):
        what = (f"ramp to {conv(seg.target, length):+.3f} {length}" if seg.is_ramp
                else "hold")
        lines.append(f"  {i}. {t:7.3f} s  {what} over {seg.duration:.3f} s")
        t += seg.duration
    pk = p.peaks()
    lines.append(f"peaks: |u| {conv(pk['displacement'], length):.3f} {length}, "
                 f"|u'| {conv(pk['velocity'], length + '/s'):.3f} {length}/s, "
                 f"|u''| {conv(pk['acceleration'], length + '/s^2'):.1f} {length}/s^2 "
                 f"({pk['acceleration'] / 9.80665:.2f} g)")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
