"""`sim serve`: the simulated rig as its own process, until SIGTERM, Ctrl-C or its parent dies.

It prints where the rig finds it (the CAN endpoint and the pty) and writes the
same to a JSON state file, which appears only once everything is ready:

    {"pid": 1234, "can": {"interface": "socketcand", "host": "127.0.0.1",
     "port": 40321, "channel": "can0"}, "serial": {"path": "/dev/pts/5"}}

Undeclared effects (`--effect quadratic_damping=2000`, sim.effects) change the
physics or the mass sensor and are written nowhere the rig can read. Faults
(`--fault can_drop=0.01`, `--fault stuck_valve=3@0.5`, sim.faults) break the bus,
the sensor or an actuator for the rig to notice. The CAN server listens on
127.0.0.1 only (sim.socketcand_server refuses anything else). The truth
file (`--truth-file`, tests only) gets the noise-free value behind every sensor
sample, as .npz, when the process stops.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import signal
import sys
import threading
from pathlib import Path
from typing import Any

import numpy as np

from analysis.model.report_constants import RUNS, report_model
from rig.config import load_config
from sim.effects import parse_effect
from sim.faults import parse_faults
from sim.rig_sim import SimRig

SWITCH_INTERVAL_S = 2e-4
PARENT_CHECK_S = 0.5  # s between looks at whether the process that started us still lives


def add_parser(sub: Any) -> None:
    p = sub.add_parser("serve", help="run the simulated rig (CAN on loopback, sensor on a pty)",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("--config", type=Path, help="rig TOML (default data/rig.toml)")
    p.add_argument("--seed", type=int, default=0, help="sensor noise seed (default 0)")
    p.add_argument("--state-file", type=Path, help="write the endpoints here as JSON")
    p.add_argument("--effect", action="append", default=[], metavar="NAME=VALUE",
                   help="an undeclared effect (see sim.effects); repeatable")
    p.add_argument("--fault", action="append", default=[], metavar="NAME=VALUE",
                   help="inject a fault (see sim.faults); repeatable")
    p.add_argument("--constants", default="average", choices=RUNS,
                   help="Table 1 column for the isolator (default average)")
    p.add_argument("--truth-file", type=Path, help="tests: noise-free samples to .npz at exit")


def run(args: argparse.Namespace) -> int:
    config = load_config(args.config)
    # Seven threads share the GIL here; one that wakes to send a frame waits up to the
    # switch interval (default 5 ms) for it, so the sensors fell behind real time.
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    effects = tuple(parse_effect(e) for e in args.effect)
    faults = parse_faults(args.fault)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    with SimRig(config, seed=args.seed, effects=effects, model=report_model(args.constants),
                record_truth=args.truth_file is not None, faults=faults) as rig:
        # everything loaded so far (numba, scipy, the compiled integrator) out of the
        # collector's reach: a full collection walked it all, and with the truth recorded
        # (a tuple per sample) one came about 2 s into run A and stopped every sensor for
        # 0.24-0.27 s, past the rig's 0.25 s liveness limit
        gc.freeze()
        state = {"pid": os.getpid(),
                 "can": {"interface": "socketcand", "host": rig.server.host,
                         "port": rig.can_port, "channel": rig.server.bus_name},
                 "serial": {"path": rig.pty_path}}
        if args.state_file:
            _write_atomic(args.state_file, json.dumps(state))
        print(f"sim serve: CAN socketcand {rig.server.host}:{rig.can_port} "
              f"channel {rig.server.bus_name}; mass sensor on {rig.pty_path}", flush=True)
        parent = os.getppid()
        while not stop.wait(PARENT_CHECK_S):
            if os.getppid() != parent:  # the rig that started us died (kill -9): no orphans
                break
        truth = rig.truth_arrays() if args.truth_file else None
    if truth is not None:
        np.savez(args.truth_file, **truth)
    if args.state_file:
        args.state_file.unlink(missing_ok=True)
    print("sim serve: stopped", file=sys.stderr, flush=True)
    return 0


def _write_atomic(path: Path, text: str) -> None:
    """The reader sees the whole file or none: write beside it, then rename."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)
