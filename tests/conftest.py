"""Shared fixtures: the location of ../shared/data (real data sets); matplotlib headless, and every
test's figures closed after it."""

import os
import sys
from pathlib import Path

os.environ.setdefault("MPLBACKEND", "Agg")

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _shared_data() -> Path:
    env = os.environ.get("BAARDA_SHARED_DATA")
    candidates = [Path(env)] if env else []
    candidates += [ROOT.parent / "shared" / "data", Path("/work/shared/data")]
    for c in candidates:
        if c.is_dir():
            return c
    return candidates[0]


@pytest.fixture(scope="session")
def shared_data() -> Path:
    p = _shared_data()
    if not p.is_dir():
        pytest.skip(f"shared data folder not found (looked at {p}); set BAARDA_SHARED_DATA")
    return p


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return ROOT


@pytest.fixture(autouse=True)
def _close_figures():
    """Figures a test drew (report hooks, figure modules) are closed after it, so none accumulate."""
    yield
    if "matplotlib.pyplot" in sys.modules:
        sys.modules["matplotlib.pyplot"].close("all")


SHARED_BESIDE = ROOT.parent / "shared" / "data"
"""Where the bundled projects (fixtures/) read real data from: paths like ``../../../shared/data/…``
relative to the project file, i.e. ``shared/data`` beside the repository (as in CI)."""


def needs_shared_beside(project: Path) -> bool:
    """The project names ``shared/data`` and the folder beside the repository is absent."""
    return "shared/data" in project.read_text() and not SHARED_BESIDE.is_dir()


@pytest.fixture(scope="session")
def shared_beside() -> Path:
    """``shared/data`` beside the repository, where the bundled projects read real data (skip when
    absent: ``shared_data`` may find another copy, but the projects' relative paths would not)."""
    if not SHARED_BESIDE.is_dir():
        pytest.skip(f"the bundled projects read ../shared/data beside the repository ({SHARED_BESIDE}), absent here")
    return SHARED_BESIDE
