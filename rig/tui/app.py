"""RigApp: the bench TUI. Four modes (Setup, Run, Runs, Results), keys in the footer.

The app owns the session state the screens share: the configuration and its
simulated rig (`session`), the chosen profile (`choice`), the run in progress
(`job`), the fit in progress (`fit`), the runs marked for a fit and the display
units. The e-stop, arm and quit actions live here so they work on every screen;
the e-stop key is taken in `on_event`, before any screen or widget, while a run is live.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import ClassVar

from textual import events
from textual.app import App
from textual.binding import Binding
from textual.reactive import reactive
from textual.screen import Screen
from textual.worker import Worker, WorkerState

from rig.config import RigConfig
from rig.runfile import list_runs
from rig.tui.choice import ProfileChoice, choose
from rig.tui.confirm import ArmScreen
from rig.tui.fit_job import FitArgvBuilder, FitJob, analysis_command
from rig.tui.priority import Spawner, lower_this_thread
from rig.tui.results_screen import ResultsScreen
from rig.tui.run_job import LiveJob
from rig.tui.run_screen import RunScreen
from rig.tui.runs_screen import RunsScreen
from rig.tui.session import BenchSession
from rig.tui.setup_screen import SetupScreen

ENDED = (WorkerState.SUCCESS, WorkerState.ERROR, WorkerState.CANCELLED)
ESTOP_KEY = "space"  # the e-stop, on every screen, widget and modal (docs/tui.md)


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
        Binding(ESTOP_KEY, "estop", "E-STOP", priority=True, key_display="space"),
        Binding("1", "switch_mode('setup')", "Setup"),
        Binding("2", "switch_mode('run')", "Run"),
        Binding("3", "switch_mode('runs')", "Runs"),
        Binding("4", "switch_mode('results')", "Fit"),
        Binding("u", "toggle_units", "in/m"),
        Binding("q", "quit", "Quit"),
        # shown only while a text box has the keys (the footer then loses every letter key)
        Binding("escape", "leave_box", f"Leave box ({ESTOP_KEY}: E-STOP in a run)"),
    ]

    units: reactive[str] = reactive("us")  # "us": in, lb (the report's); "si": m, N
    choice: reactive[ProfileChoice | None] = reactive(None, always_update=True)

    def __init__(self, config: RigConfig, out_dir: Path, *, profile: str = "A",
                 session: BenchSession | None = None, sim_args: tuple[str, ...] = (),
                 fit_command: FitArgvBuilder = analysis_command, display_nice: int = 0) -> None:
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

    async def on_event(self, event: events.Event) -> None:
        """While a run is live, the e-stop key goes to `action_estop` before anything else.

        The `space` binding (priority) alone is not enough: Textual drops every binding
        of a printable key, priority ones too, while the focused widget would type it
        (`check_consume_key`: Input, TextArea, a Select's type-to-search; see
        Screen._binding_chain), so space in Setup's path box was typed and the run went
        on. Neither `check_action` nor SkipAction can help a binding that was dropped,
        and a text box of our own that gives the key back would cover only that box.
        Here the App gets the key from the terminal, before bindings, screens (modal
        or not) and widgets: nothing can consume it. From arming until the run file is
        closed the key is only the e-stop, whatever has focus (a space lost from a path
        is nothing beside a run that cannot be stopped). Idle it goes on as usual: a
        text box types it, elsewhere the binding says no run is in progress.
        """
        if (isinstance(event, events.Key) and event.key == ESTOP_KEY
                and not event.is_forwarded and self.running):
            event.stop()
            event.prevent_default()
            self.action_estop()
            return
        await super().on_event(event)

    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        if action == "restart_sim":
            return self.session.simulated and not self.running
        if action == "leave_box":
            return self.in_text_box  # hidden, and Esc left to others, anywhere else
        return True

    @property
    def in_text_box(self) -> bool:
        """The focused widget types what it is given (Input, TextArea…), the e-stop key too."""
        focused = self.focused
        return focused is not None and focused.check_consume_key(ESTOP_KEY, " ")

    def action_leave_box(self) -> None:
        """Esc in a text box: focus goes back to the form (the widget before it: on Setup,
        the profile list); Tab still moves on."""
        self.screen.focus_previous()

    def action_estop(self) -> None:
        """Abort the run into the safe state now (RunControl.emergency_stop, thread-safe)."""
        if self.job is None or not self.job.running:
            self.notify("E-STOP: no run in progress, the table is not being driven")
            return
        first = self.job.stopped_at is None
        self.job.stop()  # a repeat (key held down) sends it again: harmless, no new notice
        if first:
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
