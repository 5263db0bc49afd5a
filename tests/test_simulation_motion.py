"""Tests of nail2nail.simulation.motion (a moving finger) and nail2nail.scan.motion (detection).

The trajectory's conventions (the reference frame is the identity, the RMS is the stated
amplitude), a moved scene against the same scene built at the moved pose, a still trajectory
that renders exactly the still frames, and the detector on frames with known shifts and on
small virtual captures: a still one is not flagged, a trembling one is, and ``scan_capture``
warns or refuses.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.ndimage as ndi
from hypothesis import given, settings
from hypothesis import strategies as st

from nail2nail.calibration.files import RigCalibration
from nail2nail.io.capture import read_capture
from nail2nail.scan.capture import motion_summary, scan_capture
from nail2nail.scan.motion import (
    MOTION_WARN_MM,
    compensate_phase_steps,
    dc_groups,
    estimate_motion,
    register_frequencies,
)
from nail2nail.scan.patterns import (
    Frequency,
    PatternSet,
    default_pattern_set,
    frame_table,
    make_patterns,
)
from nail2nail.simulation.capture import simulate, simulate_capture
from nail2nail.simulation.motion import Moved, _rotation, tremor
from nail2nail.simulation.rig import default_rig, ideal_calibration
from nail2nail.simulation.scenes import Sphere, make_scene

#: a short pattern set for the detector: x and y, 1 and 8 periods (3 steps), 16 (4)
SHORT = PatternSet(x=(Frequency(1, 3), Frequency(8, 3), Frequency(16, 4)),
                   y=(Frequency(1, 3), Frequency(8, 3), Frequency(16, 4)), gamma=2.2)
#: a shorter one for quick moving renders (every frame of a moving scene is intersected anew)
TINY = PatternSet(x=(Frequency(1, 3), Frequency(8, 3)), y=(Frequency(1, 3), Frequency(8, 3)),
                  gamma=2.2)


# -- trajectories ----------------------------------------------------------------------------
def test_tremor_reference_frame_is_the_identity_and_rms_is_the_amplitude():
    m = tremor(24, amplitude_mm=0.1, blur_steps=1, seed=4)
    assert m.reference_frame == 12
    R, t = m.pose(12, 0)
    np.testing.assert_allclose(R, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(t, 0.0, atol=1e-12)
    # over a long window the RMS of the 3D translation (about its mean) is the amplitude
    long = tremor(1200, amplitude_mm=0.1, blur_steps=1, seed=4, frame_rate_hz=600.0)
    tr = long.translation_mm[:, 0]
    rms = np.sqrt(np.mean(np.sum((tr - tr.mean(axis=0)) ** 2, axis=-1)))
    assert rms == pytest.approx(0.1, rel=0.05)
    d = m.to_dict()
    assert d["model"] == "tremor" and len(d["frames"]) == 24
    assert d["frames"][12]["translation_mm"] == [0.0, 0.0, 0.0]


def test_tremor_still_and_blur_steps():
    m = tremor(6, amplitude_mm=0.0, blur_steps=3)
    assert m.blur_steps == 3 and m.times_s.shape == (6, 3)
    np.testing.assert_allclose(m.translation_mm, 0.0)
    np.testing.assert_allclose(m.rotvec_rad, 0.0)
    # the sub-steps sit inside each exposure, in order
    assert np.all(np.diff(m.times_s, axis=1) > 0)
    assert np.all(m.times_s[:, -1] < np.arange(1, 7) / 120.0)


@pytest.mark.parametrize("kwargs, match", [
    ({"amplitude_mm": -0.1}, "amplitude_mm"), ({"amplitude_mm": float("nan")}, "amplitude_mm"),
    ({"frequency_hz": (12.0, 8.0)}, "frequency_hz"), ({"frame_rate_hz": 0.0}, "frame_rate_hz"),
    ({"exposure_s": 0.1}, "exposure_s"), ({"blur_steps": 0}, "blur_steps"),
    ({"reference_frame": 24}, "reference_frame"), ({"rotation_deg": 45.0}, "rotation_deg"),
])
def test_tremor_bad_input(kwargs, match):
    with pytest.raises(ValueError, match=match):
        tremor(24, **kwargs)


@settings(max_examples=30, deadline=None)
@given(rotvec=st.tuples(*[st.floats(-0.05, 0.05)] * 3),
       shift=st.tuples(*[st.floats(-0.5, 0.5)] * 3), seed=st.integers(0, 2**16))
def test_moved_scene_is_the_scene_at_the_moved_pose(rotvec, shift, seed):
    """A moved sphere is the sphere with its centre moved: the same hits and normals."""
    sphere = Sphere(center=(1.0, 2.0, -3.0), radius=8.0)
    R, t = _rotation(rotvec), np.asarray(shift)
    moved = Moved(sphere, R, t)
    at_pose = Sphere(center=tuple(R @ np.asarray(sphere.center) + t), radius=8.0)
    rng = np.random.default_rng(seed)
    origin = np.array([0.0, 0.0, 100.0])
    d = np.column_stack([rng.uniform(-0.05, 0.05, (50, 2)), -np.ones(50)])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(moved.intersect(origin, d), at_pose.intersect(origin, d),
                               atol=1e-9)
    hit = origin + moved.intersect(origin, d)[:, None] * d
    ok = np.isfinite(hit).all(axis=1)
    np.testing.assert_allclose(moved.surface(hit[ok]).normal, at_pose.surface(hit[ok]).normal,
                               atol=1e-9)
    assert np.array_equal(_rotation((0.0, 0.0, 0.0)), np.eye(3))


# -- rendering -------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def small_finger():
    rig = default_rig(0.125)
    return rig, make_scene("finger", rig=rig, seed=3)


def test_still_trajectory_renders_the_still_frames(small_finger):
    rig, scene = small_finger
    patterns = make_patterns(TINY)[:4]
    still = simulate(scene, rig=rig, patterns=patterns, pattern_set=TINY, seed=1, cameras=[1])
    moving = simulate(scene, rig=rig, patterns=patterns, pattern_set=TINY, seed=1, cameras=[1],
                      motion=tremor(len(patterns), amplitude_mm=0.0, blur_steps=1))
    assert np.array_equal(still.frames["cam1"], moving.frames["cam1"])
    assert moving.motion is not None


def test_motion_must_cover_the_frames(small_finger):
    rig, scene = small_finger
    with pytest.raises(ValueError, match="motion: covers 5 frames, the patterns are 12"):
        simulate(scene, rig=rig, pattern_set=TINY, cameras=[1], motion=tremor(5))


# -- detection -------------------------------------------------------------------------------
def _textured_frames(shifts, pattern_set, *, gamma=1.0, seed=0):
    """Phase frames of a ridge-like texture moved by ``shifts[g]`` (dx, dy) px in group g, with
    the fringes fixed to the projector (they do not move with the texture)."""
    rng = np.random.default_rng(seed)
    h, w = 240, 320
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    noise = ndi.gaussian_filter(rng.standard_normal((h + 40, w + 40)), 2.0)
    texture = 0.5 + 0.15 * noise / noise.std()
    frames = []
    for (label, idx), (dx, dy) in zip(dc_groups(pattern_set), shifts, strict=True):
        albedo = ndi.shift(texture, (dy, dx), order=3, mode="nearest")[20:20 + h, 20:20 + w]
        periods = float(label.split("/")[1])
        axis = xx if label.startswith("x") else yy
        for k in range(len(idx)):
            phase = 2 * np.pi * periods * axis / w + 2 * np.pi * k / len(idx)
            light = (0.5 + 0.5 * np.cos(phase)) ** gamma
            frames.append(np.clip(albedo * (0.1 + 0.8 * light) * 255, 0, 255))
    return np.asarray(frames), np.ones((h, w), bool)


def test_estimate_motion_recovers_known_shifts():
    groups = dc_groups(SHORT)
    assert [g[0] for g in groups] == ["x/1", "x/8", "x/16", "y/1", "y/8", "y/16"]
    shifts = [(0.0, 0.0), (0.3, -0.2), (0.8, 0.1), (-0.4, 0.5), (0.2, 0.2), (1.1, -0.6)]
    frames, mask = _textured_frames(shifts, SHORT)
    est = estimate_motion(frames, SHORT, mask, mm_per_px=0.05, tiles=2)
    np.testing.assert_allclose(est.shift_px, shifts, atol=0.05)
    expected = max(np.hypot(a[0] - b[0], a[1] - b[1]) for a in shifts for b in shifts)
    assert est.spread_px == pytest.approx(expected, abs=0.07)
    d = est.to_dict()
    assert d["motion_mm"] == pytest.approx(est.max_spread_px * 0.05, rel=1e-3)
    assert d["moving"] is True


def test_estimate_motion_still_frames_under_a_gamma_mismatch():
    """A still scene under a projector whose gamma the patterns did not expect: the fringes'
    harmonics stay in the 3-step groups' means, fixed to the projector; no motion is read."""
    frames, mask = _textured_frames([(0.0, 0.0)] * 6, SHORT, gamma=1.4)
    est = estimate_motion(frames, SHORT, mask, mm_per_px=0.05, tiles=2)
    assert est.max_spread_px < 0.1
    assert est.to_dict()["moving"] is False


def _flat_skin_frames(seed: int, *, lit_rows: int = 170):
    """Phase frames of still, flat skin (no texture, camera noise of 1.5 grey levels) whose
    projector light ends at row `lit_rows` (a 3 px ramp); the valid mask reaches into the ramp,
    as a decoder's modulation test lets it."""
    rng = np.random.default_rng(seed)
    h, w = 240, 320
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    lit = ndi.gaussian_filter((yy < lit_rows).astype(float), 3.0)
    frames = []
    for label, idx in dc_groups(SHORT):
        periods = float(label.split("/")[1])
        axis = xx if label.startswith("x") else yy
        for k in range(len(idx)):
            phase = 2 * np.pi * periods * axis / w + 2 * np.pi * k / len(idx)
            light = (0.5 + 0.5 * np.cos(phase)) ** 2.2
            frame = 0.5 * (0.05 + 0.85 * light * lit) * 255 + 1.5 * rng.standard_normal((h, w))
            frames.append(np.clip(frame, 0, 255))
    return np.asarray(frames), yy < lit_rows + 2


def test_estimate_motion_ignores_a_static_edge_on_flat_skin(monkeypatch):
    """Where the lit area ends on skin without ridges, the band-passed edge does not move with
    the skin and leaves the shift along it free: the window keeps clear of it, no motion is
    read (with the window 0.3 mm inside the valid pixels, as before, 2–11 px were)."""
    from nail2nail.scan import motion

    for seed in range(4):
        frames, mask = _flat_skin_frames(seed)
        est = estimate_motion(frames, SHORT, mask, mm_per_px=0.05, tiles=2)
        assert not est.max_spread_px > 0.1  # NaN: no texture to register anywhere
        assert est.to_dict()["moving"] is not True  # None: nothing measured, not flagged
    monkeypatch.setattr(motion, "EDGE_MM", 0.3)
    est = estimate_motion(frames, SHORT, mask, mm_per_px=0.05, tiles=2)
    assert est.max_spread_px > 1.0


def test_estimate_motion_needs_two_groups_and_pixels():
    one = PatternSet(x=(Frequency(1, 4),), gamma=2.2)
    frames = np.zeros((4, 100, 100), np.uint8)
    assert estimate_motion(frames, one, np.ones((100, 100), bool)) is None
    assert estimate_motion(np.zeros((24, 100, 100)), default_pattern_set(),
                           np.zeros((100, 100), bool)) is None


@pytest.fixture(scope="module")
def trembling_capture(tmp_path_factory, small_finger):
    """A still and a trembling finger (0.1 mm RMS at 10 Hz) at 1/8 resolution, 12 frames."""
    rig, scene = small_finger
    root = tmp_path_factory.mktemp("motion")
    patterns = make_patterns(TINY)
    out = {}
    for name, amplitude in (("still", 0.0), ("moving", 0.1)):
        motion = tremor(len(patterns), amplitude_mm=amplitude, blur_steps=1, seed=5)
        simulate_capture(root / name, scene, rig=rig, patterns=patterns, pattern_set=TINY,
                         seed=2, motion=None if amplitude == 0 else motion)
        out[name] = root / name
    return out, RigCalibration.from_dict(ideal_calibration(rig))


def test_trembling_capture_is_flagged_and_a_still_one_is_not(trembling_capture):
    dirs, calib = trembling_capture
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no motion warning on the still finger
        still = scan_capture(read_capture(dirs["still"], load=False), calib)
    summary = motion_summary(still)
    assert summary is not None and summary["motion_mm"] < MOTION_WARN_MM / 2
    with pytest.warns(UserWarning, match="the finger moved during the capture"):
        moving = scan_capture(read_capture(dirs["moving"], load=False), calib)
    summary = motion_summary(moving)
    assert summary["moving"] and summary["motion_mm"] > 2 * MOTION_WARN_MM
    assert (dirs["moving"] / "truth" / "motion.json").is_file()
    with pytest.raises(ValueError, match=r"moved during the capture.*µm allowed"):
        scan_capture(read_capture(dirs["moving"], load=False), calib, max_motion_mm=0.03)
    with pytest.raises(ValueError, match="max_motion_mm"):
        scan_capture(read_capture(dirs["still"], load=False), calib, max_motion_mm=-1.0)


# -- compensation ----------------------------------------------------------------------------
def _offset_frames(pattern_set, *, offsets: bool, seed=0):
    """Frames of a textured surface whose 6-step group's frames carry random phase offsets
    (up to ±0.6 rad, growing twofold across the image: smooth, as rigid motion makes them)."""
    table = frame_table(pattern_set)
    h, w = 192, 256
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    rng = np.random.default_rng(seed)
    fine = 2 * np.pi * xx / 13.0 + 0.3 * np.sin(yy / 20)
    coarse = 2 * np.pi * xx / (4 * w)
    a = 100 + 20 * np.sin(xx / 9) * np.cos(yy / 7)
    b = 60 + 10 * np.cos(xx / 11)
    frames, eps = [], {}
    for row in table:
        steps_fine = row.periods > 1
        e = rng.uniform(-0.6, 0.6) * (1 + xx / w) if (steps_fine and offsets) else 0.0
        eps[row.index] = e
        phase = fine if steps_fine else coarse
        frames.append(a + b * np.cos(phase + row.shift + e) + rng.normal(0, 1.0, (h, w)))
    fine_idx = [r.index for r in table if r.periods > 1]
    truth = fine + np.mean([eps[i] for i in fine_idx], axis=0)
    return np.clip(np.rint(frames), 0, 255).astype(np.uint8), table, fine_idx, truth


def _phase(frames, table, idx):
    d = np.array([table[i].shift for i in idx])
    design = np.stack([np.ones_like(d), np.cos(d), -np.sin(d)], -1)
    coef = np.tensordot(np.linalg.pinv(design), frames[idx].astype(float), axes=(1, 0))
    return np.arctan2(coef[2], coef[1])


@settings(max_examples=25, deadline=None)
@given(n=st.integers(3, 8), jitter=st.floats(0.0, 0.4), seed=st.integers(0, 2**31 - 1))
def test_per_pixel_phase_fit_is_the_least_squares_solution(n, jitter, seed):
    """The cofactor solution of the 3 × 3 normal equations is each pixel's least squares fit,
    and recovers a, C, S exactly from noise-free frames."""
    from nail2nail.scan.motion import fit_pixel_shifts

    rng = np.random.default_rng(seed)
    shifts = (2 * np.pi * np.arange(n)[:, None, None] / n
              + rng.uniform(-jitter, jitter, (n, 4, 5)))
    truth = rng.normal(0, 1, (3, 4, 5)) + np.array([5.0, 0, 0])[:, None, None]
    frames = truth[0] + truth[1] * np.cos(shifts) - truth[2] * np.sin(shifts)
    np.testing.assert_allclose(fit_pixel_shifts(frames, shifts), truth, atol=1e-9)
    noisy = frames + rng.normal(0, 0.1, frames.shape)
    got = fit_pixel_shifts(noisy, shifts)
    for r, c in ((0, 0), (3, 4)):
        design = np.stack([np.ones(n), np.cos(shifts[:, r, c]), -np.sin(shifts[:, r, c])], 1)
        expected, *_ = np.linalg.lstsq(design, noisy[:, r, c], rcond=None)
        np.testing.assert_allclose(got[:, r, c], expected, atol=1e-9)


def test_compensation_removes_per_frame_phase_offsets():
    pattern_set = PatternSet(x=(Frequency(1, 3), Frequency(64, 6)), gamma=None)
    frames, table, idx, truth = _offset_frames(pattern_set, offsets=True)
    err = np.angle(np.exp(1j * (_phase(frames, table, idx) - truth)))
    out, info = compensate_phase_steps(frames, pattern_set, None, between_frequencies=False)
    fixed = np.angle(np.exp(1j * (_phase(out, table, idx) - truth)))
    rms_before, rms_after = np.sqrt(np.mean(err**2)), np.sqrt(np.mean(fixed**2))
    assert rms_before > 0.15  # measured 0.216 rad
    assert rms_after < 0.04, rms_after  # measured 0.028 (noise alone: 0.010)
    (group,) = info["groups"]  # the 3-step group cannot be compensated, and is left
    assert group["label"] == "x/64" and group["regions"] == group["of"]
    np.testing.assert_array_equal(out[:3], frames[:3])
    assert out.dtype == frames.dtype and out.shape == frames.shape


def test_compensation_of_still_frames_changes_nothing_measurable():
    pattern_set = PatternSet(x=(Frequency(1, 3), Frequency(64, 6)), gamma=None)
    frames, table, idx, truth = _offset_frames(pattern_set, offsets=False)
    out, info = compensate_phase_steps(frames, pattern_set, None, between_frequencies=False)
    before = np.angle(np.exp(1j * (_phase(frames, table, idx) - truth)))
    after = np.angle(np.exp(1j * (_phase(out, table, idx) - truth)))
    assert np.sqrt(np.mean(after**2)) < np.sqrt(np.mean(before**2)) + 0.005
    assert info["groups"][0]["offset_rms_rad"] < 0.02


def _moving_frequency_frames(pattern_set, shift_periods: float, *, seed=0):
    """Frames of a surface whose panel coordinate ``u`` changes between the frequencies: the
    coarser groups see ``u + Δu``, ``Δu`` smooth and up to `shift_periods` of the finest
    fringe (as a finger moving between them). Returns frames, the frame table and ``u``."""
    table = frame_table(pattern_set)
    h, w = 160, 224
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    rng = np.random.default_rng(seed)
    u = 150 + 4.1 * xx + 0.8 * yy + 6 * np.sin(yy / 25)  # panel px, the finest group's time
    fine_period = 1280 / 64
    du = shift_periods * fine_period * (0.4 + 0.6 * xx / w) * np.cos(yy / 60)
    a = 100 + 20 * np.sin(xx / 9) * np.cos(yy / 7)
    b = 60 + 10 * np.cos(xx / 11)
    frames = []
    for row in table:
        seen = u if row.periods == 64 else u + du * (1 if row.periods == 8 else 0.6)
        phase = 2 * np.pi * row.periods * (seen + 0.5) / 1280
        frames.append(a + b * np.cos(phase + row.shift) + rng.normal(0, 1.0, (h, w)))
    return np.clip(np.rint(frames), 0, 255).astype(np.uint8), table, u


def _panel_u(frames, table):
    from nail2nail.scan.phase_shift import unwrap_hierarchical

    periods = [1.0, 8.0, 64.0]
    phases = [np.mod(_phase(frames, table, [r.index for r in table if r.periods == n]),
                     2 * np.pi) for n in periods]
    phi, bad = unwrap_hierarchical(phases, periods)
    return phi * 1280 / (2 * np.pi * 64) - 0.5, bad


def test_registering_frequencies_restores_the_fringe_order_of_a_moving_finger():
    pattern_set = PatternSet(x=(Frequency(1, 3), Frequency(8, 3), Frequency(64, 6)), gamma=None)
    frames, table, u = _moving_frequency_frames(pattern_set, 0.4)
    before, bad_before = _panel_u(frames, table)
    out, info = register_frequencies(frames, pattern_set)
    after, bad_after = _panel_u(out, table)
    wrong_before = np.abs(before - u) > 5  # a quarter of the fine period
    wrong_after = np.abs(after - u) > 5
    assert (wrong_before | bad_before).mean() > 0.15  # measured 0.20 refused, 0 wrong
    assert wrong_after.mean() == 0 and bad_after.mean() < 0.001, (wrong_after.mean(),
                                                                   bad_after.mean())
    # the finest frequency, which sets the geometry, is untouched
    fine = [r.index for r in table if r.periods == 64]
    np.testing.assert_array_equal(out[fine], frames[fine])
    assert [lv["label"] for lv in info["levels"]] == ["x/8", "x/1"]
    assert 1.0 < info["levels"][0]["misfit_max_rad"] < 0.4 * 2 * np.pi + 0.2


def test_registering_frequencies_of_still_frames_changes_no_fringe_order():
    pattern_set = PatternSet(x=(Frequency(1, 3), Frequency(8, 3), Frequency(64, 6)), gamma=None)
    frames, table, _ = _moving_frequency_frames(pattern_set, 0.0, seed=1)
    out, info = register_frequencies(frames, pattern_set)
    before, bad_before = _panel_u(frames, table)
    after, bad_after = _panel_u(out, table)
    np.testing.assert_allclose(after, before, atol=1e-3)
    assert not bad_after.any() and not bad_before.any()
    assert info["levels"][0]["misfit_rms_rad"] < 0.05
