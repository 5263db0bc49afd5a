"""Calibration (eq. 3.1–3.11) against the thesis's Tables 2 and 3 and synthetic cameras."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import PACKAGE_DATA, SHARED_DATA, skip_unless_ci, thesis_table_path
from hypothesis import given, settings
from hypothesis import strategies as st

from nail2nail.calibration.camera_models import Pinhole, dlt_from_pinhole, look_at, project_dlt
from nail2nail.calibration.dlt import (
    calibrate_points,
    crosscheck,
    fit_projection_matrix,
    reprojection_errors,
)
from nail2nail.io.points import read_points

ERR_COLUMNS = ("err_Xw", "err_Yw", "err_Zw")


@pytest.mark.parametrize("camera", [0, 1])
def test_thesis_tables_reproduce_published_errors(camera):
    """Issue 2: with --use yp every point's error matches the thesis within 0.03 mm."""
    table = read_points(thesis_table_path(camera))
    report = calibrate_points(table.xyz_world, table.xy_camera, table.xy_projector, use="yp")
    published = np.column_stack([table.columns[c] for c in ERR_COLUMNS])
    assert np.abs(report.error_mm - published).max() < 0.03


@pytest.mark.parametrize("method", ["thesis", "normalized"])
def test_both_methods_give_similar_errors_on_thesis_tables(method):
    table = read_points(thesis_table_path(0))
    report = calibrate_points(table.xyz_world, table.xy_camera, table.xy_projector, method=method)
    assert np.all(report.rms_mm < 0.06)
    assert np.sqrt(np.mean(report.camera_residual_px**2)) < 2.0


def test_crosscheck_thesis_tables():
    """Issue 2 / Figure 22: 24 common points; squared distance < 0.05 mm² with yp;
    Euclidean median ≤ 0.06 mm with xp and yp."""
    a, b = read_points(thesis_table_path(0)), read_points(thesis_table_path(1))
    out = {}
    for use in ("yp", "xpyp"):
        ra = calibrate_points(a.xyz_world, a.xy_camera, a.xy_projector, use=use)
        rb = calibrate_points(b.xyz_world, b.xy_camera, b.xy_projector, use=use)
        out[use] = crosscheck(ra, a.xyz_world, rb, b.xyz_world)
    assert out["yp"].distance_mm.size == 24
    assert out["yp"].squared_mm2.max() < 0.05
    assert np.median(out["yp"].distance_mm) == pytest.approx(0.091, abs=0.005)
    assert np.median(out["xpyp"].distance_mm) <= 0.06


def test_package_tables_match_shared():
    if not SHARED_DATA.exists():
        skip_unless_ci("../shared is not beside this checkout")
    for name in ("thesis_table2_camera0.tsv", "thesis_table3_camera1.tsv"):
        assert (PACKAGE_DATA / name).read_text() == (SHARED_DATA / name).read_text()


def random_camera(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    azimuth = rng.uniform(-np.pi / 3, np.pi / 3)
    eye = 150 * np.array([np.sin(azimuth), rng.uniform(-0.3, 0.3), np.cos(azimuth)])
    R, t = look_at(eye, rng.uniform(-2, 2, 3), [0, 1, 0])
    f = rng.uniform(2000, 6000)
    K = np.array([[f, rng.uniform(-2, 2), rng.uniform(400, 600)],
                  [0, f * rng.uniform(0.95, 1.05), rng.uniform(500, 700)], [0, 0, 1]])
    return dlt_from_pinhole(Pinhole(K=K, R=R, t=t))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), method=st.sampled_from(["thesis", "normalized"]))
def test_fit_recovers_random_camera(seed, method):
    M = random_camera(seed)
    rng = np.random.default_rng(seed + 1)
    xyz = rng.uniform([-10, -15, -10], [10, 15, 10], (30, 3))
    fitted = fit_projection_matrix(xyz, project_dlt(M, xyz), method=method)
    scale = np.abs(M).max()
    assert np.abs(fitted - M).max() / scale < 1e-7
    assert np.abs(reprojection_errors(fitted, xyz, project_dlt(M, xyz))).max() < 1e-6


def test_normalized_is_better_conditioned_under_noise():
    M = random_camera(3)
    rng = np.random.default_rng(4)
    xyz = rng.uniform([-10, -15, -10], [10, 15, 10], (60, 3))
    xy = project_dlt(M, xyz) + rng.normal(0, 0.2, (60, 2))
    for method in ("thesis", "normalized"):
        fitted = fit_projection_matrix(xyz, xy, method=method)
        res = reprojection_errors(fitted, xyz, xy)
        assert np.sqrt(np.mean(res**2)) < 0.25  # at the noise level


@pytest.mark.parametrize(
    ("xyz", "message"),
    [
        (np.zeros((5, 3)), "at least 6"),
        (np.c_[np.arange(8.0), np.arange(8.0), np.arange(8.0)], "collinear"),
        (np.c_[np.random.default_rng(0).uniform(size=(8, 2)), np.zeros(8)], "coplanar"),
        (np.r_[np.full((1, 3), np.nan), np.random.default_rng(0).uniform(size=(7, 3))], "NaN"),
    ],
)
def test_degenerate_input_is_refused(xyz, message):
    xy = np.random.default_rng(1).uniform(size=(xyz.shape[0], 2))
    with pytest.raises(ValueError, match=message):
        fit_projection_matrix(xyz, xy)


def test_bad_arguments():
    xyz = np.random.default_rng(0).uniform(size=(8, 3))
    with pytest.raises(ValueError, match="method"):
        fit_projection_matrix(xyz, xyz[:, :2], method="magic")
    with pytest.raises(ValueError, match=r"shape \(N, 2\)"):
        fit_projection_matrix(xyz, xyz)
    with pytest.raises(ValueError, match="8 world points but 7"):
        fit_projection_matrix(xyz, xyz[:7, :2])
