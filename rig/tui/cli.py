"""`rig tui [--config FILE] [--out DIR] [--profile A|B|C|FILE]`: the bench TUI.

Textual is imported only when the command runs, so `rig` itself starts fast.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from rig.config import load_config

STOP_WAIT_S = 30.0  # a run e-stopped at exit closes within a few ms; the sim start may not


def add_parser(sub: Any) -> None:
    p = sub.add_parser("tui", help="the bench's terminal UI: set up, run, watch, stop, fit")
    p.add_argument("--config", type=Path, help="rig TOML (default data/rig.toml)")
    p.add_argument("--out", type=Path, default=Path("runs"), help="directory (default ./runs)")
    p.add_argument("--profile", default="A", help="profile selected at start (A, B, C or a file)")
    p.add_argument("--sim-arg", action="append", default=[], help=argparse.SUPPRESS)


def cmd_tui(args: argparse.Namespace) -> int:
    from rig.tui.app import RigApp  # Textual: only now
    from rig.tui.priority import DISPLAY_NICE
    from rig.tui.session import BenchSession

    config = load_config(args.config)
    session = BenchSession(config, args.out, tuple(args.sim_arg))
    app = RigApp(config, args.out, profile=args.profile, session=session,
                 display_nice=DISPLAY_NICE)
    try:
        app.run()
    finally:
        if app.job is not None:  # quitting e-stops a run; make sure it has closed
            app.job.stop()
            app.job.done.wait(STOP_WAIT_S)
        if app.fit is not None:
            app.fit.cancel()
        session.close()
        app.spawner.close()
    if app.job is not None and app.job.result is not None:
        print(app.job.result.summary())
    return 0
