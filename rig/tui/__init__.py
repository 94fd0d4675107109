"""`rig tui`: the bench's terminal UI (Textual): set up, run, watch, stop, list, identify.

A thin view (design.md §4.13): every piece of work runs in a thread worker or a
subprocess; the screens only read what the workers leave behind. Modules:

    app.py             RigApp: modes (screens), key bindings, arm / e-stop / quit
    session.py         BenchSession: the configuration, the lazily started `sim serve`
    choice.py          ProfileChoice: a profile loaded and limit-checked for Setup
    run_job.py         LiveJob: one run on a worker thread, the latest LiveStatus kept
    fit_job.py         FitJob: `analysis fit` as a subprocess, its progress and JSON
    widgets.py         TracePlot (decimated plotext), unit helpers, small renderables
    confirm.py         ArmScreen: the arming modal (a deliberate `y`)
    setup_screen.py, run_screen.py, runs_screen.py, trace_screen.py, results_screen.py
    cli.py             the `rig tui` subcommand (Textual imported only when it runs)

`rig` never imports `analysis` or `sim`: the fit is a subprocess, the simulated
rig a `sim serve` process (rig.run.sim_process).
"""
