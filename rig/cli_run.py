"""The `rig check`, `run`, `runs`, `campaign` and `recover` commands (printing lives here).

Exit codes: 0 done; 1 a run did not succeed (its summary says why); 2 refused or
unusable input, one line on stderr naming the file and the problem (rig.cli_support).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from rig.cli_support import add_units_argument
from rig.config import RigConfig, load_config
from rig.errors import ConfigError, DataError, LimitError
from rig.limits import Margins, check_all, limit_error
from rig.profile import BUILTIN, load_profile
from rig.run.runner import RunResult, run_profile
from rig.run.sim_process import SimProcess
from rig.runfile import check_output_dir, check_readable, list_runs, read_status, recover
from rig.wire.bus_load import check_bus_load

CAMPAIGN = ("A", "B", "C")
DEFAULT_PAUSE_S = 5.0


def add_parsers(sub: Any) -> None:
    p = sub.add_parser("check", help="check a profile against every actuator limit; move nothing")
    _profile_args(p)
    _units_arg(p)
    p = sub.add_parser("run", help="run one profile on the table and log it to a run file")
    _profile_args(p)
    _run_args(p)
    p = sub.add_parser("campaign", help="runs A, B and C in turn, with a pause between")
    p.add_argument("--config", type=Path, help="rig TOML (default data/rig.toml)")
    _run_args(p)
    p.add_argument("--pause", type=float, default=DEFAULT_PAUSE_S,
                   help=f"s between runs (default {DEFAULT_PAUSE_S:g})")
    p = sub.add_parser("runs", help="table of the run files in a directory")
    p.add_argument("directory", type=Path)
    p = sub.add_parser(
        "recover", help="make a run file whose writer died plainly readable",
        description="Clear the 'open for write' flags a dead writer left, on a copy that "
                    "is checked and then swapped in for the file atomically; mark the run "
                    "crashed and incomplete, keeping every row flushed before it died; "
                    "remove the dead writer's disk-space reserve (.NAME.h5.reserve).")
    p.add_argument("file", type=Path,
                   help="the run file (.h5); replaced by its recovered copy")


def _profile_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--profile", required=True, help="A, B, C or a profile TOML file")
    p.add_argument("--config", type=Path, help="rig TOML (default data/rig.toml)")


def _units_arg(p: argparse.ArgumentParser) -> None:
    add_units_argument(p, "us", "units of what is printed")


def _run_args(p: argparse.ArgumentParser) -> None:
    _units_arg(p)
    p.add_argument("--out", type=Path, default=Path("runs"), help="directory (default ./runs)")
    p.add_argument("--yes", action="store_true", help="arm without asking")
    p.add_argument("--sim-arg", action="append", default=[], help=argparse.SUPPRESS)


def dispatch(args: argparse.Namespace) -> int | None:
    """Run the command if it is one of these; None if not."""
    handlers = {"check": cmd_check, "run": cmd_run, "campaign": cmd_campaign, "runs": cmd_runs,
                "recover": cmd_recover}
    handler = handlers.get(args.command)
    return None if handler is None else handler(args)


def cmd_check(args: argparse.Namespace) -> int:
    config = load_config(args.config)
    margins = _checked(config, args.profile, args.units)  # LimitError → exit 2
    print(margins.format(args.units))
    print(check_bus_load(config).format())
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    result = _one(args, args.profile)
    return 0 if result.status == "success" else 1


def cmd_campaign(args: argparse.Namespace) -> int:
    if args.pause < 0:
        raise ConfigError("--pause", "", f"must be >= 0 s, got {args.pause}")
    config = load_config(args.config)
    for name in CAMPAIGN:  # all three before anything starts or moves
        _checked(config, name, args.units)
    _output_dir(args.out)
    if config.backend != "sim":
        return _campaign(args, config)
    # one simulated rig for the whole campaign, as one table on the bench: what a run
    # leaves (a warm fluid, a mass off centre) carries into the next
    with SimProcess(config, extra_args=tuple(args.sim_arg)) as sim:
        _say(f"sim serve running (pid {sim.pid})")
        return _campaign(args, sim.config)


def _campaign(args: argparse.Namespace, config: RigConfig) -> int:
    t0 = time.monotonic()
    results = []
    for i, name in enumerate(CAMPAIGN):
        if i:
            _say(f"pause {args.pause:g} s")
            time.sleep(args.pause)
        results.append(_one(args, name, config, start_sim=False))
        if results[-1].status != "success":
            _say(f"campaign stopped after run {name}")
            break
    ok = sum(r.status == "success" for r in results)
    print(f"campaign: {ok}/{len(CAMPAIGN)} runs succeeded in {time.monotonic() - t0:.1f} s, "
          f"files in {args.out}")
    return 0 if ok == len(CAMPAIGN) else 1


def _one(args: argparse.Namespace, spec: str, config: RigConfig | None = None,
         start_sim: bool = True) -> RunResult:
    config = config or load_config(args.config)
    profile = load_profile(spec)
    text = _profile_text(spec)
    _checked(config, spec, args.units)  # refused before the output directory is made
    _output_dir(args.out)
    print(f"run {profile.name}: {profile.description or spec} ({profile.duration:.2f} s)")
    result = run_profile(config, profile, text, args.out, confirm=lambda: _confirm(args, spec),
                         progress=_say, sim_args=tuple(args.sim_arg), start_sim=start_sim)
    print(result.summary(), flush=True)
    return result


def _checked(config: RigConfig, spec: str, units: str) -> Margins:
    """`check_all`, its refusal naming the profile as given (the file, or A) in `units`."""
    try:
        return check_all(config, load_profile(spec))
    except LimitError as e:
        raise limit_error(e.margins, spec, units) from None


def _confirm(args: argparse.Namespace, spec: str) -> bool:
    if args.yes:
        return True
    if not sys.stdin.isatty():
        _say("not a terminal and no --yes: not arming")
        return False
    answer = input(f"arm the table and run profile {spec}? type 'yes': ")
    return answer.strip().lower() == "yes"


def _profile_text(spec: str) -> str:
    from rig.paths import data_file

    path = data_file("profiles", f"{spec.upper()}.toml") \
        if spec.upper() in BUILTIN and not Path(spec).exists() else Path(spec)
    return path.read_text(encoding="utf-8")


def _output_dir(out: Path) -> None:
    """Create the run directory if needed and refuse it now, before anything starts."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataError(f"{out}: cannot create the output directory: "
                        f"{exc.strerror or exc}") from None
    check_output_dir(out)


def cmd_runs(args: argparse.Namespace) -> int:
    """The table; then each unreadable file as an error line, and exit 2 if there is one."""
    rows = list_runs(args.directory, probe=True)
    print(f"{'run':<28} {'status':<10} {'duration':>10} {'samples':>9} {'lost':>6}  reason")
    for r in rows:
        print(f"{r.name:<28} {r.status:<10} {r.duration:>8.2f} s {r.samples:>9} "
              f"{r.losses:>6}  {r.reason}")
    print(f"{len(rows)} run files in {args.directory}")
    bad = [r for r in rows if r.status == "unreadable"]
    for r in bad:
        print(f"rig: error: {r.reason}", file=sys.stderr)
    return 2 if bad else 0


def cmd_recover(args: argparse.Namespace) -> int:
    """`rig recover FILE`: one line saying what the file holds now."""
    check_readable(args.file, read_status)  # a file HDF5 hangs on is refused, not hung on
    path = recover(args.file)
    status = read_status(path)
    rows = sum(n for name, n in status.samples.items() if not name.startswith("raw/"))
    print(f"{path}: {status.state}, {'complete' if status.complete else 'incomplete'}, "
          f"{rows} channel samples; {status.reason or 'closed normally'}")
    return 0


def _say(text: str) -> None:
    print(f"  {text}", flush=True)
