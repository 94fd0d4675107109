"""Arming the table: a modal that only a deliberate `y` accepts; anything listed cancels."""

from __future__ import annotations

from typing import ClassVar

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import Static

from rig.tui.choice import ProfileChoice


class ArmScreen(ModalScreen[bool]):
    """Dismisses True on `y`, False on `n` or Esc. Every other key is ignored."""

    DEFAULT_CSS = """
    ArmScreen { align: center middle; }
    ArmScreen > Vertical {
        width: 60; height: auto; border: thick $error; background: $surface; padding: 1 2;
    }
    ArmScreen #arm-title { text-style: bold; color: $error; }
    """
    BINDINGS: ClassVar[list[Binding]] = [Binding("y", "answer(True)", "Arm and start"),
                Binding("n", "answer(False)", "Cancel"),
                Binding("escape", "answer(False)", "Cancel", show=False)]

    def __init__(self, choice: ProfileChoice, where: str) -> None:
        super().__init__()
        self.choice = choice
        self.where = where

    def compose(self) -> ComposeResult:
        p = self.choice.profile
        worst = self.choice.margins.worst if self.choice.margins else None
        with Vertical():
            yield Static("ARM THE TABLE?", id="arm-title")
            yield Static(f"Profile {self.choice.label}: {p.description if p else ''}\n"
                         f"{p.duration if p else 0:.2f} s of motion on {self.where}.")
            if worst is not None:
                yield Static(f"Smallest margin: actuator {worst.actuator} {worst.quantity} "
                             f"{worst.fraction:.1%}.")
            yield Static("\n[b]y[/b] arm and start    [b]n[/b] / [b]Esc[/b] cancel\n"
                         "E-stop during the run: [b]space[/b] (or the red button)")

    def action_answer(self, yes: bool) -> None:
        self.dismiss(yes)
