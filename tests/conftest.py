"""Shared fixtures: the report's model and profiles; the simulated rig; a check that
nothing leaks.
"""

from __future__ import annotations

import gc
import os
import threading
from collections.abc import Iterator

import pytest

from analysis.blas import one_blas_thread
from analysis.model.report_constants import report_model
from analysis.simulate.compiled import warm_up
from rig.config import load_config
from rig.profile import load_profile
from sim.rig_sim import SimRig

# The fits in this process run as the `analysis` CLI runs them: BLAS on one thread
# (analysis/blas.py).
one_blas_thread()


# The files that run for minutes (`analysis fit` through the CLI, many campaigns over),
# longest first. pytest-xdist hands each worker a file at a time (README), by default
# the files with the most tests first: these few-test files then started last, and one
# worker fitted on alone for minutes after the other had run out of files.
LONGEST_FIRST = ("test_loop_unseen.py", "test_loop_unseen_refit.py", "test_loop.py",
                 "test_compiled_note.py", "test_naming.py", "test_predict.py")


# The files whose tests run the rig against the wall clock: a simulated rig in this
# process or beside it, a terminal. Their bounds are the rig's own (a watchdog, an abort
# within 0.3 s), and on a shared 2-core host whose other tenants take the cores a
# descheduled process misses one though the code meets it: a test here gets two more
# tries (pytest-rerunfailures; the summary line counts every rerun). A logic error fails
# all three. The numeric tests time nothing and get none.
AGAINST_THE_CLOCK = (
    "test_faults_actuator.py", "test_faults_can.py", "test_faults_input.py",
    "test_faults_process.py", "test_faults_serial.py", "test_faults_storage.py",
    "test_reliability_exposure.py", "test_run_campaign.py", "test_run_control.py",
    "test_run_limits.py", "test_sim_serve.py", "test_tui.py", "test_tui_estop.py",
    "test_tui_support.py", "test_tui_terminal.py",
)
RERUNS = 2


def pytest_configure(config: pytest.Config) -> None:
    if config.pluginmanager.hasplugin("xdist"):
        config.option.loadscopereorder = False  # the order below, not by count of tests


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: else as found
    for item in items:
        if item.path.name in AGAINST_THE_CLOCK:
            item.add_marker(pytest.mark.flaky(reruns=RERUNS))


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    """Before each test against the clock (and its fixtures, of any scope), the heap so
    far collected and frozen out of the collector's reach, as `sim serve` freezes its own.

    A simulated rig inside this process keeps real time only while no full collection
    stops its threads, and this process holds every module the tests import (numba,
    scipy, Textual, Dask) and every test's leftovers. Logged over one run of the tests
    against the clock: 14 full collections inside tests, of 0.22-0.58 s (one in a stuck
    valve's fault test), against the rig's 0.30 s feedback liveness limit and the fault
    tests' 0.30 s detection bounds; frozen before each, the longest 0.10 s (the
    objects a TUI test made itself), for 0.8 s of freezing in all.
    """
    if item.get_closest_marker("numeric") is None:
        gc.collect()
        gc.freeze()


def pytest_sessionstart(session: pytest.Session) -> None:
    """The integrator compiled (or loaded from numba's cache) once, before any test: on a
    cold cache each process a test starts (the simulated rig, the CLI) would compile it
    too, every one of them against its own start timeout."""
    warm_up()


@pytest.fixture(scope="session")
def average_model():
    return report_model("average")


@pytest.fixture(scope="session")
def run_a():
    return load_profile("A")


@pytest.fixture
def sim() -> Iterator[SimRig]:
    """The simulated rig (actuators, table, isolator, sensors) on the default config."""
    with SimRig(load_config()) as rig:
        yield rig


@pytest.fixture
def no_leaks() -> Iterator[None]:
    """Fails a test that leaves a thread running or a file descriptor open."""
    threads = set(threading.enumerate())
    fds = len(os.listdir("/proc/self/fd"))
    yield
    assert set(threading.enumerate()) <= threads
    assert len(os.listdir("/proc/self/fd")) == fds
