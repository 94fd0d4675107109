"""Benchmark of the bench TUI: its refresh rate and the samples lost while it displays a
1 kHz acquisition (targets: >= 10 Hz, 0 lost), against the same run without it.

    python bench/tui.py [--profile A] [--repeat 1]

One `sim serve` (started as `rig tui` starts it: rig.tui.session) serves both. First
the baseline, measured in the same run: the profile run by the TUI's run process
(rig.tui.run_process, the runner as `rig run` has it) with no display. Then the
same profile through the app itself, headless (Textual's run_test, 80 x 24), armed
with `a`, `y` as an operator would, with the UI thread lowered as `rig tui` does.

Refresh: the Run screen's redraws per second while the run is live (running and
settling), and the plots' renders per second. Lost samples: the table sensor sends
at 1 kHz, so the file should hold (last - first) x 1 kHz + 1 samples of table_u;
lost = expected - held (also mass_x, and the file's lost-frame counters). CPU: the
TUI process (display) and the runner process (getrusage of the reaped child) per
second of run, with and without the display.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

TABLE_HZ = 1000.0  # the table sensor's rate (data/rig.toml)
TARGET_HZ = 10.0


def children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def losses(path: Path) -> dict:
    """Samples held vs expected at the sensors' rate, and the file's lost-frame counters."""
    from rig.runfile import open_run

    run = open_run(path, raw=False)
    out = {"status": run.status.exit_status, "reason": run.status.reason,
           "counted": sum(c.get("lost", 0) for c in run.counters.values())}
    for name in ("table_u", "mass_x"):
        t = run.channels[name].time
        expected = round((t[-1] - t[0]) * TABLE_HZ) + 1 if len(t) else 0
        out[name] = (len(t), expected, expected - len(t))
    return out


def baseline(session, choice) -> dict:
    """The run with no display: the TUI's run process alone."""
    from rig.tui.run_process import RunProcess

    config = session.live_config(lambda _: None)
    c0, w0 = children_cpu(), time.monotonic()
    proc = RunProcess(config, choice.profile, choice.text, session.out_dir)
    result = None
    for kind, payload in proc.messages():
        if kind == "result":
            result = payload
    proc.join()
    wall = time.monotonic() - w0
    assert result is not None, "the run process gave no result"
    return {"runner_cpu": (children_cpu() - c0) / wall, "wall": wall, **losses(result.path)}


async def with_tui(session, spec: str) -> dict:
    from rig.tui.app import RigApp
    from rig.tui.priority import DISPLAY_NICE
    from rig.tui.widgets import TracePlot

    app = RigApp(session.config, session.out_dir, profile=spec, session=session,
                 display_nice=DISPLAY_NICE)
    async with app.run_test(size=(80, 24)) as pilot:
        await pilot.pause()
        await pilot.press("a", "y")
        live: list[tuple[float, float, int, int]] = []  # (t, cpu, redraws, renders)
        cpu0, child0, w0 = time.process_time(), children_cpu(), time.monotonic()
        while app.job is None or app.job.running:
            s = app.job.latest if app.job else None
            if s is not None and s.phase in ("running", "settling"):
                screen = app.screen
                renders = sum(p.renders for p in screen.query(TracePlot))
                live.append((time.monotonic(), time.process_time(), screen.redraws, renders))
            await asyncio.sleep(0.05)
        wall = time.monotonic() - w0
        runner_cpu = (children_cpu() - child0) / wall
        result, errors = app.job.result, app.screen.display_errors
        await pilot.press("q")
    assert result is not None, f"the run failed: {app.job.error}"
    (t0, c0, r0, p0), (t1, c1, r1, p1) = live[0], live[-1]
    return {"refresh_hz": (r1 - r0) / (t1 - t0), "plot_hz": (p1 - p0) / (t1 - t0) / 2,
            "tui_cpu": (c1 - c0) / (t1 - t0), "tui_cpu_all": (time.process_time() - cpu0) / wall,
            "runner_cpu": runner_cpu, "display_errors": errors, "wall": wall,
            **losses(result.path)}


def report(name: str, r: dict) -> str:
    u, x = r["table_u"], r["mass_x"]
    return (f"  {name:<10} {r['status']:<8} table_u {u[0]:>5} of {u[1]:>5} (lost {u[2]}), "
            f"mass_x {x[0]:>5} of {x[1]:>5} (lost {x[2]}), frames counted lost "
            f"{r['counted']}; runner CPU {r['runner_cpu']:.0%} of one core"
            + (f" ({r['reason']})" if r["reason"] else ""))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--profile", default="A")
    p.add_argument("--repeat", type=int, default=1)
    args = p.parse_args()
    from rig.config import load_config
    from rig.tui.choice import choose
    from rig.tui.session import BenchSession

    config = load_config()
    choice = choose(config, args.profile)
    assert choice.ok, choice.refused or choice.error
    print(f"TUI over a 1 kHz acquisition, profile {choice.label} ({choice.profile.duration:.2f} s"
          f" of motion), 80 x 24 headless; cores: {os.cpu_count()}, load "
          f"{os.getloadavg()[0]:.1f}")
    with tempfile.TemporaryDirectory() as tmp:
        session = BenchSession(config, Path(tmp))
        try:
            for _ in range(args.repeat):
                base = baseline(session, choice)
                tui = asyncio.run(with_tui(session, args.profile))
                print(report("no TUI", base))
                print(report("with TUI", tui))
                lost = tui["table_u"][2] + tui["mass_x"][2] + tui["counted"]
                print(f"  UI refresh {tui['refresh_hz']:.1f} Hz while live = "
                      f"{tui['refresh_hz'] / TARGET_HZ:.2f}x the {TARGET_HZ:g} Hz target "
                      f"(plots {tui['plot_hz']:.1f} Hz each); samples lost with the TUI {lost} "
                      f"(target 0), without {base['table_u'][2] + base['mass_x'][2]}")
                print(f"  TUI process CPU {tui['tui_cpu']:.0%} of one core while live "
                      f"({tui['tui_cpu_all']:.0%} over the whole run); runner "
                      f"{tui['runner_cpu']:.0%} with the TUI vs {base['runner_cpu']:.0%} "
                      f"without = {tui['runner_cpu'] / max(base['runner_cpu'], 1e-9):.2f}x; "
                      f"display errors {tui['display_errors']}")
        finally:
            session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
