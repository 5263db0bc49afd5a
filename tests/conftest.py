"""Shared fixtures. Tests read ../shared (the thesis tables) but never write there."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
PACKAGE_DATA = REPO / "src" / "nail2nail" / "data"

#: CI sets NAIL2NAIL_CI=1 (.ci/run): there a test that cannot run (../shared not beside the
#: checkout, no headless browser) fails instead of skipping.
CI = os.environ.get("NAIL2NAIL_CI", "") not in ("", "0")


def skip_unless_ci(reason: str) -> None:
    """Skip the calling test for `reason`, or fail it under CI (:data:`CI`)."""
    if CI:
        pytest.fail(f"{reason} (NAIL2NAIL_CI is set: CI must run this test)")
    pytest.skip(reason)


def pytest_sessionstart(session) -> None:
    """Under CI, ../shared must be beside the checkout: the thesis tables are read from it."""
    if CI and not SHARED_DATA.is_dir():
        raise pytest.UsageError(f"NAIL2NAIL_CI is set but {SHARED_DATA} is missing")


@pytest.fixture(scope="session", autouse=True)
def _shared_prints(tmp_path_factory):
    """The virtual fingers' synthetic prints, grown once per test run rather than once per
    test process (about 10 s each): kept in the run's temporary directory, which every xdist
    worker shares (``$NAIL2NAIL_FINGERPRINT_CACHE``, ``simulation.scenes``). Left alone when
    the caller set it."""
    from nail2nail.simulation.scenes import PRINT_CACHE_ENV

    if os.environ.get(PRINT_CACHE_ENV):
        yield
        return
    base = tmp_path_factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    os.environ[PRINT_CACHE_ENV] = str(root / "synthetic-prints")
    try:
        yield
    finally:
        os.environ.pop(PRINT_CACHE_ENV, None)


def thesis_table_path(camera: int) -> Path:
    """Path of the thesis table for `camera` in ../shared/data (the package copy if absent)."""
    name = {0: "thesis_table2_camera0.tsv", 1: "thesis_table3_camera1.tsv"}[camera]
    shared = SHARED_DATA / name
    return shared if shared.exists() else PACKAGE_DATA / name


@pytest.fixture
def table_paths() -> tuple[Path, Path]:
    return thesis_table_path(0), thesis_table_path(1)


@pytest.fixture(scope="session")
def processed_finger(tmp_path_factory) -> Path:
    """``process --figures --report`` of a small virtual finger (scale 0.25, its ideal
    calibration, the thesis's projector distortion): the output directory, with its
    report.html, for the report's tests. The capture and calibration stay where process.json
    names them. Read only: a test that changes it works on a copy."""
    from nail2nail.cli import main

    root = tmp_path_factory.mktemp("processed_finger")
    capture, out = root / "capture", root / "out"
    assert main(["-q", "simulate", "--scene", "finger", "--scale", "0.25", "--out",
                 str(capture)]) == 0
    calib = capture / "truth" / "calibration.json"
    assert main(["-q", "process", str(capture), "--calib", str(calib), "--out", str(out),
                 "--figures", "--report"]) == 0
    return out
