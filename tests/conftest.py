"""Shared pytest fixtures."""

from __future__ import annotations

from pathlib import Path

import pytest

# ../shared next to the checkout: the benchmark shapes and official SweepNet parameters.
SHARED = Path(__file__).resolve().parents[1].parent / "shared"
SHAPES = SHARED / "shapes"


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """The shared data folder; tests that need it skip when it is absent."""
    if not SHARED.is_dir():
        pytest.skip(f"shared data folder {SHARED} is absent")
    return SHARED


@pytest.fixture(scope="session")
def shapes_dir(shared_dir: Path) -> Path:
    """The folder of the 30 benchmark shapes (with manifest.json)."""
    if not SHAPES.is_dir():
        pytest.skip(f"shared shapes folder {SHAPES} is absent")
    return SHAPES
