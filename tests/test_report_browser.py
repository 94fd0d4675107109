"""The report page as a test engineer opens it: headless Chromium, Debian's `chromium`
driven by Playwright.

A short campaign with an undeclared dry friction is fitted and the loop closed in
process; the page is written and then opened *alone*, copied into an empty folder, so
a figure that still pointed at a PNG beside it would not load. Checked: the title,
the constants table (every constant, numbers and units in both systems, the numbers
the JSON holds), every figure decoded by the browser (naturalWidth > 0) and as many
as the fit and the loop made, the loop's step naming the effect, and that the browser
asked for nothing but the page itself.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from analysis.identify.pipeline import identify
from analysis.identify.prepare import MeasuredRun
from analysis.identify.report_format import SHOWN, fit_json
from analysis.loop import close_loop
from analysis.loop.report import loop_json
from analysis.loop.runs import loop_runs
from analysis.model.report_constants import report_model
from analysis.report_html import num
from analysis.report_page import write_report
from rig.units import us_unit
from sim.effects import parse_effect
from sim.generate import generate_campaign

pytestmark = pytest.mark.slow

RUNS = ("A", "B")
EFFECT = "coulomb_friction"
# two response figures, the force curves, the α–β profile and the loop's one step
FIGURES = len(RUNS) + 2 + 1


def chromium() -> str:
    path = shutil.which("chromium")
    if path is None:  # a failure, not a skip: a report nobody opened is not tested
        pytest.fail("chromium is not installed: .ci/run installs it "
                    "(apt-get install -y chromium)")
    return path


@pytest.fixture(scope="module")
def fitted():
    gen = generate_campaign(runs=RUNS, effects=[parse_effect(f"{EFFECT}=300")], seed=3)
    mass = report_model("average").mass
    fit = identify([MeasuredRun(g.name, g.t, g.u, g.x, mass) for g in gen])
    loop = close_loop(fit.model, loop_runs(fit))
    assert loop.effects_added == [EFFECT]
    # the data the CLI writes as JSON, to hold the page's numbers against
    return fit, loop, json.loads(json.dumps({"fit": fit_json(fit), "loop": loop_json(loop)}))


def open_alone(page_path: Path, folder: Path, read):
    """Copy the page alone into `folder`, open it in Chromium, return read(page) and
    every URL the browser requested."""
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.fail("playwright is not installed: pip install '.[test]' (.ci/run does)")
    folder.mkdir()
    alone = folder / "index.html"
    shutil.copyfile(page_path, alone)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium())
        try:
            page = browser.new_page()
            requested: list[str] = []
            page.on("request", lambda r: requested.append(r.url))
            page.goto(alone.as_uri(), wait_until="load")
            return read(page), requested, alone.as_uri()
        finally:
            browser.close()


def read_report(page) -> dict:
    return {
        "title": page.title(),
        "constants": page.eval_on_selector_all(
            "table.constants tr", "rows => rows.slice(1).map(r => ({cls: r.className, "
            "cells: [...r.cells].map(c => c.textContent)}))"),
        "images": page.eval_on_selector_all(
            "img", "els => els.map(e => ({src: e.getAttribute('src').slice(0, 22), "
            "complete: e.complete, width: e.naturalWidth, height: e.naturalHeight}))"),
        "errors_head": page.eval_on_selector_all("section#errors th",
                                                 "els => els.map(e => e.textContent)"),
        "errors_runs": page.eval_on_selector_all("section#errors table.errors tr td:first-child",
                                                 "els => els.map(e => e.textContent)"),
        "steps": page.eval_on_selector_all("section#loop h3[id^=step]",
                                           "els => els.map(e => e.textContent)"),
        "loop": page.inner_text("section#loop"),
        "conditioning": page.inner_text("section#conditioning"),
        "sections": page.eval_on_selector_all("section", "els => els.map(e => e.id)"),
    }


def test_the_report_opens_whole_in_a_browser(fitted, tmp_path: Path) -> None:
    fit, loop, doc = fitted
    out = tmp_path / "report"
    path = write_report(fit, out, loop, [Path("runs/A.csv"), Path("runs/B.csv")])
    # the PNGs stay beside the page for whoever links them
    assert len(list(out.glob("*.png"))) == FIGURES
    seen, requested, url = open_alone(path, tmp_path / "alone", read_report)

    assert seen["title"] == "Isolator identification: runs A, B"
    assert seen["sections"] == ["constants", "errors", "comparisons", "loop", "conditioning",
                                "terminal"]
    # self-contained: the browser fetched the page and nothing else (the figures are data)
    assert requested == [url]
    assert len(seen["images"]) == FIGURES
    for img in seen["images"]:
        assert img["src"] == "data:image/png;base64,"
        assert img["complete"] and img["width"] > 0 and img["height"] > 0, img

    rows = seen["constants"]
    assert [r["cells"][0] for r in rows] == list(SHOWN)
    units = fit.model.units()
    base = doc["fit"]["parameters"]
    for r in rows:
        name, us, us_ci, us_u, si, si_ci, si_u, status = r["cells"]
        assert (us_u, si_u) == (us_unit(units[name]), units[name])
        float(us), float(si)  # numbers in both systems
        assert si == num(base[name]["value"])  # the JSON's number, not a second computation
        if name in fit.held:
            assert "held" in r["cls"] and "not determined by these runs" in status
            assert us_ci == si_ci == ""
        else:
            assert status == "fitted" and float(us_ci) > 0 and float(si_ci) > 0
    assert set(fit.held) == {n for n in SHOWN if base[n].get("held")}

    assert seen["errors_runs"] == list(RUNS)
    assert "force RMS (lb)" in seen["errors_head"]
    assert seen["steps"] == [f"Step 1: added {EFFECT}"]
    step = doc["loop"]["loop"][0]
    assert f"{step['parameter']} = " in seen["loop"] and " lb = " in seen["loop"]
    assert "score χ²₁" in seen["loop"] and "held-out runs" in seen["loop"]
    assert "Appendix A" in seen["conditioning"]
    for c in loop.indistinguishable:
        assert f"Not testable with these runs: {c.candidate}" in seen["conditioning"]


def test_the_report_in_si(fitted, tmp_path: Path) -> None:
    fit, loop, _ = fitted
    path = write_report(fit, tmp_path / "report", loop, units="si")

    def read(page) -> dict:
        return {"errors_head": page.eval_on_selector_all("section#errors th",
                                                         "els => els.map(e => e.textContent)"),
                "widths": page.eval_on_selector_all("img", "els => els.map(e => e.naturalWidth)"),
                "header": page.inner_text("dl.facts")}

    seen, requested, url = open_alone(path, tmp_path / "alone", read)
    assert requested == [url]
    assert len(seen["widths"]) == FIGURES and min(seen["widths"]) > 0
    assert "force RMS (N)" in seen["errors_head"]
    assert "SI (m, m/s, m/s², N)" in seen["header"]
