"""The bench a TUI session drives: its configuration, output directory and simulated rig.

With `backend = "sim"` one `sim serve` process serves the whole session (as `rig
campaign` does: one table, so what a run leaves carries into the next). It starts
lazily, at the first run, in a session of its own (rig.tui.sim_host explains why),
and stops when the session closes.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path

from rig.config import RigConfig
from rig.wire.bus_load import bus_load


class BenchSession:
    """`config` as given (hardware, or "sim" to start `sim serve`), runs written to `out_dir`."""

    def __init__(self, config: RigConfig, out_dir: Path, sim_args: tuple[str, ...] = ()) -> None:
        self.config = config
        self.out_dir = Path(out_dir)
        self.sim_args = sim_args
        self._sim = None  # rig.tui.sim_host.SimHost once started
        self._lock = threading.Lock()

    @property
    def simulated(self) -> bool:
        return self.config.backend == "sim"

    @property
    def sim_pid(self) -> int | None:
        return None if self._sim is None else self._sim.pid

    def describe(self) -> list[tuple[str, str]]:
        """(label, text) rows of what is in use: backend, bus, port, sensors, bus load."""
        c = self.config
        if self.simulated:
            backend = "sim (sim serve, lazily)"
            bus = f"{c.can.interface} {c.can.channel} (sim's)"
            port = "sim's pty"
        else:
            backend = "hardware"
            where = ":".join(str(c.can.extra[k]) for k in ("host", "port") if k in c.can.extra)
            bus = f"{c.can.interface} {c.can.channel}" + (f" @{where}" if where else "")
            port = c.serial.path
        load = bus_load(c)
        return [
            ("config", Path(c.source).name if c.source != "<memory>" else "in memory"),
            ("backend", backend),
            ("CAN", f"{bus} {c.can.bitrate / 1e6:g} Mbit/s"),
            ("serial", f"{port}, {c.serial.baud:,} baud"),
            ("sensors", (f"u CAN {c.table_sensor.sample_rate:g} Hz, "
                         f"x serial {c.mass_sensor.sample_rate:g} Hz")),
            ("bus load", f"{load.load_worst:.0%} of {load.budget:.0%} budget"),
            ("out", str(self.out_dir)),
        ]

    def live_config(self, progress: Callable[[str], None]) -> RigConfig:
        """The configuration a run uses: as given, or pointed at the session's `sim serve`
        (started now if this is the first run; call from a worker thread, it may take s)."""
        self.out_dir.mkdir(parents=True, exist_ok=True)
        if not self.simulated:
            return self.config
        with self._lock:
            if self._sim is None:
                from rig.tui.sim_host import SimHost  # processes: only when a run needs them

                progress("starting the simulated rig (sim serve)…")
                self._sim = SimHost(self.config, self.sim_args)
                progress(f"sim serve running (pid {self._sim.pid})")
            return self._sim.config

    def close(self) -> None:
        """Stop `sim serve` if this session started it; idempotent."""
        with self._lock:
            sim, self._sim = self._sim, None
        if sim is not None:
            sim.stop()
