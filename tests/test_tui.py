"""The bench TUI (rig.tui) driven by Textual's Pilot against the simulated rig.

The app gets the default configuration pointed at one `sim serve` for the module
(as "hardware", so the app starts no sim of its own): a run is real, socketcand
bus, pty, HDF5 file, the runner in its own process. Not the in-process SimRig of
test_run_control: in this process it shares the GIL with Textual, and the first
compose of a screen starved it into "actuator feedback silent" aborts. Profiles
are short custom ones (`profile_file`) to keep this quick.
"""

from __future__ import annotations

import asyncio
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from rig.config import RigConfig, load_config
from rig.runfile import open_run
from rig.tui import run_screen
from rig.tui.app import RigApp
from rig.tui.confirm import ArmScreen
from rig.tui.fit_job import FitJob, summarize
from rig.tui.run_screen import RunScreen
from rig.tui.trace_screen import TraceScreen
from rig.wire.can_messages import NodeState
from tests.test_run_limits import profile_file
from tests.test_tui_support import FIT_DOC, BusWatch, bench_sim, stand_in_fit, write_run

SIZE = (80, 24)


@pytest.fixture(scope="module")
def rig() -> Iterator[RigConfig]:
    """The default configuration pointed at one `sim serve` for the module (bench_sim)."""
    with bench_sim() as config:
        yield config


async def until(pilot, condition: Callable[[], bool], timeout: float = 20.0) -> None:
    end = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < end, "condition not met in time"
        await pilot.pause(0.05)


def shown(app: RigApp) -> str:
    """What the screen shows, as plain text lines (an operator's view, no styles)."""
    return "\n".join(strip.text for strip in app.screen._compositor.render_strips())


@pytest.mark.asyncio
async def test_setup_shows_configuration_profile_and_margins(
        rig: RigConfig, tmp_path: Path) -> None:
    app = RigApp(rig, tmp_path / "runs")
    async with app.run_test(size=SIZE) as pilot:
        await pilot.pause()
        assert app.choice is not None and app.choice.label == "A" and app.choice.ok
        shot = shown(app)
        for expected in ("Configuration", "hardware", "socketcand", rig.serial.path, "1 X1", "6 Y2",
                     "least margin"):
            assert expected in shot, expected
        await pilot.press("down")  # profile B
        await pilot.pause()
        assert app.choice.label == "B"
        await pilot.press("u")  # SI
        await pilot.pause()
        assert app.units == "si" and "stroke" in shown(app)


@pytest.mark.asyncio
async def test_a_refused_profile_shows_the_limit_and_cannot_be_armed(rig: RigConfig,
                                                                     tmp_path: Path) -> None:
    spec = profile_file(tmp_path, "too_far", 8.0, 2.0)
    app = RigApp(rig, tmp_path / "runs", profile=str(spec))
    async with app.run_test(size=SIZE) as pilot:
        await pilot.pause()
        assert app.choice is not None and not app.choice.ok
        assert "actuator 1 stroke" in app.choice.refused
        verdict = app.screen.query_one("#verdict")
        assert verdict.has_class("refused")
        assert "REFUSED" in shown(app)
        await pilot.press("a")
        await pilot.pause()
        assert not isinstance(app.screen, ArmScreen) and app.job is None
    assert not (tmp_path / "runs").exists() or not list((tmp_path / "runs").iterdir())


@pytest.mark.asyncio
async def test_arm_needs_a_deliberate_y_and_the_run_completes(
        rig: RigConfig, tmp_path: Path) -> None:
    spec = profile_file(tmp_path, "small", 1.0, 0.3)
    out = tmp_path / "runs"
    app = RigApp(rig, out, profile=str(spec))
    async with app.run_test(size=SIZE) as pilot:
        await pilot.pause()
        await pilot.press("a")
        await pilot.pause()
        assert isinstance(app.screen, ArmScreen)
        await pilot.press("x", "enter", "space")  # not an answer: still asking, nothing started
        await pilot.pause()
        assert isinstance(app.screen, ArmScreen) and app.job is None
        await pilot.press("y")
        await until(pilot, lambda: app.job is not None and not app.job.running, 30)
        result = app.job.result
        assert result is not None and result.status == "success", app.job.error
        await until(pilot, lambda: "SUCCESS" in shown(app), 5)
        screen = app.screen
        assert isinstance(screen, RunScreen) and screen.redraws >= 3
        assert screen.display_errors == 0
        assert open_run(result.path).status.exit_status == "success"
        await pilot.press("3")  # Runs lists it
        await pilot.pause()
        assert result.path.name in shown(app)
        await pilot.press("enter")  # its traces
        await until(pilot, lambda: isinstance(app.screen, TraceScreen))
        await pilot.pause()
        assert "success" in shown(app) and "table_u" in shown(app)
        await pilot.press("escape")


@pytest.mark.asyncio
async def test_emergency_stop_mid_run_closes_the_run_as_abort(
        rig: RigConfig, tmp_path: Path) -> None:
    spec = profile_file(tmp_path, "long", 1.0, 3.0)
    app = RigApp(rig, tmp_path / "runs", profile=str(spec))
    async with app.run_test(size=SIZE) as pilot:
        await pilot.pause()
        await pilot.press("a", "y")

        def moving() -> bool:
            assert app.job is not None and (app.job.running or app.job.result), app.job.error
            s = app.job.latest
            assert s is None or s.phase != "ended", (s, app.job.result)
            return s is not None and s.phase == "running" and s.elapsed > 0.3

        await until(pilot, moving, 30)
        watch = BusWatch(rig)
        try:
            pressed = time.monotonic()
            await pilot.press("space")
            await until(pilot, lambda: not app.job.running, 10)
            took = time.monotonic() - pressed
            await until(pilot, lambda: len(watch.states(time.monotonic() - 0.1)) == 6 and all(
                s == NodeState.SAFE_STATE for s in watch.states(pressed + took).values()), 3)
            assert watch.safe_state_sent(after=pressed)
        finally:
            watch.close()
        result = app.job.result
        assert result is not None and result.status == "abort", app.job.error
        assert "emergency stop" in result.reason and took < 3.0
        await pilot.pause(0.2)
        assert "ABORT" in shown(app)
    status = open_run(result.path).status
    assert status.exit_status == "abort" and "emergency stop" in status.reason


@pytest.mark.asyncio
async def test_a_failing_display_never_stops_logging(rig: RigConfig, tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(self, status, units) -> None:
        raise RuntimeError("plot exploded")

    monkeypatch.setattr(run_screen.RunScreen, "_plots", broken)
    spec = profile_file(tmp_path, "small", 1.0, 0.3)
    app = RigApp(rig, tmp_path / "runs", profile=str(spec))
    async with app.run_test(size=SIZE) as pilot:
        await pilot.pause()
        await pilot.press("a", "y")
        await until(pilot, lambda: app.job is not None and not app.job.running, 30)
        assert app.job.result is not None and app.job.result.status == "success"
        assert app.screen.display_errors > 0
        assert app.is_running  # the app survived its own display fault


@pytest.mark.asyncio
async def test_quitting_during_a_run_stops_it_first(rig: RigConfig, tmp_path: Path) -> None:
    spec = profile_file(tmp_path, "long", 1.0, 3.0)
    app = RigApp(rig, tmp_path / "runs", profile=str(spec))
    async with app.run_test(size=SIZE) as pilot:
        await pilot.pause()
        await pilot.press("a", "y")
        await until(pilot, lambda: app.job.latest is not None and app.job.latest.phase == "running",
                    30)
        await pilot.press("q")
        await until(pilot, lambda: not app.job.running, 10)
        await asyncio.sleep(0.2)
    assert app.job.result is not None and app.job.result.status == "abort"
    assert open_run(app.job.result.path).status.exit_status == "abort"


@pytest.mark.asyncio
async def test_runs_screen_lists_marks_and_fits_with_progress(tmp_path: Path) -> None:
    out = tmp_path / "runs"
    for name, status in (("20250101T000000_A", "success"), ("20250101T000100_B", "abort"),
                         ("20250101T000200_C", "success")):
        write_run(out / f"{name}.h5", status)
    app = RigApp(load_config(), out, fit_command=stand_in_fit(tmp_path))
    async with app.run_test(size=SIZE) as pilot:
        await pilot.press("3")
        await pilot.pause()
        shot = shown(app)
        assert "20250101T000100_B.h5" in shot and "abort" in shot and "3 run files" in shot
        assert app.fit_files() == [out / "20250101T000000_A.h5", out / "20250101T000200_C.h5"]
        await pilot.press("m")  # mark the first
        await pilot.pause()
        assert app.fit_files() == [out / "20250101T000000_A.h5"]
        await pilot.press("f")
        await until(pilot, lambda: app.fit is not None and not app.fit.running)
        assert app.fit.error == "" and app.fit.summary is not None
        await pilot.pause(0.3)
        shot = shown(app)
        assert "done in" in shot and "k1" in shot and "report " in shot
        assert app.fit.html_path.exists() and app.fit.json_path.exists()
        assert "441.79" in shot and "lb/in" in shot and "lbm" in shot  # the report's units
        await pilot.press("u")
        await pilot.pause(0.3)
        assert "77370" in shown(app) and " kg" in shown(app)
        await pilot.press("v")  # the loop's steps
        await pilot.pause(0.3)
        shot = shown(app)
        assert "sensor_delay" in shot and "21.68 → 15.91" in shot and "unexplained" in shot
        assert any("stand-in fit" in line for line in app.fit.lines)


def test_summarize_reads_the_fit_json() -> None:
    s = summarize(FIT_DOC)
    k1 = next(c for c in s.constants if c.name == "k1")
    assert k1.shown("us") == ("441.79", "± 19.4", "lb/in")  # the 95 % half width, as the CLI
    assert s.effects_added == ("sensor_delay",) and s.steps[0].added == "sensor_delay"
    assert s.before["20261123T141108_A"] == pytest.approx(21.68, abs=0.01)
    assert s.unexplained.startswith("residual")


def test_a_failing_fit_says_why(tmp_path: Path) -> None:
    script = ("import sys; print('analysis fit [  0.1 s] loading', file=sys.stderr); "
              "print('analysis: error: no usable runs', file=sys.stderr); sys.exit(2)")

    def failing(files, json_path, report) -> list[str]:
        return [sys.executable, "-c", script]

    job = FitJob((tmp_path / "x.h5",), tmp_path / "report", failing)
    assert job.execute() is None and not job.running
    assert job.error == "analysis fit exited with code 2: analysis: error: no usable runs"
    assert job.lines[0] == "analysis fit [  0.1 s] loading"
