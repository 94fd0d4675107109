"""Results: `analysis fit` of the chosen runs with its progress, the constants (SI/US), the
loop's steps with the error before and after each, and where the report was written."""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.screen import Screen
from textual.widgets import DataTable, Footer, Header, TabbedContent, TabPane

from rig.tui.fit_job import FitJob, FitSummary
from rig.tui.widgets import LiveText

POLL_HZ = 5.0
TABS = ("constants", "loop")


class ResultsScreen(Screen):
    """Shows `app.fit`; f starts a fit (marked runs, or every successful one), c cancels."""

    DEFAULT_CSS = """
    ResultsScreen #fit-state { height: 1; padding: 0 1; }
    ResultsScreen #fit-log { height: 3; padding: 0 1; color: $text-muted; }
    ResultsScreen TabbedContent { height: 1fr; }
    ResultsScreen DataTable { height: 1fr; }
    ResultsScreen #fit-files { height: 2; padding: 0 1; }
    """
    BINDINGS: ClassVar[list[Binding]] = [Binding("f", "app.start_fit", "Fit"),
                Binding("v", "next_tab", "Constants/loop"),
                Binding("c", "cancel", "Cancel fit")]

    def __init__(self) -> None:
        super().__init__()
        self._job: FitJob | None = None
        self._tail: list[str] = []
        self._shown: FitJob | None = None

    def compose(self) -> ComposeResult:
        yield Header()
        yield LiveText(id="fit-state")
        yield LiveText(id="fit-log")
        with TabbedContent(initial="constants"):
            with TabPane("Constants", id="constants"):
                yield DataTable(id="constants-table", cursor_type="row", zebra_stripes=True)
            with TabPane("Loop", id="loop"):
                yield DataTable(id="loop-table", cursor_type="row", zebra_stripes=True)
        yield LiveText(id="fit-files")
        yield Footer(compact=True)

    def on_mount(self) -> None:
        self.query_one("#constants-table", DataTable).add_columns(
            "constant", "value", "± 95 %", "unit")
        self.query_one("#loop-table", DataTable).add_columns(
            "step", "effect added", "evidence", "run", "resid/noise before → after")
        self.set_interval(1.0 / POLL_HZ, self._poll)
        self.watch(self.app, "units", lambda _: self._constants(), init=False)
        self._poll()

    def action_next_tab(self) -> None:
        tabs = self.query_one(TabbedContent)
        tabs.active = TABS[(TABS.index(tabs.active) + 1) % len(TABS)]

    def action_cancel(self) -> None:
        fit = self.app.fit
        if fit is not None and fit.running:
            fit.cancel()

    def _poll(self) -> None:
        fit: FitJob | None = self.app.fit
        state = self.query_one("#fit-state", LiveText)
        if fit is None:
            state.set("no fit yet: f fits the runs marked on Runs (3), or every successful run")
            return
        if fit is not self._job:  # a new fit: clear what the last one showed
            self._job, self._tail, self._shown = fit, [], None
            for table in self.query(DataTable):
                table.clear()
            self.query_one("#fit-files", LiveText).set("")
        tail = list(fit.lines)[-3:]
        if tail != self._tail:
            self.query_one("#fit-log", LiveText).set("\n".join(_clip(ln, 77) for ln in tail))
            self._tail = tail
        state.set(_state(fit))
        if not fit.running and self._shown is not fit:
            self._shown = fit
            self._finished(fit)

    def _finished(self, fit: FitJob) -> None:
        if fit.summary is None:
            return
        self._constants()
        self._loop(fit.summary)
        self.query_one("#fit-files", LiveText).set(
            f"report {_where(fit.html_path)} (fit.json, fit.txt beside it)")

    def _constants(self) -> None:
        fit = self.app.fit
        if fit is None or fit.summary is None:
            return
        table = self.query_one("#constants-table", DataTable)
        table.clear()
        for c in fit.summary.constants:
            value, std, unit = c.shown(self.app.units)
            table.add_row(c.name, Text(value, justify="right"), std, unit)

    def _loop(self, s: FitSummary) -> None:
        table = self.query_one("#loop-table", DataTable)
        table.clear()
        for i, step in enumerate(s.steps, 1):
            for k, run in enumerate(step.before):
                table.add_row(str(i) if k == 0 else "", step.added if k == 0 else "",
                              f"χ² {step.statistic:,.0f}" if k == 0 else "", _short(run),
                              _change(step.before[run], step.after.get(run)))
        for k, run in enumerate(s.before):
            table.add_row("all" if k == 0 else "",
                          ("+".join(s.effects_added) or "(none)") if k == 0 else "", "",
                          _short(run), _change(s.before[run], s.after.get(run)))
        if s.unexplained:
            table.add_row("", Text("unexplained", style="bold red"), "", "", s.unexplained[:70])


def _state(fit: FitJob) -> Text:
    n = len(fit.files)
    runs = f"{n} run{'s' * (n != 1)}"
    if fit.running:
        return Text(f"fitting {runs}… (c cancels)", style="bold")
    took = (fit.finished or fit.started) - fit.started
    if fit.error:
        return Text(f"fit failed after {took:.1f} s: {fit.error}", style="bold red")
    s = fit.summary
    effects = ", ".join(s.effects_added) if s and s.effects_added else "none"
    return Text(f"fit of {runs} done in {took:.1f} s; the loop added: {effects}",
                style="bold green")


def _change(before: float, after: float | None) -> str:
    return f"{before:6.2f} → {after if after is not None else float('nan'):.2f}"


def _clip(text: str, width: int) -> str:
    return text if len(text) <= width else text[: width - 1] + "…"


def _short(run: str) -> str:
    """`20261123T141108_A` → `141108_A`: the time and profile, enough to tell runs apart."""
    return run.split("T", 1)[-1] if "T" in run else run


def _where(path: Path) -> str:
    """`path` relative to the working directory when it is under it (shorter to read)."""
    try:
        return str(path.resolve().relative_to(Path.cwd()))
    except ValueError:
        return str(path)
