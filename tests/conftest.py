"""Shared fixtures. Tests read ../shared (the thesis tables) but never write there."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
PACKAGE_DATA = REPO / "src" / "nail2nail" / "data"


def thesis_table_path(camera: int) -> Path:
    """Path of the thesis table for `camera` in ../shared/data (the package copy if absent)."""
    name = {0: "thesis_table2_camera0.tsv", 1: "thesis_table3_camera1.tsv"}[camera]
    shared = SHARED_DATA / name
    return shared if shared.exists() else PACKAGE_DATA / name


@pytest.fixture
def table_paths() -> tuple[Path, Path]:
    return thesis_table_path(0), thesis_table_path(1)
