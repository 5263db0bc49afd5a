"""Tests of nail2nail.unroll.accuracy: the similarity fit and the geometric accuracy of a print.

The print is made by :func:`unroll_scans` from three virtual pinhole views of an elliptic
cylinder (semi-axes 9 mm across, 7 mm towards the pad) carrying a 25 µm ridge relief along the
normal. The true skin coordinates of each camera pixel are exact: ``u`` the ellipse's arc length
from the pad's centre line (numerical integration), ``v`` the position along the axis.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import cumulative_trapezoid

sys.path.insert(0, str(Path(__file__).parent))
from _synthetic import camera_ring, make_projector

from nail2nail.scan.results import Scan
from nail2nail.unroll import unroll_scans
from nail2nail.unroll.accuracy import geometric_accuracy, similarity_fit

ELLIPSE_A, ELLIPSE_B = 9.0, 7.0  # mm, across (x) and towards the pad (z)
HALF_LENGTH = 12.0  # mm along the finger (y)
RELIEF_MM, RIDGE_MM = 0.025, 0.5


# -- synthetic scans of an elliptic cylinder -------------------------------------------------
def _arc_length():
    phi = np.linspace(-np.pi, np.pi, 200_001)
    length = cumulative_trapezoid(np.hypot(ELLIPSE_A * np.cos(phi), ELLIPSE_B * np.sin(phi)),
                                  phi, initial=0.0)
    length -= np.interp(0.0, phi, length)
    return lambda p: np.interp(p, phi, length)


def _relief(u, v):
    """Ridge relief (mm) at skin coordinates: oblique ridges of 0.5 mm period."""
    return RELIEF_MM * np.sin(2 * np.pi * (0.8 * u + 0.6 * v) / RIDGE_MM)


def elliptic_scan(camera, projector, name):
    """A :class:`Scan` of the elliptic cylinder with relief, and its true ``(u, v)``.

    Each pixel's ray is intersected with the base ellipse (analytically); the point is then
    moved along the normal by the relief at its skin coordinates (a first-order model of the
    ridges: the skin coordinates of the moved point are those of the base point).
    """
    width, height = camera.size
    rows, cols = np.mgrid[0:height, 0:width]
    o, d = camera.rays(np.stack([cols, rows], axis=-1).astype(float))
    ia, ib = 1 / ELLIPSE_A**2, 1 / ELLIPSE_B**2
    qa = d[..., 0] ** 2 * ia + d[..., 2] ** 2 * ib
    qb = 2 * (o[0] * d[..., 0] * ia + o[2] * d[..., 2] * ib)
    qc = o[0] ** 2 * ia + o[2] ** 2 * ib - 1
    disc = qb * qb - 4 * qa * qc
    with np.errstate(invalid="ignore"):
        t = (-qb - np.sqrt(disc)) / (2 * qa)
    base = o + t[..., None] * d
    normal = np.stack([base[..., 0] * ia, 0 * base[..., 1], base[..., 2] * ib], -1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    phi = np.arctan2(base[..., 0] / ELLIPSE_A, base[..., 2] / ELLIPSE_B)
    u, v = _arc_length()(phi), base[..., 1]
    xyz = base + _relief(u, v)[..., None] * normal
    to_cam = o - xyz
    to_cam /= np.linalg.norm(to_cam, axis=-1, keepdims=True)
    to_proj = projector.center - xyz
    to_proj /= np.linalg.norm(to_proj, axis=-1, keepdims=True)
    cos_c = np.einsum("...k,...k->...", normal, to_cam)
    cos_p = np.einsum("...k,...k->...", normal, to_proj)
    xy_p = projector.project(xyz)
    with np.errstate(invalid="ignore"):
        mask = (np.isfinite(xyz).all(-1) & (disc > 0) & (np.abs(v) <= HALF_LENGTH)
                & (cos_c > 0.2) & (cos_p > 0.1))
    xyz[~mask] = np.nan
    xy_p[~mask] = np.nan
    modulation = np.where(mask, 0.5 * np.clip(cos_p, 0, 1), 0).astype(np.float32)
    albedo = np.where(mask, 0.6 + 0.05 * _relief(u, v) / RELIEF_MM, 0).astype(np.float32)
    scan = Scan(name=name, xyz=xyz.astype(np.float32), xp=xy_p[..., 0].astype(np.float32),
                yp=xy_p[..., 1].astype(np.float32), albedo=albedo, intensity=modulation.copy(),
                modulation=modulation, mask=mask, camera_center=np.asarray(o, float))
    return scan, (np.where(mask, u, np.nan), np.where(mask, v, np.nan))


@pytest.fixture(scope="module")
def ellipse_scans():
    # 0.067 mm per camera pixel at the axis: denser than the 500-ppi print (0.0508 mm) after
    # the obliquity of the side views, as at the virtual scanner's full scale
    projector = make_projector()
    cams = camera_ring((-45.0, 0.0, 45.0), size=(360, 400), field_mm=24.0)
    out = [elliptic_scan(c, projector, f"cam{i}") for i, c in enumerate(cams)]
    return [s for s, _ in out], [uv for _, uv in out]


@pytest.fixture(scope="module")
def rolled_print(ellipse_scans):
    scans, _ = ellipse_scans
    return unroll_scans(scans, method="rolled")


@pytest.fixture(scope="module")
def rolled_accuracy(ellipse_scans, rolled_print):
    scans, truth = ellipse_scans
    return geometric_accuracy(rolled_print, scans, truth, maps=True)


# -- similarity_fit --------------------------------------------------------------------------
def _rotation(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s], [s, c]])


@settings(max_examples=50, deadline=None)
@given(scale=st.floats(0.2, 5.0), angle=st.floats(-np.pi + 1e-6, np.pi - 1e-6),
       shift=st.tuples(st.floats(-100, 100), st.floats(-100, 100)),
       seed=st.integers(0, 2**16))
def test_similarity_fit_recovers_a_similarity(scale, angle, shift, seed):
    src = np.random.default_rng(seed).uniform(-10, 10, (30, 2))
    dst = scale * src @ _rotation(angle).T + shift
    s, rot, t = similarity_fit(src, dst)
    assert isinstance(s, float) and rot.shape == (2, 2) and t.shape == (2,)
    assert s == pytest.approx(scale, rel=1e-9)
    np.testing.assert_allclose(rot, _rotation(angle), atol=1e-9)
    np.testing.assert_allclose(t, shift, atol=1e-7)


def _similarity_reference(src, dst):
    """Plain linear least squares for ``dst ≈ [[p, −q], [q, p]] src + t`` (a complex factor
    ``p + iq`` never reflects)."""
    n = len(src)
    A = np.zeros((2 * n, 4))
    A[0::2] = np.column_stack([src[:, 0], -src[:, 1], np.ones(n), np.zeros(n)])
    A[1::2] = np.column_stack([src[:, 1], src[:, 0], np.zeros(n), np.ones(n)])
    (p, q, tx, ty), *_ = np.linalg.lstsq(A, dst.ravel(), rcond=None)
    return float(np.hypot(p, q)), float(np.arctan2(q, p)), np.array([tx, ty])


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**16), noise=st.floats(0.0, 0.5))
def test_similarity_fit_agrees_with_plain_least_squares(seed, noise):
    rng = np.random.default_rng(seed)
    src = rng.uniform(-10, 10, (40, 2))
    dst = 1.3 * src @ _rotation(0.4).T + [2.0, -1.0] + noise * rng.standard_normal((40, 2))
    s, rot, t = similarity_fit(src, dst)
    s_ref, a_ref, t_ref = _similarity_reference(src, dst)
    assert s == pytest.approx(s_ref, rel=1e-9)
    assert np.arctan2(rot[1, 0], rot[0, 0]) == pytest.approx(a_ref, abs=1e-9)
    np.testing.assert_allclose(t, t_ref, atol=1e-8)


@pytest.mark.parametrize("mirror", [np.diag([-1.0, 1.0]), np.diag([1.0, -1.0])])
def test_similarity_fit_never_reflects(mirror):
    src = np.random.default_rng(1).uniform(-10, 10, (50, 2))
    dst = 2.0 * src @ mirror.T + [1.0, 3.0]
    s, rot, t = similarity_fit(src, dst)
    assert np.linalg.det(rot) == pytest.approx(1.0)
    np.testing.assert_allclose(rot @ rot.T, np.eye(2), atol=1e-12)
    # the mirror cannot be explained: a large residual remains
    resid = np.linalg.norm(dst - (s * src @ rot.T + t), axis=1)
    assert np.median(resid) > 1.0
    s_ref, a_ref, _ = _similarity_reference(src, dst)
    assert s == pytest.approx(s_ref, abs=1e-9)
    assert np.arctan2(rot[1, 0], rot[0, 0]) == pytest.approx(a_ref, abs=1e-9)


# -- geometric_accuracy on the elliptic cylinder ---------------------------------------------
def test_geometric_accuracy_output(rolled_accuracy, rolled_print):
    acc = rolled_accuracy
    assert acc["pixels"] > 100_000
    assert acc["similarity"]["reflected"] is False
    for key in ("scale_error", "displacement_mm"):
        assert set(acc[key]) == {"median", "p95", "max"}
        assert 0 <= acc[key]["median"] <= acc[key]["p95"] <= acc[key]["max"]
    assert acc["scale_error_blocks"] > 200  # 1 mm blocks over ≈ 600 mm² of skin
    shape = rolled_print.grid.shape
    assert acc["scale_error_map"].shape == shape and acc["displacement_map"].dtype == np.float32
    assert np.isnan(acc["displacement_map"][~rolled_print.mask]).all()


def test_geometric_accuracy_rolled_on_ellipse(rolled_accuracy):
    acc = rolled_accuracy
    assert acc["similarity"]["scale"] == pytest.approx(1.0, abs=0.005)
    assert abs(acc["similarity"]["rotation_deg"]) < 0.5
    assert acc["scale_error"]["p95"] < 0.015, acc["scale_error"]
    assert acc["displacement_mm"]["p95"] < 0.1, acc["displacement_mm"]


def test_geometric_accuracy_sees_the_cylinder_maps_stretch(ellipse_scans, rolled_accuracy):
    # the contrast: the circular cylinder map stretches the elliptic section by 3.4 % more at
    # the sides than on the pad (tests/test_unroll_flatten.py): about ±1 % about the mean scale
    # the similarity takes (measured: p95 0.99 %, displacement p95 0.028 mm; the rolled map
    # 0.085 % and 0.0035 mm). The metric must see it
    scans, truth = ellipse_scans
    cyl = geometric_accuracy(unroll_scans(scans, method="cylinder"), scans, truth)
    assert cyl["scale_error"]["p95"] > 0.006
    assert cyl["scale_error"]["p95"] > 5 * rolled_accuracy["scale_error"]["p95"]
    assert cyl["displacement_mm"]["p95"] > 3 * rolled_accuracy["displacement_mm"]["p95"]


def test_geometric_accuracy_known_anisotropic_stretch(ellipse_scans, rolled_print,
                                                      rolled_accuracy):
    # truth stretched by 3 % around the finger: the similarity takes the mean scale (≈ 1.015),
    # the local scale error is what remains, ≈ 1.5 % everywhere
    scans, truth = ellipse_scans
    stretched = [(1.03 * u, v) for u, v in truth]
    acc = geometric_accuracy(rolled_print, scans, stretched)
    assert acc["similarity"]["scale"] == pytest.approx(1.015, abs=0.003)
    assert acc["scale_error"]["median"] == pytest.approx(0.015, abs=0.003)


def test_geometric_accuracy_ignores_a_rigid_motion_of_the_truth(ellipse_scans, rolled_print,
                                                                 rolled_accuracy):
    scans, truth = ellipse_scans
    rot = _rotation(np.radians(10.0))
    moved = []
    for u, v in truth:
        uv = np.stack([u, v], -1) @ rot.T + [0.7, -1.2]
        moved.append((uv[..., 0], uv[..., 1]))
    acc = geometric_accuracy(rolled_print, scans, moved)
    assert acc["similarity"]["rotation_deg"] == pytest.approx(
        rolled_accuracy["similarity"]["rotation_deg"] + 10.0, abs=1e-3)
    for key in ("scale_error", "displacement_mm"):
        for stat in ("median", "p95"):
            assert acc[key][stat] == pytest.approx(rolled_accuracy[key][stat], abs=2e-4)


def test_geometric_accuracy_mismatched_truth(ellipse_scans, rolled_print):
    scans, truth = ellipse_scans
    with pytest.raises(ValueError):
        geometric_accuracy(rolled_print, scans, truth[:2])
