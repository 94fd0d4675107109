"""Runs: the run files of the output directory; open one, mark runs for a fit."""

from __future__ import annotations

from typing import ClassVar

from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.screen import Screen
from textual.widgets import DataTable, Footer, Header, Static

from rig.errors import DataError
from rig.runfile import RunSummary, list_runs
from rig.tui.trace_screen import TraceScreen

STATUS_STYLE = {"success": "green", "abort": "bold red", "fail": "bold red",
                "running": "cyan", "crashed": "bold red", "unreadable": "red"}


class RunsScreen(Screen):
    """A table of `list_runs(out_dir)`; Enter opens a run's traces, m marks it, f fits."""

    DEFAULT_CSS = """
    RunsScreen #runs { height: 1fr; }
    RunsScreen #runs-info { height: 3; padding: 0 1; }
    """
    BINDINGS: ClassVar[list[Binding]] = [Binding("enter", "open", "Open"),
                Binding("m", "mark", "Mark"),
                Binding("f", "fit", "Fit"),
                Binding("r", "reload", "Reload", show=False)]

    def __init__(self) -> None:
        super().__init__()
        self.rows: list[RunSummary] = []

    def compose(self) -> ComposeResult:
        yield Header()
        yield DataTable(id="runs", cursor_type="row", zebra_stripes=True)
        yield Static(id="runs-info")
        yield Footer(compact=True)

    def on_mount(self) -> None:
        table = self.query_one(DataTable)
        table.add_columns("fit", "run", "status", "duration", "samples", "lost", "reason")
        self.action_reload()
        table.focus()

    def on_screen_resume(self) -> None:
        self.action_reload()

    def action_reload(self) -> None:
        table = self.query_one(DataTable)
        row = table.cursor_row
        table.clear()
        try:
            self.rows = list_runs(self.app.out_dir) if self.app.out_dir.is_dir() else []
        except DataError as exc:
            self.rows = []
            self.query_one("#runs-info", Static).update(Text(str(exc), style="red"))
            return
        for r in self.rows:
            table.add_row("✓" if r.name in self.app.marked else "", r.name,
                          Text(r.status, style=STATUS_STYLE.get(r.status, "")),
                          f"{r.duration:.2f} s", f"{r.samples:,}",
                          Text(str(r.losses), style="bold red" if r.losses else ""),
                          _clip(r.reason, 15), key=r.name)
        if self.rows:
            table.move_cursor(row=min(row, len(self.rows) - 1))
        self._info()

    def _info(self) -> None:
        marked = sorted(self.app.marked & {r.name for r in self.rows})
        row = self._current()
        self.query_one("#runs-info", Static).update(
            (f"{row.name}: {row.status}{' (' + row.reason + ')' if row.reason else ''}\n"
             if row is not None else "")
            + f"{len(self.rows)} run files in {self.app.out_dir}; "
            + (f"{len(marked)} marked for the fit" if marked else
               "m marks runs for the fit (none: f fits every successful run)"))

    def on_data_table_row_highlighted(self, event: DataTable.RowHighlighted) -> None:
        self._info()

    def _current(self) -> RunSummary | None:
        table = self.query_one(DataTable)
        if not self.rows or table.cursor_row < 0 or table.cursor_row >= len(self.rows):
            return None
        return self.rows[table.cursor_row]

    def on_data_table_row_selected(self, event: DataTable.RowSelected) -> None:
        self.action_open()

    def action_open(self) -> None:
        row = self._current()
        if row is not None:
            self.app.push_screen(TraceScreen(self.app.out_dir / row.name))

    def action_mark(self) -> None:
        row = self._current()
        if row is None:
            return
        self.app.marked ^= {row.name}
        self.query_one(DataTable).update_cell(row.name, self._fit_column(),
                                              "✓" if row.name in self.app.marked else "")
        self._info()

    def _fit_column(self):
        return next(iter(self.query_one(DataTable).columns))

    def action_fit(self) -> None:
        self.app.start_fit()


def _clip(text: str, width: int) -> str:
    return text if len(text) <= width else text[: width - 1] + "…"
