"""Stabilising a moving finger's frames (:mod:`nail2nail.scan.stabilise`): the skin's motion
measured from its texture, the frames resampled to one time."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.ndimage as ndi
from hypothesis import given, settings
from hypothesis import strategies as st

from nail2nail.io.capture import read_capture
from nail2nail.scan.capture import scan_capture
from nail2nail.scan.patterns import Frequency, PatternSet, default_pattern_set, frame_table
from nail2nail.scan.stabilise import (
    _affine_basis,
    _affine_basis_at,
    _register_affine,
    _trajectory,
    _warp_affine,
    reference_direction,
    stabilise_frames,
)

H, W = 240, 320
#: the finest fringe's period, px (the thesis rig's at half resolution: 12–14 px)
FINE_PX = 13.0


def _trajectory_px(n_frames: int, amplitude: float) -> np.ndarray:
    """A smooth tremor-like path ``(n_frames, 2)`` (dy, dx) of the skin, px."""
    t = np.arange(n_frames, dtype=float)
    return amplitude * np.stack([np.sin(2 * np.pi * t / 12 + 0.4),
                                 0.6 * np.cos(2 * np.pi * t / 10 + 1.0)], axis=1)


def _frames(pattern_set: PatternSet, path: np.ndarray, *, contrast: float = 0.15, seed: int = 0):
    """Frames of a ridge-like texture carried along `path` (each frame's (dy, dx) px) under
    fringes fixed to the projector: ``I_k = ρ(x − d_k) (0.15 + 0.7 L_k(x))``, 8-bit, noise 1
    grey level. Returns the frames and the phase of the finest fringe of each direction."""
    rng = np.random.default_rng(seed)
    noise = ndi.gaussian_filter(rng.standard_normal((H + 40, W + 40)), 1.5)
    texture = 1.0 + contrast * noise / noise.std()
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    table = frame_table(pattern_set)
    most = max(row.periods for row in table)
    out = []
    for row, (dy, dx) in zip(table, path, strict=True):
        rho = ndi.shift(texture, (dy, dx), order=3, mode="nearest")[20:20 + H, 20:20 + W]
        axis = xx if row.direction == "x" else yy
        phase = 2 * np.pi * axis / FINE_PX * row.periods / most
        light = 0.5 + 0.5 * np.cos(phase + row.shift)
        out.append(150 * rho * (0.15 + 0.7 * light) + rng.normal(0, 1.0, (H, W)))
    fine = {d: 2 * np.pi * (xx if d == "x" else yy) / FINE_PX for d in ("x", "y")}
    return np.clip(np.rint(out), 0, 255).astype(np.uint8), fine


def _group_phase(frames, pattern_set, direction):
    """Wrapped phase of the direction's finest group (least squares over its steps)."""
    table = frame_table(pattern_set)
    most = max(row.periods for row in table)
    idx = [r.index for r in table if r.direction == direction and r.periods == most]
    d = np.array([table[i].shift for i in idx])
    design = np.stack([np.ones_like(d), np.cos(d), -np.sin(d)], -1)
    coef = np.tensordot(np.linalg.pinv(design), frames[idx].astype(float), axes=(1, 0))
    return np.arctan2(coef[2], coef[1])


def _wrapped_rms(a, b, inner):
    return float(np.sqrt(np.mean(np.angle(np.exp(1j * (a - b)))[inner] ** 2)))


INNER = (slice(30, H - 30), slice(30, W - 30))


def test_the_reference_is_the_last_finest_group():
    assert reference_direction(default_pattern_set()) == "y"
    xs = PatternSet(x=(Frequency(1, 3), Frequency(16, 4)), y=(Frequency(1, 3), Frequency(8, 4)),
                    gamma=None)
    assert reference_direction(xs) == "x"  # the most periods win over the later group


def test_the_reference_can_be_the_direction_asked():
    assert reference_direction(default_pattern_set(), "x") == "x"
    with pytest.raises(ValueError, match="no phase-shift group in direction 'y'"):
        reference_direction(PatternSet(x=(Frequency(1, 3), Frequency(16, 4)), gamma=None), "y")


def test_the_trajectory_meets_averages_and_extrapolates_linearly():
    truth = 0.3 * np.arange(10.0) - 1.0  # linear: the least-curvature path through its averages
    members = [[0, 1, 2], [3, 6], [4, 7], [5, 8], [9]]
    observed = np.array([truth[m].mean() for m in members])
    np.testing.assert_allclose(_trajectory(10, members, observed), truth, atol=1e-3)


def test_moving_texture_is_measured_and_held_still():
    pattern_set = default_pattern_set()
    path = _trajectory_px(pattern_set.n_frames, 1.2)
    frames, fine = _frames(pattern_set, path)
    out, info = stabilise_frames(frames, pattern_set)
    assert info["reference"] == "y/64" and info["direction"] == "y"
    assert "skipped" not in info and min(info["correlation"]) > 0.9
    # the motion relative to the reference group's mean, every frame
    expected = path - path[18:24].mean(axis=0)
    measured = np.array(info["frames_px"])
    assert np.sqrt(np.mean((measured - expected) ** 2)) < 0.12
    # the reference direction's phase: the sliding texture's error is gone
    before = _wrapped_rms(_group_phase(frames, pattern_set, "y"), fine["y"], INNER)
    after = _wrapped_rms(_group_phase(out, pattern_set, "y"), fine["y"], INNER)
    assert after < 0.5 * before and after < 0.03
    assert out.dtype == frames.dtype and out.shape == frames.shape


def test_still_frames_are_left_as_they_are():
    pattern_set = default_pattern_set()
    frames, fine = _frames(pattern_set, np.zeros((pattern_set.n_frames, 2)))
    out, info = stabilise_frames(frames, pattern_set)
    assert np.abs(np.array(info["frames_px"])).max() < 0.03 and info["spread_px"] < 0.05
    for direction in ("x", "y"):
        before = _wrapped_rms(_group_phase(frames, pattern_set, direction), fine[direction], INNER)
        after = _wrapped_rms(_group_phase(out, pattern_set, direction), fine[direction], INNER)
        assert after < before + 0.003
    # the frames differ by the noise the per-pixel fit leaves out (σ 1 grey level, 3 of 6
    # steps' degrees of freedom in the fine groups, none in the 3-step ones) and rounding
    diff = out[:, 40:-40, 40:-40].astype(float) - frames[:, 40:-40, 40:-40]
    assert np.sqrt(np.mean(diff**2)) < 0.8 and np.abs(diff).max() <= 6


def test_skin_without_texture_is_not_resampled():
    pattern_set = default_pattern_set()
    frames, _ = _frames(pattern_set, _trajectory_px(pattern_set.n_frames, 1.0), contrast=0.0)
    out, info = stabilise_frames(frames, pattern_set)
    assert "does not register" in info["skipped"]
    assert np.array_equal(out, frames)


@pytest.mark.parametrize("pattern_set", [
    PatternSet(x=(Frequency(1, 3), Frequency(8, 5)), y=(Frequency(1, 3),), gamma=None),
    PatternSet(scheme="gray", x=(Frequency(320, 4),), y=(), gamma=None),
])
def test_pattern_sets_it_cannot_stabilise_are_returned(pattern_set):
    frames = np.random.default_rng(0).integers(0, 255, (pattern_set.n_frames, 40, 50),
                                               dtype=np.uint8)
    out, info = stabilise_frames(frames, pattern_set)
    assert info["reference"] is None and np.array_equal(out, frames)


def test_scan_capture_stabilised_triangulates_from_the_reference_direction(tmp_path):
    from nail2nail.calibration.files import RigCalibration
    from nail2nail.simulation.capture import simulate_capture
    from nail2nail.simulation.rig import default_rig, ideal_calibration
    from nail2nail.simulation.scenes import make_scene

    rig = default_rig(0.125)
    simulate_capture(tmp_path / "cap", make_scene("finger", rig=rig, seed=3), rig=rig, seed=2)
    calib = RigCalibration.from_dict(ideal_calibration(rig))
    capture = read_capture(tmp_path / "cap", load=False)
    scans = scan_capture(capture, calib, stabilise_motion=True)
    for scan in scans:
        assert "stabilisation" in scan.motion and "compensation" in scan.motion
        # resampled: triangulated from yp; not (too little texture): as asked (xpyp)
        stabilisation = scan.motion["stabilisation"]
        assert stabilisation["use"] == ("xpyp" if "skipped" in stabilisation else "yp")
        assert np.isfinite(scan.xyz[scan.mask]).all() and scan.mask.any()
    # a single direction asked: stabilised to that direction's finest group (xp is
    # ill-conditioned on the thesis rig, and said so)
    with pytest.warns(UserWarning, match="ill-conditioned"):
        scans = scan_capture(capture, calib, stabilise_motion=True, use="xp")
    for scan in scans:
        stabilisation = scan.motion["stabilisation"]
        if "skipped" not in stabilisation:
            assert stabilisation["reference"] == "x/64" and stabilisation["use"] == "xp"


def _first_harmonic_frames(amplitude_px: float, relief_rad: float = 0.0, seed: int = 1):
    """One 6-step group of a ridge-like texture moved within the group along the first harmonic
    of the steps (``e_k = E_c cos δ_k + E_s sin δ_k``: what pairs and triples of opposite steps
    cannot see), under a fixed fringe; optionally a relief in phase with the texture. Returns
    the frames, the nominal shifts ``(6, 1, 1)``, the true phase and the texture."""
    rng = np.random.default_rng(seed)
    noise = ndi.gaussian_filter(rng.standard_normal((H + 40, W + 40)), 1.5)
    texture = 1.0 + 0.15 * noise / noise.std()
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    rho0 = texture[20:20 + H, 20:20 + W]
    phase = 2 * np.pi * yy / FINE_PX + 0.3 * np.sin(xx / 40) + relief_rad * (rho0 - 1) / 0.15
    shifts = 2 * np.pi * np.arange(6) / 6
    e_c, e_s = np.array([0.5, -0.3]) * amplitude_px, np.array([-0.2, 0.6]) * amplitude_px
    frames = []
    for d in shifts:
        dy, dx = e_c * np.cos(d) + e_s * np.sin(d)
        rho = ndi.shift(texture, (dy, dx), order=3, mode="nearest")[20:20 + H, 20:20 + W]
        frames.append(150 * rho * (0.15 + 0.35 * (1 + np.cos(phase + d)))
                      + rng.normal(0, 0.5, (H, W)))
    return np.array(frames), shifts[:, None, None], phase, rho0


def _fit_phase(frames, shifts):
    from nail2nail.scan.motion import fit_pixel_shifts

    return fit_pixel_shifts(frames, shifts)


@pytest.mark.parametrize("amplitude", [0.5, 1.0])
def test_motion_the_texture_images_cannot_see_is_taken_out_of_the_phase(amplitude):
    from nail2nail.scan.stabilise import texture_phase_error

    frames, shifts, phase, _ = _first_harmonic_frames(amplitude)
    a, c, s = _fit_phase(frames, shifts)
    weight = np.zeros((H, W))
    weight[INNER] = 1.0
    error, figures = texture_phase_error(a, c, s, weight)
    before = _wrapped_rms(np.arctan2(s, c), phase, INNER)
    after = _wrapped_rms(np.arctan2(s, c) - error, phase, INNER)
    assert before > 0.02  # the sliding texture's error, at the ridges' and fringe's beat
    assert after < 0.3 * before, (before, after)
    assert figures["rms_rad"] > 0.5 * before


@pytest.mark.parametrize("relief", [0.0, 0.1])
def test_still_skin_and_its_relief_are_left_in_the_phase(relief):
    from nail2nail.scan.stabilise import texture_phase_error

    frames, shifts, phase, _ = _first_harmonic_frames(0.0, relief_rad=relief)
    a, c, s = _fit_phase(frames, shifts)
    weight = np.zeros((H, W))
    weight[INNER] = 1.0
    error, _ = texture_phase_error(a, c, s, weight)
    # nothing to take out: the correction stays far below the relief's phase (0.1 rad RMS
    # ridges in phase with the texture, which the print reads) and the noise's
    assert np.sqrt(np.mean(error[INNER] ** 2)) < 0.004
    after = _wrapped_rms(np.arctan2(s, c) - error, phase, INNER)
    assert after < _wrapped_rms(np.arctan2(s, c), phase, INNER) + 0.001


def _rig_views(rotation, translation, scale: float = 0.25):
    """Points on a finger-like half cylinder (radius 8 mm along y) seen by the virtual rig's
    cameras, and each camera's exact per-frame image motion under the small rigid motions
    (``X → X + ω × (X − c) + t`` per frame) fitted as affine maps."""
    from nail2nail.calibration.camera_models import project_dlt, projection_matrix
    from nail2nail.calibration.files import RigCalibration
    from nail2nail.simulation.rig import default_rig, ideal_calibration

    calib = RigCalibration.from_dict(ideal_calibration(default_rig(scale)))
    angle, y = np.meshgrid(np.linspace(-1.2, 1.2, 40), np.linspace(-10, 10, 30))
    xyz = np.stack([8 * np.sin(angle), y, 8 * np.cos(angle)], -1).reshape(-1, 3)
    center = xyz.mean(axis=0)
    views = []
    for cam in calib.cameras:
        m = projection_matrix(cam.camera)
        w, h = cam.size
        col, row = project_dlt(m, xyz).T
        inside = (col > 0) & (col < w - 1) & (row > 0) & (row < h - 1)
        pts, rows, cols = xyz[inside], row[inside], col[inside]
        flow = np.stack([project_dlt(m, pts + np.cross(om, pts - center) + t)[:, ::-1]
                         - np.stack([rows, cols], -1)
                         for om, t in zip(rotation, translation, strict=True)])
        b = _affine_basis_at(rows, cols, (h, w)).T
        coef, *_ = np.linalg.lstsq(b, flow.transpose(1, 0, 2).reshape(len(rows), -1), rcond=None)
        maps = coef.reshape(3, len(rotation), 2).transpose(1, 2, 0)
        views.append((maps, pts, rows, cols, m, (h, w)))
    return views, center


def test_one_rigid_motion_moves_every_camera_alike():
    from nail2nail.scan.stabilise import affine_image_motion, rigid_motion

    rng = np.random.default_rng(4)
    rotation = rng.normal(0, 0.004, (5, 3))  # rad: 0.03 mm at 8 mm from the centre
    translation = rng.normal(0, 0.08, (5, 3))  # mm
    views, center = _rig_views(rotation, translation)
    # two cameras give the motion; it moves the third's image as the third saw it
    rigid = rigid_motion(views[:2], center)
    # the points' 3D motion (rotation and translation trade a little over one finger)
    pts = views[1][1]
    true = np.cross(rotation[:, None], pts - center) + translation[:, None]
    found = np.cross(rigid[:, None, :3], pts - center) + rigid[:, None, 3:]
    assert np.sqrt(np.mean((found - true) ** 2)) < 0.1 * np.sqrt(np.mean(true**2))
    maps, pts, rows, cols, m, shape = views[2]
    predicted = affine_image_motion(rigid, pts, rows, cols, m, shape, center)
    b = _affine_basis_at(rows, cols, shape)
    error = np.einsum("kjb,bp->kpj", predicted - maps, b)
    motion = np.einsum("kjb,bp->kpj", maps, b)
    # every map is an affine fit of a perspective flow (6 % of it here, 0.05 px of 0.74): the
    # transfer is that close, against the 15-35 % a camera's own texture estimate errs by
    # on the virtual scanner's trembling finger
    assert np.sqrt(np.mean(error**2)) < 0.1 * np.sqrt(np.mean(motion**2))


def test_a_camera_without_texture_takes_the_others_motion():
    from types import SimpleNamespace

    from nail2nail.calibration.files import RigCalibration
    from nail2nail.scan.capture import _motion_from_other_cameras
    from nail2nail.simulation.rig import default_rig, ideal_calibration

    rng = np.random.default_rng(5)
    rotation, translation = rng.normal(0, 0.004, (4, 3)), rng.normal(0, 0.08, (4, 3))
    views, _ = _rig_views(rotation, translation)
    calib = RigCalibration.from_dict(ideal_calibration(default_rig(0.25)))
    scans = []
    for k, (maps, pts, rows, cols, _, shape) in enumerate(views):
        mask, xyz = np.zeros(shape, bool), np.full((*shape, 3), np.nan, np.float32)
        r, c = np.rint(rows).astype(int), np.rint(cols).astype(int)
        mask[r, c], xyz[r, c] = True, pts
        info = {"reference": "y/64", "frames_affine": maps.tolist()}
        if k == 2:
            info = {"reference": "y/64", "skipped": "the skin's texture does not register"}
        scans.append(SimpleNamespace(name=calib.cameras[k].name, mask=mask, xyz=xyz,
                                     motion={"stabilisation": info}))
    (index, maps, sources), = _motion_from_other_cameras(scans, calib)
    assert index == 2 and sources == [calib.cameras[0].name, calib.cameras[1].name]
    rows, cols = np.nonzero(scans[2].mask)
    b = _affine_basis_at(rows, cols, views[2][5])
    error = np.einsum("kjb,bp->kpj", maps - views[2][0], b)
    motion = np.einsum("kjb,bp->kpj", views[2][0], b)
    assert np.sqrt(np.mean(error**2)) < 0.1 * np.sqrt(np.mean(motion**2))
    # nothing to take from when no camera registered
    for scan in scans[:2]:
        scan.motion["stabilisation"]["skipped"] = "no texture"
    assert _motion_from_other_cameras(scans, calib) == []


# -- the compiled warp and Gauss–Newton step against their NumPy definitions -------------------
def _warp_reference(image, params):
    """``image(x + P·b(x))`` as scipy computes it: bilinear, the image's edge beyond it."""
    d = np.einsum("jb,bhw->jhw", params, _affine_basis(image.shape))
    rows, cols = np.mgrid[0:image.shape[0], 0:image.shape[1]].astype(np.float64)
    return ndi.map_coordinates(image, [rows + d[0], cols + d[1]], order=1, mode="nearest")


@settings(max_examples=25, deadline=None)
@given(params=st.lists(st.floats(-6.0, 6.0), min_size=6, max_size=6),
       seed=st.integers(0, 2**16), shape=st.sampled_from([(17, 23), (40, 31), (2, 5)]))
def test_warp_affine_is_the_scipy_bilinear_warp(params, seed, shape):
    image = np.random.default_rng(seed).random(shape)
    p = np.reshape(params, (2, 3))  # shifts of up to several pixels: some beyond the edge
    np.testing.assert_allclose(_warp_affine(image, p), _warp_reference(image, p), rtol=0,
                               atol=1e-12)


def test_register_affine_takes_the_numpy_gauss_newton_steps():
    """The compiled normal equations give the steps of the NumPy formulation (np.gradient of the
    moved image times the basis, weighted least squares), and recover a known affine map."""
    def texture(r, c):  # smooth, in every direction
        return (np.sin(r / 3.1 + 0.4) * np.cos(c / 4.3) + 0.5 * np.sin((r + c) / 5.2)
                + 0.3 * np.cos((r - 2 * c) / 6.1))

    truth = np.array([[0.6, -0.8, 0.3], [-0.4, 0.5, 0.9]])
    rows, cols = np.mgrid[0:60, 0:80].astype(np.float64)
    image = texture(rows, cols)
    d = np.einsum("jb,bhw->jhw", truth, _affine_basis(image.shape))
    reference = texture(rows + d[0], cols + d[1])  # image(x + P·b(x)), exactly
    weight = np.zeros((60, 80))
    weight[8:-8, 8:-8] = 1.0

    def numpy_register(iterations):
        params = np.zeros((2, 3))
        sel = weight > 0
        b = _affine_basis(reference.shape)[:, sel]
        for _ in range(iterations):
            moved = _warp_reference(image, params)
            gy, gx = np.gradient(moved)
            jac = np.concatenate([gy[sel] * b, gx[sel] * b])
            normal = (jac * weight[sel]) @ jac.T
            normal += 1e-6 * np.trace(normal) / 6 * np.eye(6)
            step = np.linalg.solve(normal, (jac * weight[sel]) @ (reference[sel] - moved[sel]))
            params += np.clip(step.reshape(2, 3), -2.0, 2.0)
        return params

    for iterations in (1, 3):
        np.testing.assert_allclose(_register_affine(image, reference, weight, iterations),
                                   numpy_register(iterations), rtol=0, atol=1e-9)
    # and the map: its displacement within 0.02 px of the truth's over the weighted pixels (the
    # bilinear interpolation of a texture of 20–40 px periods bounds it)
    error = np.einsum("jb,bhw->jhw", _register_affine(image, reference, weight) - truth,
                      _affine_basis(image.shape))
    assert np.abs(error[:, weight > 0]).max() < 0.02
