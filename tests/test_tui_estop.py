"""The e-stop key acts from every screen, modal and focusable widget while a run is live.

Every widget that can take focus, on every screen of the app (its modes, the
traces pushed over Runs, the Results' second tab, the arming modal), is found
from the screens themselves (`focus_chain`), so a widget added later is covered
without editing this file; a widget only a new state shows (every `can_focus`
widget in the DOM), or a new screen class in rig.tui, fails the test as not
reached until EXTRA_VIEWS shows it. For each one a run is started, that widget
is focused, space is pressed, and the run file must close as `abort`
(emergency stop), not `success`. Against a `sim serve` of its own, started as
tests/test_tui.py starts one (bench_sim).

And the profile path box, idle: a space is typed into it, Esc leaves it, and the
screen says how the e-stop and leaving work while the box has the keys.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from textual.screen import Screen
from textual.widget import Widget
from textual.widgets import Input, OptionList, TabbedContent

from rig.config import RigConfig, load_config
from rig.runfile import open_run
from rig.tui.app import RigApp
from rig.tui.confirm import ArmScreen
from rig.tui.runs_screen import RunsScreen
from tests.test_run_limits import profile_file
from tests.test_tui import SIZE, shown, until
from tests.test_tui_support import bench_sim, write_run

#: what is shown: each mode of the app, then the states that show other screens or widgets
EXTRA_VIEWS = ("runs/trace",  # a run's traces, pushed over Runs (Enter)
               "results/loop",  # the Results' second tab (v)
               "run/arm")  # the arming modal; `a` refuses it during a run, so it is pushed


@pytest.fixture(scope="module")
def rig() -> Iterator[RigConfig]:
    with bench_sim() as config:
        yield config


def views() -> list[str]:
    return [*RigApp.MODES, *EXTRA_VIEWS]


def screen_classes(base: type[Screen] = Screen) -> set[type[Screen]]:
    """Every Screen (and ModalScreen) class of rig.tui: each must be in some view."""
    found = set()
    for cls in base.__subclasses__():
        if cls.__module__.startswith("rig.tui."):
            found.add(cls)
        found |= screen_classes(cls)
    return found


async def show(app: RigApp, pilot, view: str) -> None:
    """Bring up `view`: a mode of the app (its own screen on top), or a state within one."""
    mode, _, state = view.partition("/")
    app.switch_mode(mode)
    await pilot.pause()
    while len(app.screen_stack) > 1:  # a trace or modal left from the last view
        app.pop_screen()
    await pilot.pause()
    if state == "trace":
        runs = app.screen
        assert isinstance(runs, RunsScreen) and runs.rows, "Runs lists no file to open"
        runs.action_open()
    elif state == "loop":
        app.screen.query_one(TabbedContent).active = "loop"
    elif state == "arm":
        assert app.choice is not None
        app.push_screen(ArmScreen(app.choice, "the simulated rig"))
    await pilot.pause(0.2)


def name(screen: Screen, widget: Widget | None) -> str:
    """`Screen/Widget#id` (its index among the screen's widgets of that type if no id)."""
    if widget is None:
        return f"{type(screen).__name__}/nothing focused"
    same = [w for w in screen.query(type(widget).__name__) if type(w) is type(widget)]
    tag = f"#{widget.id}" if widget.id else f"[{same.index(widget)}]"
    return f"{type(screen).__name__}/{type(widget).__name__}{tag}"


async def start_run(app: RigApp, pilot) -> None:
    """Arm (the modal, `y`) and wait until the table is moving."""
    app.action_arm()
    await pilot.pause()
    assert isinstance(app.screen, ArmScreen)
    await pilot.press("y")

    def moving() -> bool:
        job = app.job
        assert job is not None and (job.running or job.result), job.error
        s = job.latest
        assert s is None or s.phase != "ended", (s, job.result)
        return s is not None and s.phase == "running" and s.elapsed > 0.05

    await until(pilot, moving, 30)


@pytest.mark.asyncio
async def test_estop_acts_from_every_focusable_widget_of_every_screen(
        rig: RigConfig, tmp_path: Path) -> None:
    out = tmp_path / "runs"
    write_run(out / "20250101T000000_A.h5", "success")  # a run for the traces view
    # Setup shows its path in the file box. Long enough that no run ends by itself while a
    # view is brought up and a widget focused: 3 s ran out first on a loaded 2-core EPYC,
    # and the space pressed then found a run that had ended in success
    spec = profile_file(tmp_path, "long", 1.0, 20.0)
    app = RigApp(rig, out, profile=str(spec))
    reached: set[str] = set()
    focusable: set[str] = set()
    shown_screens: set[type[Screen]] = set()
    async with app.run_test(size=SIZE) as pilot:
        await pilot.pause()
        for view in views():
            await show(app, pilot, view)  # idle: what can take focus here
            screen = app.screen
            shown_screens.add(type(screen))
            targets = [name(screen, w) for w in screen.focus_chain] or [name(screen, None)]
            focusable |= {name(screen, w) for w in screen.query("*") if w.can_focus}
            for i, target in enumerate(targets):
                if target in reached:  # the same widget, seen from an earlier view
                    continue
                await start_run(app, pilot)
                await show(app, pilot, view)
                widget = app.screen.focus_chain[i] if app.screen.focus_chain else None
                assert name(app.screen, widget) == target
                app.screen.set_focus(widget)
                await pilot.pause()
                assert app.focused is widget and app.job is not None and app.job.running, target
                await pilot.press("space")
                await until(pilot, lambda: not app.job.running, 10)
                result = app.job.result
                assert result is not None, f"{view}, {target}: {app.job.error}"
                status = open_run(result.path).status
                assert status.exit_status == "abort" and "emergency stop" in status.reason, (
                    f"space with {target} focused ({view}): the run ended "
                    f"{status.exit_status} {status.reason!r}, not e-stopped")
                reached.add(target)
    assert focusable <= reached, f"widgets no view reached: {sorted(focusable - reached)}"
    assert screen_classes() <= shown_screens, (
        f"screens not shown: {screen_classes() - shown_screens}")
    assert "SetupScreen/Input#file" in reached  # the box of issue 18 (a sanity check)


@pytest.mark.asyncio
async def test_the_path_box_idle_types_a_space_esc_leaves_it_and_it_says_so(
        tmp_path: Path) -> None:
    app = RigApp(load_config(), tmp_path / "runs")
    async with app.run_test(size=SIZE) as pilot:
        await pilot.pause()
        await pilot.press("down", "down", "down", "enter")  # file…, then into its box
        await pilot.pause()
        box = app.screen.query_one("#file", Input)
        assert app.focused is box
        shot = shown(app)
        footer = shot.splitlines()[-1]
        assert "esc Leave box" in footer, footer  # how to leave the box
        assert "space: E-STOP in a run" in footer, footer  # and how the e-stop works
        await pilot.press("m", "y", "space", "q", "1")
        await pilot.pause()
        assert box.value == "my q1" and app.job is None and app.is_running
        await pilot.press("escape")
        await pilot.pause()
        assert app.focused is app.screen.query_one("#profiles", OptionList)
        await pilot.press("2")  # out of the box, the keys are the app's again
        await pilot.pause()
        assert app.current_mode == "run"
