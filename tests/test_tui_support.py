"""Helpers for the TUI tests: deterministic run files, a stand-in `analysis fit`, a fit JSON.

(Named test_tui_*.py to live with the TUI tests; it checks its own helpers too.)
"""

from __future__ import annotations

import json
import sys
import textwrap
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import can
import numpy as np

from rig.config import RigConfig, load_config
from rig.errors import DataError
from rig.runfile import RunInfo, RunWriter, list_runs
from rig.tui.fit_job import FitArgvBuilder
from rig.tui.sim_host import SimHost
from rig.wire import can_messages as cm
from rig.wire.can_messages import CommandKind, Feedback, NodeState, RigCommand

#: the shape of `analysis fit --json` (values from a real fit of runs A, B, C)
_ERR = {"20261123T141108_A": (21.68469477914084, 15.907012235883517),
        "20261123T141112_B": (38.107778181478835, 35.11047692074091)}
FIT_DOC: dict = {
    "schema_version": 1,
    "parameters": {
        "m": {"value": 2721.55422, "std": None, "unit": "kg", "held": True},
        "delta": {"value": 0.01955345793262456, "std": None, "unit": "m", "held": False},
        "k1": {"value": 77370.03762528897, "std": 1732.2717309966724, "unit": "N/m",
               "ci95": [73974.85, 80765.23]},  # value ± 1.96 std, as analysis fit writes
        "c1": {"value": 5884.824988709689, "std": 158.69919859996747, "unit": "N/(m/s)"},
        "alpha": {"value": 192.48133696137728, "std": 14981.46036568541, "unit": "1/m"},
        "sensor_delay": {"value": 0.0037536659507171007, "std": 0.0011794742197019103,
                         "unit": "s"},
    },
    "runs": {r: {} for r in _ERR},
    "error": {r: {"residual_over_noise": b} for r, (b, _) in _ERR.items()},
    "loop": [{"added": "sensor_delay", "parameter": "sensor_delay",
              "evidence": {"value": 2113.227760430688,
                           "explanation": "one sensor lags the other"},
              "error_before": {r: {"residual_over_noise": b} for r, (b, _) in _ERR.items()},
              "error_after": {r: {"residual_over_noise": a} for r, (_, a) in _ERR.items()}}],
    "effects_added": ["sensor_delay"],
    "error_before": {r: {"residual_over_noise": b} for r, (b, _) in _ERR.items()},
    "error_after": {r: {"residual_over_noise": a} for r, (_, a) in _ERR.items()},
    "unexplained": {"value": True, "description": "residual 34.21 x the sensor noise"},
}


@contextmanager
def bench_sim() -> Iterator[RigConfig]:
    """The default configuration pointed at a `sim serve` process, as if it were the bench.

    Started as `rig tui` starts it (rig.tui.sim_host): in a session of its own, so it
    does not share this process's CPU share (autogroup) with the display under test.
    """
    sim = SimHost(load_config())
    try:
        yield replace(sim.config, backend="hardware")
    finally:
        sim.stop()


def stand_in_fit(tmp_path: Path) -> FitArgvBuilder:
    """An `analysis fit` stand-in: progress lines on stderr, FIT_DOC as JSON, an index.html."""
    script = tmp_path / "stand_in_fit.py"
    script.write_text(textwrap.dedent(f"""
        import json, sys, time
        from pathlib import Path
        out, report = Path(sys.argv[1]), Path(sys.argv[2])
        for i, step in enumerate(("loading", "stand-in fit", "loop")):
            print(f"analysis fit [{{i * 0.1:5.1f}} s] {{step}}", file=sys.stderr, flush=True)
            time.sleep(0.05)
        print("the text report")
        out.write_text(json.dumps({FIT_DOC!r}))
        (report / "index.html").write_text("<html></html>")
    """), encoding="utf-8")

    def command(files: Sequence[Path], json_path: Path, report: Path) -> list[str]:
        return [sys.executable, str(script), str(json_path), str(report), *map(str, files)]

    return command


def write_run(path: Path, status: str, seconds: float = 2.0) -> Path:
    """A small run file with fixed content: table_u, mass_x at 100 Hz, closed with `status`."""
    path.parent.mkdir(parents=True, exist_ok=True)
    t = np.arange(0.0, seconds, 0.01)
    u = 0.1397 * np.clip((t - 0.3) / 0.2, 0, 1)
    with RunWriter(path, RunInfo(path.stem[-1], "", "sim")) as w:
        w.samples("table_u", t, u)
        w.samples("mass_x", t, u * (1 - np.exp(-np.clip(t - 0.3, 0, None) * 4)))
        if status != "success":
            w.count("can", "lost", 3)
        w.close(status, "" if status == "success" else "emergency stop by the operator")
    return path


class BusWatch:
    """Another client on the rig's bus (a thread): the commands and actuator feedback seen.

    With the simulated rig in its own process (`sim serve`) this is how a test sees
    that the actuators were commanded into the safe state and report it.
    """

    def __init__(self, config: RigConfig) -> None:
        kwargs = config.can.bus_kwargs()
        kwargs.pop("bitrate", None)  # a socketcand client does not set it
        self.bus = can.Bus(**kwargs)
        self.seen: list[tuple[float, RigCommand | Feedback]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            frame = self.bus.recv(timeout=0.05)
            if frame is None:
                continue
            try:
                msg = cm.from_can(frame)
            except DataError:
                continue
            if isinstance(msg, (RigCommand, Feedback)):
                self.seen.append((time.monotonic(), msg))

    def safe_state_sent(self, after: float) -> bool:
        return any(isinstance(m, RigCommand) and m.command == CommandKind.SAFE_STATE
                   for t, m in self.seen if t >= after)

    def states(self, after: float) -> dict[int, NodeState]:
        """Each actuator's last reported state among the feedback frames seen after `after`."""
        return {m.actuator: m.status for t, m in list(self.seen)
                if t >= after and isinstance(m, Feedback)}

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.bus.shutdown()


def test_write_run_is_deterministic(tmp_path: Path) -> None:
    write_run(tmp_path / "a" / "20250101T000000_A.h5", "abort")
    write_run(tmp_path / "b" / "20250101T000000_A.h5", "abort")
    assert list_runs(tmp_path / "a") == list_runs(tmp_path / "b")
    row = list_runs(tmp_path / "a")[0]
    assert row.status == "abort" and row.losses == 3 and row.duration == 1.99


def test_fit_doc_is_json() -> None:
    assert json.loads(json.dumps(FIT_DOC)) == FIT_DOC
