"""The `rig import` and `rig export` commands: run files from and to other tools' formats.

Exit codes: 0 written; 2 refused or unusable input, one line on stderr naming the
file and the reason (rig.cli_support), and no output file left behind.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from rig.config import load_config
from rig.convert.export_mdf import export_mdf
from rig.convert.import_log import FORMATS, import_log


def add_parsers(sub: Any) -> None:
    p = sub.add_parser(
        "import", help="decode a CAN log of another tool (BLF, ASC, TRC, CSV, MF4) into a run file",
        description="Decode a CAN log (" + ", ".join(f"{k} {v}" for k, v in FORMATS.items())
        + ") with the DBC into a new run file, through the same decoding as `rig run`. "
          "Refused, leaving no file, unless the log gives both table_u and mass_x "
          "(docs/formats.md).")
    p.add_argument("log", type=Path, help="the CAN log")
    p.add_argument("--dbc", type=Path,
                   help="the DBC the log was recorded with (default data/isolator_rig.dbc); "
                        "it must hold the rig's messages as they are, and may add a MassSensor")
    p.add_argument("--out", type=Path, required=True, help="the run file to write (.h5)")
    p.add_argument("--config", type=Path,
                   help="rig TOML: sensor scales, setpoint rate, payload (default data/rig.toml)")
    p = sub.add_parser("export", help="write a run file's channels in another format (MDF 4)")
    p.add_argument("run", type=Path, help="the run file (.h5)")
    p.add_argument("--mdf", type=Path, required=True,
                   help="the ASAM MDF 4 file to write (.mf4); never overwritten")


def dispatch(args: argparse.Namespace) -> int | None:
    """Run the command if it is one of these; None if not."""
    if args.command == "import":
        print(import_log(args.log, args.out, load_config(args.config), args.dbc).summary())
        return 0
    if args.command == "export":
        print(export_mdf(args.run, args.mdf).summary())
        return 0
    return None
