"""Widgets and helpers shared by the screens: a decimated trace plot, lengths in in or m."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from rich.console import RenderableType
from textual.widget import Widget
from textual_plotext import PlotextPlot

from rig.units import from_si

MAX_POINTS = 300  # per series, at most; a plot draws ~2 points per column (braille)

#: one series: (label, t s, value m, colour)
Series = tuple[str, np.ndarray, np.ndarray, str]


def length_unit(units: str) -> str:
    """"in" for the report's units ("us"), "m" for SI."""
    return "in" if units == "us" else "m"


def length(value_m: float, units: str, digits: int | None = None) -> str:
    """A length for the display: `value_m` (m) in in or m, signed, fixed width."""
    if not np.isfinite(value_m):
        return "—"
    d = digits if digits is not None else (3 if units == "us" else 4)
    return f"{float(from_si(value_m, length_unit(units))):+.{d}f}"


def decimate(t: np.ndarray, v: np.ndarray, points: int = MAX_POINTS
             ) -> tuple[np.ndarray, np.ndarray]:
    """Every k-th sample so at most `points` remain (the last one kept: the live edge)."""
    n = len(t)
    if n <= points:
        return t, v
    idx = np.linspace(0, n - 1, points).astype(int)
    return t[idx], v[idx]


class TracePlot(PlotextPlot):
    """A plotext plot of a few (t, value) series, lengths converted to `units`.

    `renders` counts the frames actually drawn: the UI refresh rate the bench reports.
    """

    DEFAULT_CSS = """
    TracePlot { height: 1fr; width: 1fr; min-height: 5; }
    """

    def __init__(self, title: str = "", *, id: str | None = None,
                 classes: str | None = None) -> None:
        super().__init__(id=id, classes=classes)
        self.title = title
        self.renders = 0

    def show(self, series: Sequence[Series], units: str, xlabel: str = "t s",
             xlim: tuple[float, float] | None = None) -> None:
        """Replace the data and ask for a redraw (drawn on the next screen refresh)."""
        plt = self.plt
        plt.clear_data()  # not clear_figure: rebuilding the figure's settings costs ~15 %
        plt.title(f"{self.title} [{length_unit(units)}]" if self.title else "")
        plt.xlabel(xlabel)
        unit = length_unit(units)
        points = min(MAX_POINTS, max(2 * self.size.width, 40))
        for label, t, v, colour in series:
            ok = np.isfinite(v)
            t, v = decimate(np.asarray(t)[ok], np.asarray(v)[ok], points)
            if len(t):
                plt.plot(t.tolist(), np.asarray(from_si(v, unit)).tolist(),
                         label=label or None, color=colour, marker="braille")
        if xlim is not None and xlim[1] > xlim[0]:
            plt.xlim(*xlim)
        else:
            plt.xlim(None, None)
        self.refresh()

    def render(self):
        self.renders += 1
        return super().render()


class LiveText(Widget):
    """A fixed-size box showing one renderable; `set()` repaints it without a layout pass.

    (Static.update re-lays out the screen, which at 10+ Hz costs more than the drawing.)
    """

    DEFAULT_CSS = "LiveText { height: 1; }"

    def __init__(self, renderable: RenderableType = "", *, id: str | None = None,
                 classes: str | None = None) -> None:
        super().__init__(id=id, classes=classes)
        self._renderable = renderable

    def set(self, renderable: RenderableType) -> None:
        self._renderable = renderable
        self.refresh()

    def render(self) -> RenderableType:
        return self._renderable
