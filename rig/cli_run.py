"""The `rig check`, `rig run`, `rig runs` and `rig campaign` commands (printing lives here)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from rig import can_messages as cm
from rig.config import RigConfig, load_config
from rig.errors import ConfigError
from rig.limits import check_all
from rig.profile import BUILTIN, load_profile
from rig.runfile import list_runs
from rig.runner import RunResult, run_profile
from rig.simproc import SimProcess

CAMPAIGN = ("A", "B", "C")
DEFAULT_PAUSE_S = 5.0


def add_parsers(sub: Any) -> None:
    p = sub.add_parser("check", help="check a profile against every actuator limit; move nothing")
    _profile_args(p)
    p.add_argument("--units", default="us", choices=("us", "si"))
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


def _profile_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--profile", required=True, help="A, B, C or a profile TOML file")
    p.add_argument("--config", type=Path, help="rig TOML (default data/rig.toml)")


def _run_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, default=Path("runs"), help="directory (default ./runs)")
    p.add_argument("--yes", action="store_true", help="arm without asking")
    p.add_argument("--sim-arg", action="append", default=[], help=argparse.SUPPRESS)


def dispatch(args: argparse.Namespace) -> int | None:
    """Run the command if it is one of these; None if not."""
    handlers = {"check": cmd_check, "run": cmd_run, "campaign": cmd_campaign, "runs": cmd_runs}
    handler = handlers.get(args.command)
    return None if handler is None else handler(args)


def cmd_check(args: argparse.Namespace) -> int:
    config = load_config(args.config)
    margins = check_all(config, load_profile(args.profile))  # LimitError → exit 2
    print(margins.format(args.units))
    print(cm.check_bus_load(config).format())
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    result = _one(args, args.profile)
    return 0 if result.status == "success" else 1


def cmd_campaign(args: argparse.Namespace) -> int:
    if args.pause < 0:
        raise ConfigError("--pause", "", f"must be >= 0 s, got {args.pause}")
    config = load_config(args.config)
    for name in CAMPAIGN:  # all three before anything starts or moves
        check_all(config, load_profile(name))
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
    args.out.mkdir(parents=True, exist_ok=True)
    print(f"run {profile.name}: {profile.description or spec} ({profile.duration:.2f} s)")
    result = run_profile(config, profile, text, args.out, confirm=lambda: _confirm(args, spec),
                         progress=_say, sim_args=tuple(args.sim_arg), start_sim=start_sim)
    print(result.summary(), flush=True)
    return result


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


def cmd_runs(args: argparse.Namespace) -> int:
    rows = list_runs(args.directory)
    print(f"{'run':<28} {'status':<10} {'duration':>10} {'samples':>9} {'lost':>6}  reason")
    for r in rows:
        print(f"{r.name:<28} {r.status:<10} {r.duration:>8.2f} s {r.samples:>9} "
              f"{r.losses:>6}  {r.reason}")
    print(f"{len(rows)} run files in {args.directory}")
    return 0


def _say(text: str) -> None:
    print(f"  {text}", flush=True)
