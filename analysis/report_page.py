"""`analysis fit --report DIR`: the fit and the loop as one self-contained HTML page.

DIR/index.html is the report a test engineer forwards: what was fitted, the
constants in the report's units and in SI with their 95 % intervals, the errors
per run, the report's Figures 13–18 as measured-against-model comparisons in the
user's units, each step of the loop with its evidence and figure, what stayed
unexplained and the conditioning notes; the terminal's text closes it. Every
figure is embedded, so the file alone is the report; the PNGs are also written
beside it for whoever links or reuses them.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from pathlib import Path

import numpy as np

from analysis.identify.figures import fit_figures
from analysis.identify.pipeline import IsolatorFit
from analysis.identify.report_format import format_fit
from analysis.identify.report_page import (
    comparisons_section,
    conditioning_notes,
    conditioning_section,
    constants_section,
    errors_section,
    header,
)
from analysis.loop import LoopResult, predict
from analysis.loop import report_page as loop_page
from analysis.loop.report import format_loop, loop_figures
from analysis.report_html import Html, page, section, tag

CONTENTS = (("constants", "Identified constants"), ("errors", "Errors per run"),
            ("comparisons", "Measured and model"), ("loop", "Closing the loop"),
            ("conditioning", "Conditioning"), ("terminal", "As printed by analysis fit"))


def write_report(fit: IsolatorFit, directory: Path, loop: LoopResult | None = None,
                 sources: Sequence[Path] = (), units: str = "us",
                 when: datetime | None = None) -> Path:
    """Write the figures (PNG) and index.html into `directory`; returns the page's path.

    `units`: "us" (the report's in, in/s, g, lb) or "si" for the figures and the first
    columns; the constants are given in both. `sources`: the files the runs came from.
    """
    directory = Path(directory)
    after = _after_loop(fit, loop) if loop is not None and loop.steps else None
    figures = fit_figures(fit, directory, units, after)
    body: list[object] = [header(fit, sources, when or datetime.now().astimezone(), units),
                          _contents(loop is not None),
                          constants_section(fit, units, loop is not None),
                          errors_section(fit, units), comparisons_section(figures)]
    notes = conditioning_notes(fit)
    text = format_fit(fit)
    if loop is not None:
        body.append(loop_page.loop_section(loop, loop_figures(loop, directory, units), units))
        notes += loop_page.conditioning_notes(loop)
        text += "\n\n" + format_loop(loop, "us")  # as the CLI prints it
    body += [conditioning_section(notes),
             section("terminal", "As printed by analysis fit", tag("pre", text))]
    path = directory / "index.html"
    names = ", ".join(p.run.name for p in fit.prepared)
    path.write_text(page(f"Isolator identification: runs {names}", body), encoding="utf-8")
    return path


def _after_loop(fit: IsolatorFit, loop: LoopResult) -> dict[str, np.ndarray]:
    """Run name → x (m) the final model, effects included, predicts on the fit's runs (the
    loop's runs are the fit's: `loop.runs.loop_runs`)."""
    predicted = predict(loop.final.hypothesis, [p.oe for p in fit.prepared])
    return {p.run.name: x[0] for p, x in zip(fit.prepared, predicted)}


def _contents(with_loop: bool) -> Html:
    links = "".join(tag("li", tag("a", title, href=f"#{anchor}")) for anchor, title in CONTENTS
                    if with_loop or anchor != "loop")
    return tag("nav", tag("ol", Html(links)))
