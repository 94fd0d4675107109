"""One run file's traces: table u, mass x and z = x − u, its status, counters and gaps."""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

import numpy as np
from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal
from textual.screen import Screen
from textual.widgets import Footer, Header, Static

from rig.errors import DataError
from rig.runfile import RunFile, open_run
from rig.tui.widgets import TracePlot


class TraceScreen(Screen):
    """Pushed over Runs; Esc goes back."""

    DEFAULT_CSS = """
    TraceScreen #trace-info { height: auto; max-height: 5; padding: 0 1; }
    TraceScreen #trace-plots { height: 1fr; }
    TraceScreen #plot-z { height: 1fr; }
    """
    BINDINGS: ClassVar[list[Binding]] = [Binding("escape", "app.pop_screen", "Back"),
                Binding("backspace", "app.pop_screen", "Back", show=False)]

    def __init__(self, path: Path) -> None:
        super().__init__()
        self.path = path
        self.run: RunFile | None = None

    def compose(self) -> ComposeResult:
        yield Header()
        yield Static(id="trace-info")
        with Horizontal(id="trace-plots"):
            yield TracePlot("table u", id="plot-u")
            yield TracePlot("mass x", id="plot-x")
        yield TracePlot("z = x - u", id="plot-z")
        yield Footer(compact=True)

    def on_mount(self) -> None:
        try:
            self.run = open_run(self.path, raw=False)
        except DataError as exc:
            self.query_one("#trace-info", Static).update(Text(str(exc), style="bold red"))
            return
        self.watch(self.app, "units", lambda _: self._show(), init=False)
        self._show()

    def _show(self) -> None:
        run = self.run
        assert run is not None
        s = run.status
        lost = sum(c.get("lost", 0) for c in run.counters.values())
        crc = sum(c.get("crc_errors", 0) for c in run.counters.values())
        style = "green" if s.state == "success" else "bold red"
        self.query_one("#trace-info", Static).update(Text.assemble(
            (f"{self.path.name}  ", "bold"), (s.state, style),
            f"{'  (' + s.reason + ')' if s.reason else ''}\nprofile {run.meta['profile_name']}, "
            f"{run.meta['backend']}, started {run.meta['start_time']}\n"
            f"table_u {s.samples.get('table_u', 0):,} samples, mass_x "
            f"{s.samples.get('mass_x', 0):,}; lost {lost} frames, {crc} CRC errors, "
            f"{len(run.gaps)} gaps"))
        units = self.app.units
        u, x = run.channels.get("table_u"), run.channels.get("mass_x")
        if u is None or x is None:
            return
        self.query_one("#plot-u", TracePlot).show([("", u.time, u.value, "cyan")], units)
        self.query_one("#plot-x", TracePlot).show([("", x.time, x.value, "magenta")], units)
        z = x.value - np.interp(x.time, u.time, u.value) if len(u.time) > 1 else x.value * np.nan
        self.query_one("#plot-z", TracePlot).show([("", x.time, z, "yellow")], units)
