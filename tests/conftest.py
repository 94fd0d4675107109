"""Shared fixtures: the report's model and profiles; a check that nothing leaks."""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator

import pytest

from analysis.model.report_constants import report_model
from rig.profile import load_profile


@pytest.fixture(scope="session")
def average_model():
    return report_model("average")


@pytest.fixture(scope="session")
def run_a():
    return load_profile("A")


@pytest.fixture
def no_leaks() -> Iterator[None]:
    """Fails a test that leaves a thread running or a file descriptor open."""
    threads = set(threading.enumerate())
    fds = len(os.listdir("/proc/self/fd"))
    yield
    assert set(threading.enumerate()) <= threads
    assert len(os.listdir("/proc/self/fd")) == fds
