"""Who may run beside whom under pytest-xdist (pyproject addopts: `-n auto`).

Most of the suite's time is numeric (identification, the loop): each test one process on
one core, timing nothing, so two of them run side by side on two cores. The rest runs the
simulated rig, a terminal or a Dask cluster against the clock, where a neighbour's load
shows up as a late frame or a tripped watchdog: those hold the machine alone.

A test that runs alone also runs with the suite's heap out of the garbage collector's
way: the rig and the simulated rig run in this process, and a full collection over
what hundreds of tests left behind stops every thread for tenths of a second (an
actuator's feedback "silent for 0.65 s" in an e-stop test). `gc.freeze` moves what is
alive when the hold starts to a generation no collection walks.

A module opts in to sharing with `pytestmark = pytest.mark.shares_cpu`; anything else
runs alone (the safe default for a new test). Two `flock`s across the workers: a shared
or exclusive hold on the machine, behind a turnstile that a test waiting to run alone
takes first, so a stream of shared tests cannot keep it waiting.
"""

from __future__ import annotations

import fcntl
import gc
import os
import tempfile
from pathlib import Path
from typing import IO

import pytest


def _shares_cpu(item: pytest.Item | None) -> bool:
    return item is not None and item.get_closest_marker("shares_cpu") is not None


class MachineShare:
    """This worker's hold on the machine: none, shared or alone."""

    def __init__(self, directory: Path) -> None:
        directory.mkdir(exist_ok=True)
        self._turnstile: IO[str] = open(directory / "turnstile", "a")  # held for the session
        self._machine: IO[str] = open(directory / "machine", "a")
        self.held: str | None = None

    def hold(self, alone: bool) -> None:
        want = "alone" if alone else "shared"
        if self.held == want:
            return
        self.release()
        fcntl.flock(self._turnstile, fcntl.LOCK_EX)
        fcntl.flock(self._machine, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        if not alone:
            fcntl.flock(self._turnstile, fcntl.LOCK_UN)
        self.held = want

    def release(self) -> None:
        if self.held is None:
            return
        fcntl.flock(self._machine, fcntl.LOCK_UN)
        if self.held == "alone":
            fcntl.flock(self._turnstile, fcntl.LOCK_UN)
        self.held = None


_share: MachineShare | None = None
_frozen = False  # this process's heap is out of the collector's way


def machine_share() -> MachineShare | None:
    """The worker's share, or None outside pytest-xdist (one process: nothing to share)."""
    global _share
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID")
    if run is None:
        return None
    if _share is None:
        _share = MachineShare(Path(tempfile.gettempdir()) / f"pytest-machine-{run}")
    return _share


def around_test(item: pytest.Item, nextitem: pytest.Item | None):
    """Hold the machine as the test needs for its setup, call and teardown. A test that
    runs alone keeps the machine (and the heap frozen) while the next test on this
    worker also runs alone: a module's fixtures (a campaign on the simulated rig) live
    from one test to the next."""
    global _frozen
    alone = not _shares_cpu(item)
    share = machine_share()
    if share is not None:
        share.hold(alone)
    if alone and not _frozen:
        gc.collect()
        gc.freeze()
        _frozen = True
    try:
        yield
    finally:
        if not (alone and nextitem is not None and not _shares_cpu(nextitem)):
            if _frozen:
                gc.unfreeze()
                _frozen = False
            if share is not None:
                share.release()
