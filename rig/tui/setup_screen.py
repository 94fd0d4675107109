"""Setup: what is in use, which profile, its table motion and its per-actuator limit margins.

Moving through the profile list checks each one at once (rig.limits.check_all); a
refused profile shows the LimitError in red and cannot be armed.
"""

from __future__ import annotations

from typing import ClassVar

from rich.table import Table
from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.screen import Screen
from textual.widgets import Footer, Header, Input, OptionList, Static
from textual.widgets.option_list import Option

from rig.limits import QUANTITIES
from rig.profile import BUILTIN, load_profile
from rig.tui.choice import ProfileChoice, margin_rows, quantity_units
from rig.tui.widgets import TracePlot, length

FILE_OPTION = "file"
SHORT = {"stroke": "stroke", "velocity": "veloc.", "acceleration": "accel.", "force": "force"}


class SetupScreen(Screen):
    """Configuration, profile list (A, B, C, a file), preview, margins, verdict."""

    DEFAULT_CSS = """
    SetupScreen #setup-left { width: 32; }
    SetupScreen #config { height: auto; }
    SetupScreen #profiles { height: auto; max-height: 7; }
    SetupScreen #file { display: none; }
    SetupScreen #file.shown { display: block; }
    SetupScreen #preview { height: 1fr; min-height: 6; }
    SetupScreen #verdict { height: auto; max-height: 4; padding: 0 1; }
    SetupScreen #margins { height: auto; }
    """
    BINDINGS: ClassVar[list[Binding]] = [Binding("a", "app.arm", "Arm")]

    def compose(self) -> ComposeResult:
        yield Header()
        with Horizontal():
            with Vertical(id="setup-left"):
                yield Static(id="config", classes="panel")
                yield OptionList(*self._options(), id="profiles", classes="panel")
                yield Input(placeholder="profile TOML path, Enter", id="file")
            with Vertical(id="setup-right"):
                yield TracePlot("table u", id="preview")
                yield Static(id="verdict")
                yield Static(id="margins")
        yield Footer(compact=True)

    def _options(self) -> list[Option]:
        options = []
        for name in BUILTIN:
            try:
                text = f"{name}  {load_profile(name).description}"
            except Exception:  # noqa: BLE001 - a broken data file shows, it does not crash Setup
                text = f"{name}  (unreadable)"
            options.append(Option(text[:27], id=name))
        options.append(Option("file…  a profile TOML", id=FILE_OPTION))
        return options

    def on_mount(self) -> None:
        self.query_one("#config").border_title = "Configuration"
        self.query_one("#profiles").border_title = "Profile"
        self.watch(self.app, "units", lambda _: self._show(), init=False)
        self.watch(self.app, "choice", lambda _: self._show(), init=False)
        profiles = self.query_one(OptionList)
        initial = self.app.initial_profile
        if initial.upper() in BUILTIN:
            profiles.highlighted = BUILTIN.index(initial.upper())
        else:
            profiles.highlighted = len(BUILTIN)
            box = self.query_one("#file", Input)
            box.value = initial
            self.app.select_profile(initial)
        profiles.focus()
        self._show_config()
        self._show()

    def _show_config(self) -> None:
        rows = Table.grid(padding=(0, 1))
        rows.add_column(style="bold")
        rows.add_column()
        for label, text in self.app.session.describe():
            rows.add_row(label, text)
        self.query_one("#config", Static).update(rows)

    def on_option_list_option_highlighted(self, event: OptionList.OptionHighlighted) -> None:
        box = self.query_one("#file", Input)
        if event.option.id == FILE_OPTION:
            box.add_class("shown")
            if box.value.strip():
                self.app.select_profile(box.value.strip())
            return
        box.remove_class("shown")
        self.app.select_profile(str(event.option.id))

    def on_option_list_option_selected(self, event: OptionList.OptionSelected) -> None:
        if event.option.id == FILE_OPTION:
            self.query_one("#file", Input).focus()

    def on_input_submitted(self, event: Input.Submitted) -> None:
        if event.value.strip():
            self.app.select_profile(event.value.strip())

    def _show(self) -> None:
        choice: ProfileChoice | None = self.app.choice
        units = self.app.units
        plot = self.query_one("#preview", TracePlot)
        verdict = self.query_one("#verdict", Static)
        margins = self.query_one("#margins", Static)
        if choice is None:
            verdict.update("choose a profile")
            return
        t, u = choice.preview()
        plot.title = f"profile {choice.label}: table u"
        plot.show([("", t, u, "cyan")], units)
        verdict.set_class(not choice.ok, "refused")
        verdict.set_class(choice.ok, "ok")
        verdict.update(_verdict(choice, units))
        margins.update(_margin_table(choice, units) if choice.margins else "")


def _verdict(choice: ProfileChoice, units: str) -> Text:
    if choice.error:
        return Text(f"cannot read: {choice.error}")
    if choice.refused:
        return Text(f"REFUSED: {choice.refused}")
    p = choice.profile
    assert p is not None and choice.margins is not None
    w = choice.margins.worst
    peak = length(p.peaks()["displacement"], units, 2)
    return Text(f"OK {p.duration:.2f} s, |u| {peak.lstrip('+')} {'in' if units == 'us' else 'm'}; "
                f"least margin: act {w.actuator} {w.quantity} {w.fraction:.0%}.  a: arm")


def _margin_table(choice: ProfileChoice, units: str) -> Table:
    assert choice.margins is not None
    table = Table(box=None, padding=(0, 1), collapse_padding=True, pad_edge=False,
                  show_edge=False, header_style="bold", title_style="italic",
                  title="peak and margin (1 - peak/limit)")
    table.add_column("act\n")
    for q, unit in zip(QUANTITIES, quantity_units(units)):
        table.add_column(f"{SHORT[q]}\n{unit}", justify="right")
    for name, cells in margin_rows(choice.margins, units):
        table.add_row(name, *[Text(text, style="" if ok else "bold red") for text, ok in cells])
    return table
