"""Shared fixtures: the report's model and profiles."""

from __future__ import annotations

import pytest

from analysis.model.report_constants import report_model
from rig.profile import load_profile


@pytest.fixture(scope="session")
def average_model():
    return report_model("average")


@pytest.fixture(scope="session")
def run_a():
    return load_profile("A")
