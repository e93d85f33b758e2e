"""Shared fixtures: the real data folder, free loopback ports, small recordings."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DATA = Path(os.environ.get("GFLOW_DATA", ROOT.parent / "shared" / "data"))


def data_dir(name: str) -> Path:
    """A sequence folder of ../shared/data, or skip the test saying why."""
    p = DATA / name
    if not p.is_dir():
        pytest.skip(f"real data not available: {p} is missing (tests look for ../shared/data beside the repo, "
                    f"or set GFLOW_DATA)")
    return p


@pytest.fixture
def crossing() -> Path:
    return data_dir("crossing")


@pytest.fixture
def caviar1() -> Path:
    return data_dir("caviar1")


@pytest.fixture
def gflow_cmd() -> list[str]:
    """The gflow command as the user runs it (the console script), falling back to python -m."""
    return [sys.executable, "-m", "pipeline.cli"]
