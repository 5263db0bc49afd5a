"""Reconstruction (eq. 3.12–3.14), its least-squares variant and the rational look-up table."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nail2nail.calibration.camera_models import Pinhole, dlt_from_pinhole, look_at, project_dlt
from nail2nail.scan.triangulation import (
    pixel_grid,
    reconstruct_points,
    reconstruct_points_lsq,
    triangulate,
    triangulation_table,
)


def rig(seed: int, azimuth: float | None = None):
    rng = np.random.default_rng(seed)
    a = rng.uniform(-0.8, 0.8) if azimuth is None else azimuth
    R, t = look_at(160 * np.array([np.sin(a), 0.0, np.cos(a)]), [0, 0, 0], [0, 1, 0])
    cam = dlt_from_pinhole(Pinhole(K=[[5000, 0, 512], [0, 5000, 640], [0, 0, 1]], R=R, t=t))
    R, t = look_at([0, -60 + rng.uniform(-10, 10), 200], [0, 0, 0], [0, 1, 0])
    proj = dlt_from_pinhole(Pinhole(K=[[2500, 0, 640], [0, 2500, 1000], [0, 0, 1]], R=R, t=t))
    return cam, proj


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), axis=st.sampled_from(["x", "y"]))
def test_reconstruction_inverts_projection(seed, axis):
    cam, proj = rig(seed)
    xyz = np.random.default_rng(seed).uniform(-10, 10, (50, 3))
    xc, yc = project_dlt(cam, xyz).T
    xp, yp = project_dlt(proj, xyz).T
    rec = reconstruct_points(cam, proj, xc, yc, yp if axis == "y" else xp, axis=axis)
    assert np.abs(rec - xyz).max() <= 1e-9 * np.abs(xyz).max() * 10
    rec2 = reconstruct_points_lsq(cam, proj, xc, yc, xp, yp)
    assert np.abs(rec2 - xyz).max() <= 1e-9 * np.abs(xyz).max() * 10


def test_any_shape_and_nan_passthrough_without_warnings():
    cam, proj = rig(0)
    xyz = np.random.default_rng(0).uniform(-10, 10, (2, 3, 4, 3))
    xc, yc = np.moveaxis(project_dlt(cam, xyz), -1, 0)
    xp, yp = np.moveaxis(project_dlt(proj, xyz), -1, 0)
    yp[0, 1, 2] = np.nan
    xp[1, 0, 0] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = reconstruct_points(cam, proj, xc, yc, yp)
        rec2 = reconstruct_points_lsq(cam, proj, xc, yc, xp, yp)
    assert rec.shape == (2, 3, 4, 3)
    assert np.isnan(rec[0, 1, 2]).all() and np.isnan(rec2[0, 1, 2]).all()
    assert np.isnan(rec2[1, 0, 0]).all() and np.isfinite(rec[1, 0, 0]).all()
    assert np.isfinite(rec).sum() == (24 - 1) * 3


def test_lsq_reduces_noise():
    """A side camera (45°) sees the projector's column planes at a good angle: xp helps."""
    cam, proj = rig(1, azimuth=np.pi / 4)
    rng = np.random.default_rng(2)
    xyz = rng.uniform(-10, 10, (4000, 3))
    xc, yc = project_dlt(cam, xyz).T
    xp, yp = (project_dlt(proj, xyz) + rng.normal(0, 0.3, (4000, 2))).T
    e1 = np.linalg.norm(reconstruct_points(cam, proj, xc, yc, yp) - xyz, axis=1)
    e2 = np.linalg.norm(
        reconstruct_points_lsq(cam, proj, xc, yc, xp, yp, camera_weight=1e3) - xyz, axis=1
    )
    assert np.median(e2) < 0.95 * np.median(e1)


@pytest.mark.parametrize("axis", ["x", "y"])
def test_table_matches_direct_reconstruction(axis):
    cam, proj = rig(3)
    H, W = 40, 30
    xc, yc = pixel_grid((H, W))
    p = np.random.default_rng(0).uniform(0, 1000, (H, W)).astype(np.float32)
    table = triangulation_table(cam, proj, (H, W), axis=axis)
    assert table.numerator.dtype == np.float32
    got = triangulate(table, p)
    want = reconstruct_points(cam, proj, xc, yc, p.astype(float), axis=axis)
    np.testing.assert_allclose(got, want, rtol=2e-5, atol=2e-5 * np.abs(want).max())


def test_bad_input_messages():
    cam, proj = rig(0)
    with pytest.raises(ValueError, match="camera_matrix"):
        reconstruct_points(cam[:2], proj, 1, 2, 3)
    with pytest.raises(ValueError, match="axis"):
        reconstruct_points(cam, proj, 1, 2, 3, axis="z")
    table = triangulation_table(cam, proj, (4, 5))
    with pytest.raises(ValueError, match=r"p: expected shape \(4, 5\)"):
        triangulate(table, np.zeros((5, 4)))
