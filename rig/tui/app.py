"""RigApp: the bench TUI. Four modes (Setup, Run, Runs, Results), keys in the footer.

The app owns the session state the screens share: the configuration and its
simulated rig (`session`), the chosen profile (`choice`), the run in progress
(`job`), the fit in progress (`fit`), the runs marked for a fit and the display
units. The e-stop, arm and quit actions live here so they work on every screen.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import ClassVar

from textual.app import App
from textual.binding import Binding
from textual.reactive import reactive
from textual.screen import Screen
from textual.widgets import Input
from textual.worker import Worker, WorkerState

from rig.config import RigConfig
from rig.runfile import list_runs
from rig.tui.choice import ProfileChoice, choose
from rig.tui.confirm import ArmScreen
from rig.tui.fit_job import Command, FitJob, analysis_command
from rig.tui.live import LiveJob
from rig.tui.priority import Spawner, lower_this_thread
from rig.tui.results_screen import ResultsScreen
from rig.tui.run_screen import RunScreen
from rig.tui.runs_screen import RunsScreen
from rig.tui.session import BenchSession
from rig.tui.setup_screen import SetupScreen

ENDED = (WorkerState.SUCCESS, WorkerState.ERROR, WorkerState.CANCELLED)


class RigApp(App[None]):
    """`RigApp(config, out_dir)`; tests pass a config pointed at an in-process SimRig."""

    TITLE = "isolator rig"
    ENABLE_COMMAND_PALETTE = False  # every action has a key in the footer
    CSS = """
    Screen { layout: vertical; }
    .panel { border: round $primary; }
    .refused { color: $error; text-style: bold; }
    .ok { color: $success; }
    """
    MODES: ClassVar[dict[str, type[Screen]]] = {
        "setup": SetupScreen, "run": RunScreen, "runs": RunsScreen, "results": ResultsScreen}
    DEFAULT_MODE = "setup"
    BINDINGS: ClassVar[list[Binding]] = [
        Binding("space", "estop", "E-STOP", priority=True, key_display="space"),
        Binding("1", "switch_mode('setup')", "Setup"),
        Binding("2", "switch_mode('run')", "Run"),
        Binding("3", "switch_mode('runs')", "Runs"),
        Binding("4", "switch_mode('results')", "Fit"),
        Binding("u", "toggle_units", "in/m"),
        Binding("q", "quit", "Quit"),
    ]

    units: reactive[str] = reactive("us")  # "us": in, lb (the report's); "si": m, N
    choice: reactive[ProfileChoice | None] = reactive(None, always_update=True)

    def __init__(self, config: RigConfig, out_dir: Path, *, profile: str = "A",
                 session: BenchSession | None = None, sim_args: tuple[str, ...] = (),
                 fit_command: Command = analysis_command, display_nice: int = 0) -> None:
        """display_nice: lower the UI thread's priority by this much while the app runs
        (rig.tui.priority; `rig tui` uses DISPLAY_NICE) so a loaded machine starves the
        display, never the run."""
        super().__init__()
        self.spawner = Spawner()  # made before the UI thread is lowered: runs start from it
        self.display_nice = display_nice
        self._undo_nice = lambda: None
        self.config = config
        self.session = session or BenchSession(config, out_dir, sim_args)
        self.initial_profile = profile
        self.fit_command = fit_command
        self.job: LiveJob | None = None
        self.fit: FitJob | None = None
        self.marked: set[str] = set()  # run file names marked for the fit
        self.quitting = False

    @property
    def out_dir(self) -> Path:
        return self.session.out_dir

    @property
    def running(self) -> bool:
        return self.job is not None and self.job.running

    # -- profile and arming ------------------------------------------------------------

    def select_profile(self, spec: str) -> ProfileChoice:
        self.choice = choose(self.config, spec)
        return self.choice

    def action_arm(self) -> None:
        """Ask for confirmation (a modal), then start the run on a worker thread."""
        if self.running:
            self.notify("a run is in progress", severity="warning")
            return
        c = self.choice
        if c is None or not c.ok:
            why = "choose a profile first" if c is None else (c.refused or c.error)
            self.notify(f"cannot arm: {why.splitlines()[0]}", severity="error")
            return
        where = "the simulated rig" if self.session.simulated else "the table (hardware)"
        self.push_screen(ArmScreen(c, where), self._armed)

    def _armed(self, yes: bool | None) -> None:
        if not yes:
            self.notify("not armed: nothing moved")
            return
        assert self.choice is not None
        self.job = LiveJob(self.session, self.choice, spawn=self.spawner.call)
        self.switch_mode("run")
        self.run_worker(self.job.execute, name=f"run {self.choice.label}", group="run",
                        thread=True, exit_on_error=False)

    # -- e-stop and quitting ------------------------------------------------------------

    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        if action == "estop" and not self.running and isinstance(self.focused, Input):
            return False  # idle: let a typed space reach the file-name box
        if action == "restart_sim":
            return self.session.simulated and not self.running
        return True

    def action_estop(self) -> None:
        """Abort the run into the safe state now (RunControl.emergency_stop, thread-safe)."""
        if self.job is None or not self.job.running:
            self.notify("E-STOP: no run in progress, the table is not being driven")
            return
        self.job.stop()
        self.notify("E-STOP: safe state commanded, run closing as abort", severity="error")
        if self.current_mode != "run":
            self.switch_mode("run")

    async def action_quit(self) -> None:
        """Quit; a run in progress is e-stopped first and the app exits once it has closed."""
        if self.fit is not None and self.fit.running:
            self.fit.cancel()
        if self.running:
            assert self.job is not None
            self.quitting = True
            self.job.stop()
            self.notify("stopping the run before quitting…", severity="warning")
            return
        self.exit()

    def on_worker_state_changed(self, event: Worker.StateChanged) -> None:
        if event.worker.group == "run" and event.state in ENDED:
            if self.quitting:
                self.exit()
            else:
                self.refresh_bindings()

    def on_mount(self) -> None:
        self._undo_nice = lower_this_thread(self.display_nice)

    def on_unmount(self) -> None:
        """Never leave the table driven by a run nobody can see, nor a fit running."""
        if self.job is not None and self.job.running:
            self.job.stop()
        if self.fit is not None and self.fit.running:
            self.fit.cancel()
        self.spawner.close(wait=False)
        self._undo_nice()

    # -- fitting -------------------------------------------------------------------------

    def action_start_fit(self) -> None:
        self.start_fit()

    def start_fit(self) -> FitJob | None:
        """`analysis fit` of the marked runs (or every successful one) on a worker thread."""
        if self.fit is not None and self.fit.running:
            self.notify("a fit is in progress (c cancels it)", severity="warning")
            return None
        files = self.fit_files()
        if not files:
            self.notify(f"no successful runs in {self.out_dir} to fit", severity="error")
            return None
        report = self.out_dir / f"fit-{time.strftime('%Y%m%dT%H%M%S')}"
        self.fit = FitJob(tuple(files), report, self.fit_command)
        self.switch_mode("results")
        self.run_worker(self.fit.execute, name="fit", group="fit", thread=True,
                        exit_on_error=False)
        return self.fit

    def fit_files(self) -> list[Path]:
        """The marked run files, or every successful run in the output directory."""
        if not self.out_dir.is_dir():
            return []
        rows = list_runs(self.out_dir)
        names = [r.name for r in rows if r.name in self.marked] or \
                [r.name for r in rows if r.status == "success"]
        return [self.out_dir / n for n in names]

    def action_restart_sim(self) -> None:
        """A fresh `sim serve` at the next run (after a fault the old one keeps reporting)."""
        if self.running or not self.session.simulated:
            return
        self.run_worker(self.session.close, name="stop sim", thread=True, exit_on_error=False)
        self.notify("the simulated rig is stopped; the next run starts a fresh one")

    # -- units ---------------------------------------------------------------------------

    def action_toggle_units(self) -> None:
        self.units = "si" if self.units == "us" else "us"
        self.notify(f"units: {'in, lb (the report)' if self.units == 'us' else 'SI: m, N'}",
                    timeout=1.5)
