"""Tests for nail2nail.scan.decoding: wrapped phase, hierarchical unwrapping, decode and its fast
path."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nail2nail.scan.decoding import decode
from nail2nail.scan.inputs import normalize_frames
from nail2nail.scan.kernels import decode_fast, planar_table
from nail2nail.scan.patterns import PatternSet, default_pattern_set, frame_table, make_patterns
from nail2nail.scan.phase_shift import unwrap_hierarchical, wrapped_phase
from nail2nail.scan.results import (
    EDGE,
    LOW_MODULATION,
    OUT_OF_PANEL,
    SATURATED,
    SHADOW,
    STEEP,
    UNWRAP_ERROR,
    neighbourhood_reasons,
)


def render_capture(pattern_set, shape=(96, 120), *, seed=0, defocus_px=1.0, full_well=20000.0,
                   read_noise=0.0005, albedo=None, ambient=0.03, gain=0.85):
    """Noisy 8-bit frames of a camera looking at a smooth surface, with their true (xp, yp).

    Camera pixel -> panel coordinate is a smooth non-linear map covering most of the panel.
    Defocus (Gaussian, `defocus_px` panel px) attenuates a sinusoid of period T by
    exp(-2 pi^2 sigma^2 / T^2). Noise: shot (`full_well` electrons at full scale), read, 8-bit.
    """
    rng = np.random.default_rng(seed)
    h, w = shape
    wp, hp = pattern_set.panel_size
    r, c = np.mgrid[0:h, 0:w].astype(np.float64)
    s, t = c / (w - 1), r / (h - 1)
    xp = 30 + (wp - 60) * (s + 0.04 * np.sin(3 * t)) / 1.04
    yp = 25 + (hp - 50) * (t + 0.03 * np.cos(2.5 * s)) / 1.03
    if albedo is None:
        albedo = 0.5 + 0.15 * np.cos(7 * s) * np.sin(5 * t)
    truth = {"x": xp, "y": yp}
    frames = np.empty((pattern_set.n_frames, h, w), np.uint8)
    for info in frame_table(pattern_set):
        size = pattern_set.axis_size(info.direction)
        period = size / info.periods
        m = np.exp(-2 * np.pi**2 * defocus_px**2 / period**2)
        phi = 2 * np.pi * info.periods * (truth[info.direction] + 0.5) / size
        value = gain * albedo * (ambient + 0.5 + 0.5 * m * np.cos(phi - info.shift))
        electrons = rng.poisson(np.clip(value, 0, None) * full_well)
        noisy = electrons / full_well + rng.normal(0.0, read_noise, value.shape)
        frames[info.index] = np.clip(np.rint(255 * noisy), 0, 255).astype(np.uint8)
    return frames, xp.astype(np.float32), yp.astype(np.float32)


def test_wrapped_phase_recovers_phase_amplitude_mean():
    rng = np.random.default_rng(1)
    phi = rng.uniform(0, 2 * np.pi, 50)
    shifts = -2 * np.pi * np.arange(5) / 5 + 0.3
    frames = 0.4 + 0.2 * np.cos(phi[None] - shifts[:, None])
    p, b, a = wrapped_phase(frames, shifts)
    np.testing.assert_allclose(np.angle(np.exp(1j * (p - phi))), 0, atol=1e-5)
    np.testing.assert_allclose(b, 0.2, atol=1e-6)
    np.testing.assert_allclose(a, 0.4, atol=1e-6)
    assert p.dtype == np.float32 and p.min() >= 0 and p.max() < 2 * np.pi


def test_wrapped_phase_bad_shifts():
    with pytest.raises(ValueError, match="shifts"):
        wrapped_phase(np.zeros((4, 3)), [0, 1, 2])


@settings(max_examples=30, deadline=None)
@given(u=st.floats(-0.49, 1279.49), noise=st.floats(-0.3, 0.3))
def test_unwrap_recovers_coordinate_under_coarse_noise(u, noise):
    # a coarse-phase error of noise * r rad (|.| < pi/2 after scaling) must not change the order
    size = 1280
    wrap = lambda n, e=0.0: np.mod(2 * np.pi * n * (u + 0.5) / size + e, 2 * np.pi)  # noqa: E731
    phi, bad = unwrap_hierarchical([wrap(64), wrap(1, noise / 8), wrap(8, -noise / 8)],
                                   [64, 1, 8])
    got = float(phi) * size / (2 * np.pi * 64) - 0.5
    assert not bool(bad)
    # the coarse phase may wrap at the panel edge; away from it the coordinate is exact
    if 8 < u < size - 8:
        assert got == pytest.approx(u, abs=1e-3)


def test_unwrap_flags_inconsistency():
    _, bad = unwrap_hierarchical([np.array([1.0]), np.array([8.0 + np.pi * 0.8 - 2 * np.pi])],
                                   [1, 8])
    assert bool(bad[0])
    with pytest.raises(ValueError, match="coarsest"):
        unwrap_hierarchical([np.zeros(1), np.zeros(1)], [2, 8])


def test_decode_exact_patterns():
    ps = PatternSet(x=[(1, 3), (8, 3), (64, 6)], y=[(1, 4), (16, 5)], panel_size=(256, 128))
    d = decode(make_patterns(ps), ps, saturation=1.01)
    assert d.mask.all()
    np.testing.assert_allclose(d.xp, np.broadcast_to(np.arange(256.0), (128, 256)), atol=0.02)
    np.testing.assert_allclose(d.yp, np.broadcast_to(np.arange(128.0)[:, None], (128, 256)),
                               atol=0.02)
    np.testing.assert_allclose(d.albedo, 0.5, atol=0.01)
    np.testing.assert_allclose(d.modulation, 0.5, atol=0.01)
    assert d.xp.dtype == np.float32 and d.reason.dtype == np.uint8


def test_decode_other_system_negative_shift_with_cue():
    # 3-step, 16 periods plus a 1-period cue, shift sign -1 and an offset, listed fine first
    ps = PatternSet(y=[(16, 3), (1, 3)], shift_sign=-1, phase_offset=1.0, panel_size=(10, 480))
    frames = make_patterns(ps)
    d = decode(frames, ps, saturation=1.01)
    assert d.xp is None
    np.testing.assert_allclose(d.yp[:, 0], np.arange(480.0), atol=0.1)


def test_default_set_meets_precision_target_on_noisy_capture():
    """Issue 4: RMS <= 0.05 panel px and no unwrapping error, 8-bit + shot + read noise, defocus."""
    ps = default_pattern_set()
    frames, xp, yp = render_capture(ps, (120, 150), seed=3)
    d = decode(frames, ps)
    assert d.mask.mean() > 0.99
    ex, ey = (d.xp - xp)[d.mask], (d.yp - yp)[d.mask]
    rms_x, rms_y = np.sqrt(np.mean(ex**2)), np.sqrt(np.mean(ey**2))
    assert rms_x <= 0.05 and rms_y <= 0.05, (rms_x, rms_y)
    assert np.abs(ex).max() < 1.0 and np.abs(ey).max() < 1.0  # no unwrapping error


def test_masks_and_reasons():
    ps = default_pattern_set()
    h, w = 40, 50
    albedo = np.full((h, w), 0.7)
    albedo[:, :10] = 0.0  # shadow: neither ambient-only nor lit
    frames, _, _ = render_capture(ps, (h, w), albedo=albedo, ambient=0.0, seed=5)
    frames[:, 20:25, 20:25] = 255  # saturated patch
    frames[:, 30:35, 30:35] = 120  # no fringes (flat), bright
    # an inconsistent coarse level: shift the 8-period x frames by a quarter turn-ish
    frames[3:6, 0:5, 40:45] = np.roll(frames[3:6, 0:5, 40:45], 1, axis=0)
    d = decode(frames, ps)
    assert np.all(d.reason[:, :10] & SHADOW) and np.all(d.reason[:, :10] & LOW_MODULATION)
    assert np.all(d.reason[20:25, 20:25] & SATURATED)
    assert np.all(d.reason[30:35, 30:35] == LOW_MODULATION)
    assert np.all(d.reason[0:5, 40:45] & UNWRAP_ERROR)
    assert np.isnan(d.xp[~d.mask]).all() and np.isnan(d.yp[~d.mask]).all()
    assert np.all(d.intensity[~d.mask] == 0) and np.all(d.intensity[d.mask] > 0)
    assert d.mask[11:18, 11:40].all()
    assert np.all(d.reason[11:18, 10] == EDGE)  # next to the shadow
    assert np.all(d.reason[19, 20:25] == EDGE) and np.all(d.reason[25, 20:25] == EDGE)
    assert OUT_OF_PANEL not in np.unique(d.reason)
    kept = decode(frames, ps, keep_invalid=True)
    assert np.isfinite(kept.xp[30:35, 30:35]).all()


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32])
def test_fast_path_matches_reference(dtype):
    ps = default_pattern_set()
    frames, _, _ = render_capture(ps, (64, 72), seed=11)
    frames[:, 5:8, 5:8] = 255
    frames[:, 10:14, 10:14] = 90
    if dtype == np.uint16:
        frames = frames.astype(np.uint16) * 257
    elif dtype == np.float32:
        frames = normalize_frames(frames)
    ref = decode(frames, ps)
    fast = decode(frames, ps, method="numba")
    np.testing.assert_array_equal(fast.mask, ref.mask)
    # where there are no fringes the phase is rounding noise: only the other bits must agree
    low = (ref.reason & LOW_MODULATION) > 0
    assert low[10:14, 10:14].all()
    np.testing.assert_array_equal(fast.reason[~low], ref.reason[~low])
    keep = np.uint8(~UNWRAP_ERROR & 0xFF)
    np.testing.assert_array_equal(fast.reason[low] & keep, ref.reason[low] & keep)
    np.testing.assert_allclose(fast.xp, ref.xp, atol=2e-3, equal_nan=True)
    np.testing.assert_allclose(fast.yp, ref.yp, atol=2e-3, equal_nan=True)
    for name in ("modulation", "albedo", "intensity"):
        np.testing.assert_allclose(getattr(fast, name), getattr(ref, name), atol=1e-5)
    again = decode_fast(frames, ps, out=fast)
    assert again is fast


def test_fast_path_triangulates_with_table():
    from nail2nail.scan.triangulation import triangulate, triangulation_table

    ps = default_pattern_set()
    frames, _, _ = render_capture(ps, (48, 40), seed=2)
    Mc = np.array([[900.0, 0, 0, 20], [0, 900, 0, 24], [0, 0, 0.01, 1]])
    Mp = np.array([[800.0, 0, 300, 600], [0, 800, 300, 500], [0, 0, 0.01, 1]])
    table = triangulation_table(Mc, Mp, (48, 40))
    fast = decode_fast(frames, ps, table=planar_table(table))
    ref = decode(frames, ps)
    expected = triangulate(table, ref.yp)
    np.testing.assert_allclose(fast.xyz, expected, rtol=1e-4, atol=1e-3, equal_nan=True)
    assert np.isnan(fast.xyz[~fast.mask]).all()


def test_decode_bad_input():
    ps = default_pattern_set()
    with pytest.raises(ValueError, match="has 24 frames, got 3"):
        decode(np.zeros((3, 4, 4), np.uint8), ps)
    with pytest.raises(ValueError, match=r"expected shape \(n_frames, H, W\)"):
        decode(np.zeros((24, 4), np.uint8), ps)
    with pytest.raises(TypeError, match="dtype"):
        decode(np.zeros((24, 4, 4), np.int32), ps)
    with pytest.raises(TypeError, match="PatternSet"):
        decode(np.zeros((24, 4, 4), np.uint8), {"x": []})
    with pytest.raises(ValueError, match="method"):
        decode(np.zeros((24, 4, 4), np.uint8), ps, method="gpu")
    with pytest.raises(ValueError, match="table"):
        decode_fast(np.zeros((24, 4, 4), np.uint8), ps,
                    table=(np.zeros((6, 3, 3), np.float32), np.zeros((2, 3, 3), np.float32), "y"))


def test_neighbourhood_reasons_edge_and_steep():
    reason = np.zeros((9, 10), np.uint8)
    reason[4, 4] = SHADOW
    u = np.tile(np.arange(10.0, dtype=np.float32), (9, 1))
    u[:, 7:] *= 5.0  # steep from column 6 on (central differences of 1 and 11.5, 5)
    out = neighbourhood_reasons(reason, [u], erode=1, max_gradient=3.0)
    assert out[4, 4] == SHADOW
    assert np.all(out[3:6, 3:6][np.arange(9).reshape(3, 3) != 4] == EDGE)
    assert np.all(out[1:-1, 6:9] & STEEP) and not np.any(out[:, :6] & STEEP)
    assert np.all(out[0] & STEEP == 0) and out[0, 0] == 0  # border: no neighbours, no flags
    two = neighbourhood_reasons(reason, [u], erode=2, max_gradient=None)
    assert np.count_nonzero(two == EDGE) == 24


def test_fast_path_neighbourhood_matches_reference():
    ps = PatternSet(x=[(1, 3), (8, 4)], y=[(1, 3), (8, 4)], panel_size=(128, 96))
    frames, _, _ = render_capture(ps, (40, 50), seed=4)
    frames[:, 10:14, 10:14] = 0
    for kwargs in ({"erode": 2, "max_gradient": 1.2}, {"erode": 0, "max_gradient": 1.36}):
        ref = decode(frames, ps, **kwargs)
        fast = decode(frames, ps, method="numba", **kwargs)
        assert (np.count_nonzero(ref.reason & EDGE) > 0) == (kwargs["erode"] > 0)
        assert np.count_nonzero(ref.reason & STEEP) > 0
        assert np.mean(fast.reason == ref.reason) > 0.999
    with pytest.raises(ValueError, match="erode"):
        decode(frames, ps, erode=-1)
    with pytest.raises(ValueError, match="max_gradient"):
        decode_fast(frames, ps, max_gradient=0)


def test_frame_count_error_shows_the_expected_frame_table():
    """Frames that do not match the pattern set: the error lists what each frame should show."""
    ps = default_pattern_set()
    frames = make_patterns(ps)[:12]
    with pytest.raises(ValueError, match=r"has 24 frames, got 12 \(the frames it expects, in "
                       r"order: 0: x: 1 period, step 1/3; 1: x: 1 period, step 2/3;.*"
                       r"23: y: 64 periods, step 6/6\)"):
        decode(frames, ps)
