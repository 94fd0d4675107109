"""Run: live traces, the six actuators, the bus's health, time, the e-stop, the summary.

A timer redraws from the newest LiveStatus the job holds (REFRESH_HZ); statuses
that arrive in between are skipped, never queued, so a slow terminal cannot back
up the runner. A redraw that fails is counted and shown; the run goes on.
"""

from __future__ import annotations

import logging
from typing import ClassVar

from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal
from textual.screen import Screen
from textual.widgets import Button, Footer, Header

from rig.run.status import LiveStatus
from rig.tui.run_job import LiveJob
from rig.tui.run_view import BusMeter, actuator_table, health_table, state_line
from rig.tui.widgets import LiveText, TracePlot

log = logging.getLogger(__name__)

REFRESH_HZ = 13.0  # redraws per second asked while a run is live (statuses come at 20 Hz)


class RunScreen(Screen):
    """The live view of `app.job`; idle, it says what would run."""

    DEFAULT_CSS = """
    RunScreen #top { height: 1; }
    RunScreen #state { width: 1fr; height: 1; }
    RunScreen #estop { width: 18; background: red; color: white; text-style: bold; }
    RunScreen #plots { height: 1fr; min-height: 7; }
    RunScreen #plot-ux { width: 3fr; }
    RunScreen #plot-z { width: 2fr; }
    RunScreen #bottom { height: 7; }
    RunScreen #actuators { width: 1fr; height: 7; }
    RunScreen #health { width: 29; height: 7; border-left: solid $primary; padding-left: 1; }
    RunScreen #summary { height: 3; }
    """
    BINDINGS: ClassVar[list[Binding]] = [Binding("a", "app.arm", "Arm"),
                                         Binding("r", "app.restart_sim", "New sim")]

    def __init__(self) -> None:
        super().__init__()
        self.redraws = 0  # successful redraws (the bench divides by time)
        self.display_errors = 0
        self._seen = -1
        self._job: LiveJob | None = None
        self._lines: list[str] = []
        self._meter: BusMeter | None = None

    def compose(self) -> ComposeResult:
        yield Header()
        with Horizontal(id="top"):
            yield LiveText(id="state")
            yield Button("E-STOP  space", id="estop", variant="error", compact=True)
        with Horizontal(id="plots"):
            yield TracePlot("table u, mass x", id="plot-ux")
            yield TracePlot("z = x - u", id="plot-z")
        with Horizontal(id="bottom"):
            yield LiveText(id="actuators")
            yield LiveText(id="health")
        yield LiveText(id="summary")
        yield Footer(compact=True)

    def on_mount(self) -> None:
        self.set_interval(1.0 / REFRESH_HZ, self._tick)
        self.watch(self.app, "units", lambda _: self._redraw(force=True), init=False)
        self._redraw(force=True)

    def on_screen_resume(self) -> None:
        self._redraw(force=True)

    def on_button_pressed(self, event: Button.Pressed) -> None:
        if event.button.id == "estop":
            self.app.action_estop()

    def _tick(self) -> None:
        if self.is_current:
            self._redraw()

    def _redraw(self, force: bool = False) -> None:
        job = self.app.job
        if job is not self._job:  # a new run: start its log and bus meter afresh
            self._job, self._seen, self._lines = job, -1, []
            self._meter = BusMeter(self.app.config)
        if job is None:
            self._idle()
            return
        news = bool(job.messages)
        while job.messages:
            self._lines = (self._lines + [job.messages.popleft()])[-3:]
        if job.statuses == self._seen and not (force or news) and job.running:
            return
        self._seen = job.statuses
        try:
            self._draw(job, job.latest)
            self.redraws += 1
        except Exception as exc:
            self.display_errors += 1
            log.warning("run display failed", exc_info=True)
            self.query_one("#summary", LiveText).set(
                Text(f"display error ({type(exc).__name__}: {exc}); logging continues",
                     style="bold red"))

    def _draw(self, job: LiveJob, status: LiveStatus | None) -> None:
        units = self.app.units
        stopped = job.stopped_at is not None
        self.query_one("#state", LiveText).set(state_line(job.choice.label, status, stopped))
        load = self._meter.update(status) if status is not None and self._meter else float("nan")
        self.query_one("#actuators", LiveText).set(actuator_table(status, units))
        self.query_one("#health", LiveText).set(health_table(status, load))
        if status is not None:
            self._plots(status, units)
        self.query_one("#summary", LiveText).set(self._summary(job))

    def _plots(self, status: LiveStatus, units: str) -> None:
        xlim = (-0.35, max(status.duration + 0.45, status.elapsed))
        self.query_one("#plot-ux", TracePlot).show(
            [("u", *status.table_u, "cyan"), ("x", *status.mass_x, "magenta")], units, xlim=xlim)
        self.query_one("#plot-z", TracePlot).show([("", *status.relative_z, "yellow")], units,
                                                  xlim=xlim)

    def _summary(self, job: LiveJob) -> Text:
        if job.running:
            lines = list(self._lines)
            if job.stopped_at is not None:
                lines.append("E-STOP pressed: safe state commanded, closing the run as abort")
            return Text("\n".join(lines[-3:]))
        if job.result is not None:
            r = job.result
            style = "bold green" if r.status == "success" else "bold red"
            return Text.assemble((f"{r.status.upper()} ", style), r.summary())
        if job.result is None and job.stopped_at is not None and "before the run" in job.error:
            return Text("E-STOP before the run started: nothing moved, no run file",
                        style="bold red")
        return Text(f"FAILED to run: {job.error}", style="bold red")

    def _idle(self) -> None:
        choice = self.app.choice
        self.query_one("#state", LiveText).set(Text("no run yet", style="bold"))
        what = ("choose a profile on Setup (1)" if choice is None else
                f"profile {choice.label} selected: {choice.refused.splitlines()[0]}"
                if choice.refused else f"profile {choice.label} selected; a: arm and start")
        self.query_one("#summary", LiveText).set(what)
        self.query_one("#actuators", LiveText).set(actuator_table(None, self.app.units))
