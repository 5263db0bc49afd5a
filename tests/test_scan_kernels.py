"""Issue 11: ``nail2nail scan`` runs the fused numba kernel for every option; it agrees with the
NumPy reference (``method="numpy"``: :func:`nail2nail.scan.decoding.decode` and the float64
:func:`nail2nail.scan.triangulation.reconstruct_image`) on virtual captures.

Acceptance, for every option combination (both projector directions or one, the projector
distortion model on and off, pinhole lens distortion of camera and projector, the steep-pixel
check on and off, other decode options, 8-, 12- and 16-bit frames):

* the mask is the same but for at most :data:`MASK_PIXELS` pixels (measured: 0 in every case;
  only a value within rounding of a threshold could differ);
* ``xp``, ``yp`` within 1e-4 px: both are rounded to float32 once from nearly the same value
  (the kernel's arctangent is exact to 1.5e-7 rad), so they differ by at most one float32 step,
  6.1e-5 px below 1024 px (1.2e-4 px above, where the stored value's own resolution is coarser
  than 1e-4 px);
* ``xyz`` within 1e-4 mm of the reference's triangulation of the same float32 coordinates, and
  of the reference scan itself for ``use="xpyp"`` and ``"yp"`` (measured 6.2e-6 mm). With
  ``use="xp"`` the virtual rig's column planes nearly contain the camera rays (the projector sits
  above the cameras): a point moves by up to 46 mm per projector px there, so the one-step
  difference of the decoded ``xp`` moves it by up to 0.02 mm, as the float32 rounding of ``xp``
  moves the reference's own points.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nail2nail.calibration.camera_models import Pinhole, dlt_from_pinhole, look_at, project_dlt
from nail2nail.calibration.distortion import ideal_from_panel, panel_from_ideal
from nail2nail.calibration.files import RigCalibration
from nail2nail.io.capture import read_capture
from nail2nail.scan.capture import gradient_limit, scan_capture, scan_frames
from nail2nail.scan.kernels import decode_fast
from nail2nail.scan.results import NO_POINT
from nail2nail.scan.triangulation import (
    RayTable,
    ray_table,
    reconstruct_image,
    reconstruct_points,
    reconstruct_points_lsq,
    reconstruct_points_ray,
    undistorted_pixels,
)
from nail2nail.simulation.capture import simulate, simulate_capture
from nail2nail.simulation.rig import Photometry, default_rig, ideal_calibration

SCALE = 0.25  # 256 x 320 cameras

#: Pixels whose validity may differ between the kernel and the reference (a value within
#: rounding of a threshold); measured: none.
MASK_PIXELS = 3

#: Lens distortion of the lens rig's cameras and projector (OpenCV k1, k2, p1, p2, k3).
CAMERA_LENS = (-0.3, 0.2, 0.001, -0.002, 0.05)
PROJECTOR_LENS = (-0.1, 0.05, 0.0005, 0.001, 0.0)


def render(rig, camera: int = 1):
    """One camera's frames of the virtual finger, the pattern set and the ideal calibration."""
    sim = simulate("finger", rig=rig, seed=3, cameras=[camera])
    name = rig.camera_names[camera]
    calibration = RigCalibration.from_dict(ideal_calibration(rig))
    return sim.frames[name], sim.pattern_set, calibration.camera(name), rig.projector_distortion


@pytest.fixture(scope="module")
def finger():
    """8-bit frames; the rig has the thesis's projector distortion."""
    return render(default_rig(SCALE))


@pytest.fixture(scope="module")
def lens():
    """8-bit frames of a rig whose cameras and projector have lens distortion."""
    rig = default_rig(SCALE, camera_distortion=CAMERA_LENS)
    p = rig.projector
    rig.projector = Pinhole(K=p.K, R=p.R, t=p.t, dist=np.array(PROJECTOR_LENS), size=p.size)
    return render(rig)


@pytest.fixture(scope="module")
def finger16():
    """16-bit frames."""
    return render(default_rig(SCALE, photometry=Photometry(bit_depth=16)))


def assert_scans_agree(fast, ref, camera, *, use: str, projector_distortion):
    """The acceptance of the module docstring; returns the deviations."""
    assert fast.name == ref.name and fast.shape == ref.shape
    for key in ("xyz", "xp", "yp", "albedo", "intensity", "modulation"):
        assert getattr(fast, key).dtype == np.float32, key
    assert fast.mask.dtype == bool
    differ = int(np.count_nonzero(fast.mask != ref.mask))
    assert differ <= MASK_PIXELS, differ
    assert ref.mask.sum() > 10000
    # invalid pixels: NaN coordinates and points, no intensity
    invalid = ~fast.mask
    assert np.isnan(fast.xyz[invalid]).all() and np.isnan(fast.xp[invalid]).all()
    assert np.isnan(fast.yp[invalid]).all() and not fast.intensity[invalid].any()
    assert np.isfinite(fast.xyz[fast.mask]).all()
    both = fast.mask & ref.mask
    dev = {}
    for key in ("xp", "yp"):
        got, want = getattr(fast, key)[both], getattr(ref, key)[both]
        np.testing.assert_array_equal(np.isnan(got), np.isnan(want))  # a direction not decoded
        got, want = got[np.isfinite(want)], want[np.isfinite(want)]
        step = np.spacing(np.abs(want))  # one float32 step of the stored value
        dev[key] = float(np.abs(got - want).max(initial=0))
        assert np.all(np.abs(got - want) <= np.maximum(1e-4, step)), key
        assert np.all(np.abs(got - want)[np.abs(want) < 1024] <= 1e-4), key
    # triangulation of the same float32 coordinates: the reference's float64 within 1e-4 mm
    same = reconstruct_image(camera.camera, camera.projector, fast.xp, fast.yp,
                             projector_distortion=projector_distortion, use=use)
    dev["xyz_same_input"] = float(np.abs(fast.xyz[fast.mask] - same[fast.mask]).max())
    assert dev["xyz_same_input"] <= 1e-4
    dev["xyz"] = float(np.abs(fast.xyz[both] - ref.xyz[both]).max())
    assert dev["xyz"] <= (1e-4 if use != "xp" else 0.05)  # xp: see the module docstring
    for key, atol in (("albedo", 1e-6), ("modulation", 1e-6), ("intensity", 2e-6)):
        np.testing.assert_allclose(getattr(fast, key), getattr(ref, key), rtol=0, atol=atol,
                                   err_msg=key)
    np.testing.assert_array_equal(fast.camera_center, ref.camera_center)
    return dev


def check_scan(frames, pattern_set, camera, projector_distortion, *, use="xpyp", **options):
    """The fast scan against the reference, asserted; returns the fast scan."""
    ref = scan_frames(frames, pattern_set, camera, projector_distortion=projector_distortion,
                      use=use, method="numpy", **options)
    fast = scan_frames(frames, pattern_set, camera, projector_distortion=projector_distortion,
                       use=use, **options)
    assert_scans_agree(fast, ref, camera, use=use, projector_distortion=projector_distortion)
    return fast


@pytest.mark.parametrize("use", ["xpyp", "yp", "xp"])
@pytest.mark.parametrize("steep", [True, False])
@pytest.mark.parametrize("model", [True, False])
def test_fast_scan_matches_reference(finger, use, steep, model):
    frames, pattern_set, camera, distortion = finger
    max_gradient = gradient_limit(2.0, frames.shape) if steep else None
    check_scan(frames, pattern_set, camera, distortion if model else None, use=use,
               max_gradient=max_gradient)


@pytest.mark.parametrize("options", [
    {"erode": 0},
    {"erode": 2, "max_gradient": 8.0},
    {"erode": 1, "max_gradient": 5.0},  # many steep pixels
    {"min_modulation": 0.1, "saturation": 0.9, "unwrap_tolerance": 1.0, "min_albedo": 0.1},
])
def test_fast_scan_decode_options(finger, options):
    frames, pattern_set, camera, distortion = finger
    check_scan(frames, pattern_set, camera, distortion, **options)


@pytest.mark.parametrize("use", ["xpyp", "yp", "xp"])
def test_fast_scan_lens_distortion(lens, use):
    """Pinhole camera and projector with OpenCV distortion, and the distortion model."""
    frames, pattern_set, camera, distortion = lens
    assert np.any(camera.camera.dist) and np.any(camera.projector.dist)
    check_scan(frames, pattern_set, camera, distortion, use=use,
               max_gradient=gradient_limit(2.0, frames.shape))
    table = ray_table(camera.camera, camera.projector, frames.shape[1:],
                      projector_distortion=distortion, use=use)
    again = ray_table(camera.camera, camera.projector, frames.shape[1:], use=use)
    assert table.pixel_offsets is again.pixel_offsets  # once per camera model and size
    assert table.pixel_offsets.shape == (2, *frames.shape[1:])


def test_fast_scan_16bit(finger16):
    frames, pattern_set, camera, distortion = finger16
    assert frames.dtype == np.uint16 and frames.max() > 255
    check_scan(frames, pattern_set, camera, distortion,
               max_gradient=gradient_limit(2.0, frames.shape))


@pytest.mark.parametrize("bit_depth", [8, 12])
def test_fast_scan_capture_raw_frames(tmp_path, bit_depth):
    """scan_capture decodes the raw integer frames (right-aligned 12-bit values: full scale
    4095) as the reference decodes their floats."""
    rig = default_rig(0.125, photometry=Photometry(bit_depth=bit_depth))
    simulate_capture(tmp_path / "cap", "finger", rig=rig, seed=1, write_truth=False)
    calibration = RigCalibration.from_dict(ideal_calibration(rig))
    capture = read_capture(tmp_path / "cap", load=False)
    fast = scan_capture(capture, calibration)
    ref = scan_capture(capture, calibration, method="numpy")
    assert capture.frames == {}
    for f, r in zip(fast, ref, strict=True):
        differ = int(np.count_nonzero(f.mask != r.mask))
        assert differ <= MASK_PIXELS and r.mask.sum() > 2000, differ
        both = f.mask & r.mask
        assert np.abs(f.xp - r.xp)[both].max() <= 1e-4
        assert np.abs(f.yp - r.yp)[both].max() <= 1e-4
        assert np.abs(f.xyz - r.xyz)[both].max() <= 1e-4
        np.testing.assert_allclose(f.albedo, r.albedo, rtol=0, atol=1e-6)


def test_fast_scan_one_projector_direction(finger):
    """A pattern set of rows only: ``use="yp"`` triangulates, with a projector distortion
    model too (issue 12: on the camera ray, tests/test_scan_one_direction.py); ``xp`` is NaN;
    ``use="xpyp"`` and ``use="xp"`` are refused with the reference's message."""
    frames, pattern_set, camera, distortion = finger
    assert pattern_set.directions == ("x", "y")  # frames: the columns', then the rows'
    rows = dataclasses.replace(pattern_set, x=(), directions=())
    y_frames = frames[pattern_set.n_frames - rows.n_frames:]
    fast = check_scan(y_frames, rows, camera, None, use="yp")
    assert np.isnan(fast.xp).all()
    scans = [scan_frames(y_frames, rows, camera, method=method, use="yp",
                         projector_distortion=distortion) for method in ("numba", "numpy")]
    assert np.array_equal(scans[0].mask, scans[1].mask) and scans[0].mask.sum() > 2000
    both = scans[0].mask
    assert np.abs(scans[0].xyz - scans[1].xyz)[both].max() <= 1e-4
    for method in ("numba", "numpy"):
        with pytest.raises(ValueError, match="the pattern set has one projector direction"):
            scan_frames(y_frames, rows, camera, method=method, use="xpyp")
        with pytest.raises(ValueError, match="use='xp', but the pattern set decodes only 'y'"):
            scan_frames(y_frames, rows, camera, use="xp", method=method)


@pytest.mark.parametrize(("options", "why"), [
    ({"min_modulation": 2.0}, "no pixel has a fringe amplitude ≥ min_modulation 2"),
    ({"min_albedo": 2.0}, r"none of its \d+ lit pixels decoded validly"),
])
def test_fast_scan_errors_are_the_reference_errors(finger, options, why):
    frames, pattern_set, camera, _ = finger
    messages = []
    for method in ("numba", "numpy"):
        with pytest.raises(ValueError, match=why) as info:
            scan_frames(frames, pattern_set, camera, method=method, **options)
        messages.append(str(info.value))
    assert messages[0] == messages[1]
    assert messages[0].startswith("camera 'cam1': the scan keeps 0 valid pixels")


def test_bad_method_and_use(finger):
    frames, pattern_set, camera, _ = finger
    with pytest.raises(ValueError, match="method: expected 'numba' or 'numpy', got 'gpu'"):
        scan_frames(frames, pattern_set, camera, method="gpu")
    for method in ("numba", "numpy"):
        with pytest.raises(ValueError, match="use: expected 'xpyp', 'yp' or 'xp', got 'z'"):
            scan_frames(frames, pattern_set, camera, use="z", method=method)
    with pytest.raises(ValueError, match="table: expected a table for images of shape"):
        decode_fast(frames, pattern_set,
                    table=ray_table(camera.camera, camera.projector, (10, 10)))


def test_decode_fast_with_a_ray_table_flags_no_point(finger):
    """decode_fast(table=RayTable): mask = reason == 0, NO_POINT where the point is not finite
    (here: every pixel, the camera matrix being singular)."""
    frames, pattern_set, camera, distortion = finger
    table = ray_table(camera.camera, camera.projector, frames.shape[1:],
                      projector_distortion=distortion)
    decoded = decode_fast(frames, pattern_set, table=table, max_gradient=8.0)
    np.testing.assert_array_equal(decoded.mask, decoded.reason == 0)
    assert not np.any(decoded.reason & NO_POINT)
    broken = dataclasses.replace(table, camera_inverse=np.full((3, 3), np.nan))
    decoded = decode_fast(frames, pattern_set, table=broken, max_gradient=8.0)
    assert not decoded.mask.any() and np.isnan(decoded.xyz).all()
    assert np.count_nonzero(decoded.reason == NO_POINT) > 10000
    assert isinstance(table, RayTable) and table.needs_both


# ------------------------------------------------------------------------------------------------
# The ray-constrained least squares, per point
# ------------------------------------------------------------------------------------------------
def _random_rig(rng):
    """A camera and a projector looking at the origin from random directions, ~150 mm away."""
    models = []
    for _ in range(2):
        direction = rng.normal(size=3)
        direction[2] = abs(direction[2]) + 1.0
        eye = 150.0 * direction / np.linalg.norm(direction)
        R, t = look_at(eye, rng.normal(scale=3.0, size=3), [0.0, 1.0, 0.0])
        f = rng.uniform(2000, 6000)
        K = np.array([[f, rng.uniform(-5, 5), rng.uniform(400, 800)],
                      [0, f * rng.uniform(0.9, 1.1), rng.uniform(400, 800)], [0, 0, 1]])
        models.append(Pinhole(K=K, R=R, t=t))
    return models


@settings(max_examples=60, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**32 - 1), noise=st.sampled_from([0.0, 0.05, 0.5]))
def test_ray_points_are_lsq_with_an_infinite_camera_weight(seed, noise):
    """reconstruct_points_ray is reconstruct_points_lsq with the point kept on the camera ray:
    within 1e-6 mm plus 2e-5 of the coordinate of camera weight 1e3 (the reference's; its
    points leave the ray by ~residual / 1e6, and its normal equations, weighted 1e6, lose about
    six digits on the worse random rigs: measured at most 8e-6 of the coordinate over 4000
    seeds at each noise level, 2e-5 mm; a fixed 1e-6 mm failed at seed 39391), and exact for
    one projector coordinate."""
    rng = np.random.default_rng(seed)
    camera, projector = _random_rig(rng)
    Mc, Mp = dlt_from_pinhole(camera), dlt_from_pinhole(projector)
    X = rng.normal(scale=8.0, size=(50, 3))
    xc, yc = project_dlt(Mc, X).T
    xp, yp = (project_dlt(Mp, X) + rng.normal(scale=noise, size=(50, 2))).T
    ray = reconstruct_points_ray(Mc, Mp, xc, yc, xp, yp)
    lsq = reconstruct_points_lsq(Mc, Mp, xc, yc, xp, yp, camera_weight=1e3)
    np.testing.assert_allclose(ray, lsq, rtol=2e-5, atol=1e-6)
    # on the camera ray: reprojects onto the pixel
    np.testing.assert_allclose(project_dlt(Mc, ray), np.column_stack([xc, yc]), atol=1e-7)
    for use, p in (("yp", yp), ("xp", xp)):
        one = reconstruct_points_ray(Mc, Mp, xc, yc, xp, yp, use=use)
        ref = reconstruct_points(Mc, Mp, xc, yc, p, axis=use[0])
        np.testing.assert_allclose(one, ref, rtol=0, atol=1e-7)


@settings(max_examples=30, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**32 - 1), model=st.booleans(),
       camera_lens=st.booleans(), projector_lens=st.booleans())
def test_ray_points_compensate_distortions_as_the_reference(seed, model, camera_lens,
                                                           projector_lens):
    """The kernel's distortion model and lens inversions against the reference's NumPy
    (ideal_from_panel, Pinhole.undistort with its 20 iterations), for points seen through
    them (projector coordinates 0.05 px off)."""
    rng = np.random.default_rng(seed)
    camera, projector = _random_rig(rng)
    if camera_lens:
        camera = dataclasses.replace(camera, dist=np.array(CAMERA_LENS) * rng.uniform(0, 1))
    if projector_lens:
        projector = dataclasses.replace(projector,
                                        dist=np.array(PROJECTOR_LENS) * rng.uniform(0, 1))
    distortion = ({"center": rng.uniform(300, 900, 2).tolist(), "rho": -0.004}
                  if model else None)
    X = rng.normal(scale=8.0, size=(40, 3))
    xc, yc = camera.project(X).T
    panel = projector.project(X)
    if distortion is not None:
        panel = panel_from_ideal(panel, distortion["center"], distortion["rho"])
    xp, yp = (panel + rng.normal(scale=0.05, size=panel.shape)).T
    xp[0] = np.nan
    for use in ("xpyp", "yp", "xp"):
        got = reconstruct_points_ray(camera, projector, xc, yc, xp, yp,
                                     projector_distortion=distortion, use=use)
        ideal = np.column_stack([xp, yp])
        if distortion is not None:
            ideal = ideal_from_panel(ideal, distortion["center"], distortion["rho"])
        ideal = undistorted_pixels(projector, ideal)
        cam = undistorted_pixels(camera, np.column_stack([xc, yc]))
        Mc, Mp = dlt_from_pinhole(camera), dlt_from_pinhole(projector)
        if use == "xpyp":
            ref = reconstruct_points_lsq(Mc, Mp, cam[:, 0], cam[:, 1], ideal[:, 0],
                                         ideal[:, 1], camera_weight=1e3)
        else:
            ref = reconstruct_points(Mc, Mp, cam[:, 0], cam[:, 1],
                                     ideal[:, 1 if use == "yp" else 0], axis=use[0])
        np.testing.assert_array_equal(np.isnan(got), np.isnan(ref), err_msg=use)
        np.testing.assert_allclose(got[1:], ref[1:], rtol=0, atol=1e-6, err_msg=use)
        # xp[0] is NaN: lost wherever it is used
        assert np.isnan(got[0]).all() == (use != "yp" or model or projector_lens)
