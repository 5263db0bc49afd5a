"""Tests of the print rendering (nail2nail.unroll.render), the ridge signal
(nail2nail.unroll.ridges) and the block quality (nail2nail.unroll.quality).

Synthetic inputs with known answers: constant values blended across two cameras, unit-RMS
sinusoids as ridge signals, and scans of a plane and of a cylinder carrying a 25 µm sinusoidal
relief along the normal.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.ndimage as ndi
from hypothesis import given, settings
from hypothesis import strategies as st

from nail2nail._feather import feather
from nail2nail.scan.results import Scan
from nail2nail.unroll.quality import block_quality
from nail2nail.unroll.render import (
    MM_PER_INCH,
    PrintGrid,
    binarize,
    blend_cameras,
    print_grid,
    to_gray,
)
from nail2nail.unroll.ridges import camera_layer, local_normalize, masked_gaussian, ridge_signal

RELIEF_MM = 0.025  # ridge amplitude
RIDGE_MM = 0.5  # ridge period


# -- helpers ---------------------------------------------------------------------------------
def sinusoid(shape, period_px, angle_deg=30.0, phase=0.0):
    """Unit-RMS sinusoid ``√2 sin(2π x / period)`` along direction `angle_deg`, (H, W) float."""
    rr, cc = np.mgrid[0 : shape[0], 0 : shape[1]].astype(float)
    a = np.radians(angle_deg)
    return np.sqrt(2) * np.sin(2 * np.pi * (cc * np.cos(a) + rr * np.sin(a)) / period_px + phase)


def grid_scan(xyz, camera_center, *, albedo=None, valid=None, name="grid") -> Scan:
    """A :class:`Scan` of world points on a pixel grid (projector coordinates are the pixel's)."""
    h, w = xyz.shape[:2]
    valid = np.ones((h, w), bool) if valid is None else valid
    rr, cc = np.mgrid[0:h, 0:w].astype(np.float32)
    albedo = np.full((h, w), 0.6, np.float32) if albedo is None else albedo
    half = np.full((h, w), 0.5, np.float32)
    xyz = np.where(valid[..., None], xyz, np.nan).astype(np.float32)
    return Scan(name=name, xyz=xyz, xp=np.where(valid, cc, np.nan), yp=np.where(valid, rr, np.nan),
                albedo=np.asarray(albedo, np.float32), intensity=half, modulation=half,
                mask=valid, camera_center=np.asarray(camera_center, float))


def plane_with_relief(shape=(160, 180), spacing=0.05, angle=0.4):
    """Plane z = 0 seen from +Z, relief ``h`` (mm) along +Z: returns ``(xyz, h)``."""
    rr, cc = np.mgrid[0 : shape[0], 0 : shape[1]] * spacing
    h = RELIEF_MM * np.sin(2 * np.pi * (cc * np.cos(angle) + rr * np.sin(angle)) / RIDGE_MM)
    return np.stack([cc, rr, h], -1), h


def cylinder_with_relief(radius=8.0, shape=(160, 336), spacing=0.05, angle=0.7):
    """A cylinder about world Y (±60° around the pad, +Z), relief ``h`` along the radius."""
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]].astype(float)
    theta = (cols - shape[1] / 2) * spacing / radius
    y = rows * spacing - shape[0] * spacing / 2
    h = RELIEF_MM * np.sin(2 * np.pi * (radius * theta * np.cos(angle) + y * np.sin(angle))
                           / RIDGE_MM)
    rho = radius + h
    return np.stack([rho * np.sin(theta), y, rho * np.cos(theta)], -1), h


def _corr(a, b):
    ok = np.isfinite(a) & np.isfinite(b)
    return float(np.corrcoef(a[ok], b[ok])[0, 1])


# -- PrintGrid / print_grid ------------------------------------------------------------------
@settings(max_examples=50, deadline=None)
@given(s0=st.floats(-50, 50), t0=st.floats(-50, 50), ppi=st.floats(100, 4000),
       seed=st.integers(0, 2**16))
def test_print_grid_pixel_plane_round_trip(s0, t0, ppi, seed):
    grid = PrintGrid(s0, t0, MM_PER_INCH / ppi, (100, 80))
    pts = np.random.default_rng(seed).uniform(-60, 60, (25, 2))
    r, c = grid.pixel(pts)
    assert r.shape == c.shape == (25,)
    np.testing.assert_allclose(grid.plane(r, c), pts, atol=1e-9)
    rows, cols = np.random.default_rng(seed + 1).uniform(-10, 500, (2, 25))
    r2, c2 = grid.pixel(grid.plane(rows, cols))
    np.testing.assert_allclose(r2, rows, atol=1e-7)
    np.testing.assert_allclose(c2, cols, atol=1e-7)


def test_print_grid_orientation_is_legacy():
    # mirror of the pad view (s decreases to the right), tip up (t decreases downwards)
    grid = PrintGrid(2.0, 3.0, 0.05, (10, 10))
    np.testing.assert_allclose(grid.plane(0, 0), [2.0, 3.0])
    np.testing.assert_allclose(grid.plane(0, 1) - grid.plane(0, 0), [-0.05, 0.0], atol=1e-12)
    np.testing.assert_allclose(grid.plane(1, 0) - grid.plane(0, 0), [0.0, -0.05], atol=1e-12)


@pytest.mark.parametrize("ppi", [250.0, 500.0, 1000.0, 333.3])
def test_print_grid_pitch_and_cover(ppi):
    pts = np.random.default_rng(0).uniform([-8, -12], [9, 14], (5000, 2))
    grid = print_grid(pts, ppi=ppi)
    assert grid.pitch == MM_PER_INCH / ppi
    assert abs(grid.ppi - ppi) < 1e-9
    # s0, t0 on the lattice of the pitch; every point inside the grid with the 1 mm margin
    assert grid.s0 / grid.pitch == pytest.approx(round(grid.s0 / grid.pitch), abs=1e-6)
    assert grid.t0 / grid.pitch == pytest.approx(round(grid.t0 / grid.pitch), abs=1e-6)
    r, c = grid.pixel(pts)
    margin = 1.0 / grid.pitch
    assert r.min() >= margin - 1 and c.min() >= margin - 1
    assert r.max() <= grid.shape[0] - margin and c.max() <= grid.shape[1] - margin
    d = grid.describe()
    assert d["shape"] == list(grid.shape) and d["pitch_mm"] == grid.pitch


@pytest.mark.parametrize("ppi", [0, -500.0, float("nan")])
def test_print_grid_bad_ppi(ppi):
    with pytest.raises(ValueError, match="ppi: expected a positive number"):
        print_grid(np.zeros((10, 2)), ppi=ppi)


# -- blend_cameras ---------------------------------------------------------------------------
def _two_cameras(value_a=3.25, value_b=3.25, weight_a=1.0, weight_b=3.0, n=60000, seed=0):
    rng = np.random.default_rng(seed)
    st_a = rng.uniform([-5.0, -3.0], [1.0, 3.0], (n, 2))
    st_b = rng.uniform([-1.0, -3.0], [5.0, 3.0], (n, 2))
    return [(st_a, np.full(n, value_a), np.full(n, weight_a)),
            (st_b, np.full(n, value_b), np.full(n, weight_b))]


@pytest.fixture(scope="module")
def blended():
    samples = _two_cameras()
    grid = print_grid(np.concatenate([s for s, _, _ in samples]), ppi=500.0)
    return grid, blend_cameras(grid, samples)


def test_blend_cameras_shapes_and_dtypes(blended):
    grid, (value, mask, share) = blended
    assert value.shape == mask.shape == grid.shape
    assert share.shape == (2, *grid.shape)
    assert value.dtype == np.float32 and mask.dtype == bool and share.dtype == np.float32
    assert mask.mean() > 0.5
    assert np.isnan(value[~mask]).all()


def test_blend_cameras_constant_gives_the_constant(blended):
    _, (value, mask, _) = blended
    np.testing.assert_allclose(value[mask], 3.25, rtol=1e-6)


def test_blend_cameras_shares_sum_to_one(blended):
    grid, (_, mask, share) = blended
    np.testing.assert_allclose(share.sum(axis=0)[mask], 1.0, atol=1e-5)
    assert (share[:, ~mask] == 0).all()
    assert (share >= 0).all()
    # camera A alone left of s = −1 (right of the image: s decreases with the column), camera
    # B alone right of s = 1; in the overlap the weights 1 : 3 at equal sample densities (per
    # pixel the share follows the local sample count too: only its mean is 1/4)
    s = grid.plane(*np.nonzero(mask))[:, 0]
    sa = share[0][mask]
    np.testing.assert_allclose(sa[s < -1.5], 1.0, atol=1e-4)
    assert float(np.mean(sa[np.abs(s) < 0.5])) == pytest.approx(0.25, abs=0.01)
    np.testing.assert_allclose(sa[s > 1.5], 0.0, atol=1e-4)


def test_blend_cameras_value_is_the_share_weighted_mean():
    grid, samples = _grid_and(_two_cameras(value_a=1.0, value_b=5.0))
    value, mask, share = blend_cameras(grid, samples)
    np.testing.assert_allclose(value[mask], 1.0 * share[0][mask] + 5.0 * share[1][mask],
                               rtol=1e-5)
    s = grid.plane(*np.nonzero(mask))[:, 0]
    v = value[mask]
    np.testing.assert_allclose(v[s < -1.5], 1.0, rtol=1e-6)
    np.testing.assert_allclose(v[s > 1.5], 5.0, rtol=1e-6)
    assert float(np.mean(v[np.abs(s) < 0.5])) == pytest.approx((1 * 1.0 + 3 * 5.0) / 4, abs=0.05)


def _grid_and(samples, ppi=500.0):
    return print_grid(np.concatenate([s for s, _, _ in samples]), ppi=ppi), samples


def _splat_reference(grid, samples):
    """Plain loop: bilinear splat ``Σ w k v`` and ``Σ w k`` per pixel."""
    h, w = grid.shape
    num, den = np.zeros((h, w)), np.zeros((h, w))
    for st_, val, wt in samples:
        r, c = grid.pixel(st_)
        for ri, ci, vi, wi in zip(r, c, val, wt, strict=True):
            r0, c0 = int(np.floor(ri)), int(np.floor(ci))
            for dr in (0, 1):
                for dc in (0, 1):
                    k = (1 - abs(ri - r0 - dr)) * (1 - abs(ci - c0 - dc))
                    if 0 <= r0 + dr < h and 0 <= c0 + dc < w:
                        num[r0 + dr, c0 + dc] += wi * k * vi
                        den[r0 + dr, c0 + dc] += wi * k
    return num, den


def test_blend_cameras_agrees_with_plain_splat():
    rng = np.random.default_rng(4)
    grid = PrintGrid(1.0, 1.0, 0.1, (20, 20))
    samples = []
    for _ in range(2):
        st_ = rng.uniform(-0.9, 0.95, (1500, 2))
        samples.append((st_, rng.normal(size=1500), rng.uniform(0.2, 1.0, 1500)))
    value, mask, _ = blend_cameras(grid, samples, fill_sigma_px=0.0, min_support=0.5)
    num, den = _splat_reference(grid, samples)
    assert mask.sum() > 200
    np.testing.assert_allclose(value[mask], (num / den)[mask], rtol=1e-5, atol=1e-6)


# -- to_gray / binarize ----------------------------------------------------------------------
@pytest.fixture(scope="module")
def ridges():
    """A unit-RMS sinusoid of 9.5 px period inside a rectangular mask."""
    v = sinusoid((160, 160), 9.5)
    mask = np.zeros(v.shape, bool)
    mask[20:140, 15:150] = True
    return v, mask


def test_to_gray_dtype_and_background(ridges):
    v, mask = ridges
    gray = to_gray(np.where(mask, v, np.nan), mask, sigma_px=20.0)
    assert gray.dtype == np.uint8 and gray.shape == v.shape
    assert (gray[~mask] == 255).all()
    # a unit-RMS sinusoid spans about 0–255
    assert gray[mask].min() < 10 and gray[mask].max() > 245
    assert abs(float(gray[mask].mean()) - 127.5) < 2


def test_to_gray_ridges_dark_on_crests(ridges):
    v, mask = ridges
    gray = to_gray(np.where(mask, v, np.nan), mask, sigma_px=20.0)
    dark = gray[mask] < 128
    crest = v[mask] > 0
    assert np.mean(dark == crest) > 0.999
    clear = np.abs(v[mask]) > 0.3  # away from the zero crossings: every pixel
    assert (dark[clear] == crest[clear]).all()
    # I = 127.5 − 90 z with z ≈ v here
    np.testing.assert_allclose((127.5 - gray[mask].astype(float)) / 90, v[mask], atol=0.05)


@settings(max_examples=20, deadline=None)
@given(scale=st.floats(0.01, 100.0), offset=st.floats(-10.0, 10.0))
def test_to_gray_ignores_gain_and_offset(ridges, scale, offset):
    v, mask = ridges
    ref = to_gray(np.where(mask, v, np.nan), mask, sigma_px=20.0).astype(int)
    out = to_gray(np.where(mask, scale * v + offset * scale, np.nan), mask, sigma_px=20.0)
    assert np.abs(out.astype(int) - ref).max() <= 1


def _harmonic(z, mask, period_px, angle_deg=30.0):
    """Amplitude of the sinusoid of `period_px` along `angle_deg` in `z` over `mask` (least
    squares on its sine and cosine)."""
    a = sinusoid(z.shape, period_px, angle_deg) / np.sqrt(2)
    b = sinusoid(z.shape, period_px, angle_deg, phase=np.pi / 2) / np.sqrt(2)
    basis = np.stack([a[mask], b[mask]], -1)
    coef, *_ = np.linalg.lstsq(basis, z[mask], rcond=None)
    return float(np.hypot(*coef))


def test_to_gray_sharpen_zero_is_the_plain_print(ridges):
    v, mask = ridges
    plain = to_gray(np.where(mask, v, np.nan), mask, sigma_px=20.0)
    off = to_gray(np.where(mask, v, np.nan), mask, sigma_px=20.0, sharpen=0.0,
                  sharpen_sigma_px=1.5)
    np.testing.assert_array_equal(off, plain)


@settings(max_examples=10, deadline=None)
@given(amount=st.floats(0.5, 4.0), sigma=st.floats(0.8, 2.5))
def test_to_gray_sharpen_leaves_a_sinusoid_as_it_is(ridges, amount, sigma):
    """A linear filter changes a pure sinusoid's amplitude only, which is brought back."""
    v, mask = ridges
    plain = to_gray(np.where(mask, v, np.nan), mask, sigma_px=20.0).astype(int)
    sharp = to_gray(np.where(mask, v, np.nan), mask, sigma_px=20.0, sharpen=amount,
                    sharpen_sigma_px=sigma).astype(int)
    inner = ndi.binary_erosion(mask, iterations=int(4 * sigma) + 2)
    assert np.abs(sharp[inner] - plain[inner]).max() <= 2
    assert (sharp[~mask] == 255).all()


@pytest.mark.parametrize(("amount", "sigma"), [(2.0, 1.5), (1.0, 1.0), (3.0, 2.0)])
def test_to_gray_sharpen_raises_the_harmonic_by_the_unsharp_gain(ridges, amount, sigma):
    """Fundamental (period 12 px) plus its third harmonic: their amplitude ratio grows by
    ``(1 + a(1 − G(3f))) / (1 + a(1 − G(f)))``, ``G(f) = exp(−2π²σ²f²)``."""
    _, mask = ridges
    period = 12.0
    v = sinusoid(mask.shape, period) + 0.3 * sinusoid(mask.shape, period / 3)
    inner = ndi.binary_erosion(mask, iterations=int(4 * sigma) + 2)

    def ratio(gray):
        z = (127.5 - gray.astype(float)) / 90
        return _harmonic(z, inner, period / 3) / _harmonic(z, inner, period)

    plain = to_gray(np.where(mask, v, np.nan), mask, sigma_px=40.0)
    sharp = to_gray(np.where(mask, v, np.nan), mask, sigma_px=40.0, sharpen=amount,
                    sharpen_sigma_px=sigma)

    def gain(f):
        return 1 + amount * (1 - np.exp(-2 * np.pi**2 * sigma**2 * f**2))

    expected = gain(3 / period) / gain(1 / period)
    assert ratio(sharp) / ratio(plain) == pytest.approx(expected, rel=0.03)
    # the grey levels keep their span: the RMS is brought back (clipping aside)
    z_plain = (127.5 - plain[inner].astype(float)) / 90
    z_sharp = (127.5 - sharp[inner].astype(float)) / 90
    assert np.sqrt(np.mean(z_sharp**2)) == pytest.approx(np.sqrt(np.mean(z_plain**2)), rel=0.05)


def test_binarize_marks_crests(ridges):
    v, mask = ridges
    gray = to_gray(np.where(mask, v, np.nan), mask, sigma_px=20.0)
    binary = binarize(gray, mask, period_px=9.5)
    assert binary.dtype == np.uint8 and binary.shape == v.shape
    assert set(np.unique(binary)) <= {0, 255}
    assert (binary[~mask] == 255).all()
    ridge = binary[mask] == 0
    assert np.mean(ridge == (v[mask] > 0)) > 0.98
    inner = ndi.binary_erosion(mask, iterations=10)
    assert np.mean((binary[inner] == 0) == (v[inner] > 0)) > 0.999


# -- block_quality ---------------------------------------------------------------------------
def test_block_quality_shapes():
    img = sinusoid((100, 130), 8.0)
    mask = np.ones(img.shape, bool)
    q = block_quality(img, mask, block_px=32, step_px=32)
    assert q["grid"].shape == (3, 4) and q["grid"].dtype == np.float32
    for key in ("rows", "cols", "period_px", "clarity"):
        assert q[key].shape == (12,)
    assert ((q["clarity"] >= 0) & (q["clarity"] <= 1)).all()
    np.testing.assert_allclose(sorted(set(q["rows"])), [15.5, 47.5, 79.5])
    # default: blocks overlap by half
    half = block_quality(img, mask, block_px=32)
    assert half["grid"].shape == (5, 7) and half["step_px"] == 16


def test_block_quality_only_blocks_inside_the_mask():
    img = sinusoid((96, 96), 8.0)
    mask = np.ones(img.shape, bool)
    mask[40, 70] = False  # spoils block (1, 2)
    q = block_quality(img, mask, block_px=32, step_px=32)
    assert q["clarity"].size == 8
    assert np.isnan(q["grid"][1, 2]) and np.isfinite(np.delete(q["grid"].ravel(), 5)).all()
    empty = block_quality(img, np.zeros(img.shape, bool), block_px=32)
    assert empty["period_px"].size == 0 and np.isnan(empty["grid"]).all()


def test_block_quality_is_its_definition_block_by_block():
    """The ring sums taken per distinct radius equal the module docstring's definition computed
    directly for each block: the Hann-windowed block zero-padded to twice its size (the real
    FFT's half-plane), the
    spectral peak in the band, the ring ±(25 % + 1 / block) around it, the ring's share of the
    AC energy and its energy-weighted radius."""
    rng = np.random.default_rng(5)
    img = sinusoid((96, 96), 7.0, 20.0) + 0.8 * rng.standard_normal((96, 96))
    n, lo, hi = 32, 4.0, 25.0
    q = block_quality(img, np.ones(img.shape, bool), block_px=n, step_px=32,
                      min_period_px=lo, max_period_px=hi)
    win = np.outer(np.hanning(n), np.hanning(n))
    # the half-plane of the real FFT, as block_quality transforms it
    fy, fx = np.meshgrid(np.fft.fftfreq(2 * n), np.fft.rfftfreq(2 * n), indexing="ij")
    radius = np.hypot(fy, fx)
    for k, (r, c) in enumerate(zip(q["rows"], q["cols"], strict=True)):
        r0, c0 = int(r - (n - 1) / 2), int(c - (n - 1) / 2)
        b = img[r0:r0 + n, c0:c0 + n]
        spec = np.abs(np.fft.rfft2((b - b.mean()) * win, s=(2 * n, 2 * n))) ** 2
        band = (radius >= 1 / hi) & (radius <= 1 / lo)
        peak = radius[np.unravel_index(np.argmax(np.where(band, spec, 0)), spec.shape)]
        ring = (np.abs(radius - peak) <= 0.25 * peak + 1 / n) & (radius > 0)
        clarity = spec[ring].sum() / spec[radius > 0].sum()
        period = spec[ring].sum() / (spec[ring] * radius[ring]).sum()
        assert q["clarity"][k] == pytest.approx(clarity, rel=1e-9)
        assert q["period_px"][k] == pytest.approx(period, rel=1e-9)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31), st.floats(0.001, 0.999), st.booleans())
def test_weighted_quantiles_without_a_full_sort_are_the_sorted_ones(seed, q, ties):
    """Above 4096 values the quantile's value bin is found first and only it is sorted; the
    answer is the full sort's (the smallest value whose cumulative weight fraction reaches q),
    with ties, zero weights and skewed values (q = 1 is left out: there the two sums' last
    rounding decides)."""
    from nail2nail._quantile import weighted_quantiles

    rng = np.random.default_rng(seed)
    n = int(rng.integers(5000, 40000))
    x = rng.lognormal(size=n)
    if ties:
        x = np.round(x, 1)
    w = rng.random(n) * (rng.random(n) > 0.3)
    order = np.argsort(x)
    cw = np.cumsum(w[order]) / w.sum()
    expected = x[order][min(int(np.searchsorted(cw, q)), n - 1)]
    assert weighted_quantiles(x, w, [q])[0] == expected


@pytest.mark.parametrize("angle", [0.0, 30.0, 77.0])
def test_block_quality_period_and_clarity_in_large_blocks(angle):
    img = sinusoid((192, 192), 9.5, angle)
    q = block_quality(img, np.ones(img.shape, bool), block_px=64)
    np.testing.assert_allclose(q["period_px"], 9.5, rtol=0.02)
    assert q["clarity"].min() > 0.95


@pytest.mark.parametrize("angle", [0.0, 30.0, 77.0])
def test_block_quality_period_on_a_bin_in_default_blocks(angle):
    # 8 px is 4 cycles per 32 px block: on the FFT grid
    img = sinusoid((128, 128), 8.0, angle)
    q = block_quality(img, np.ones(img.shape, bool))
    np.testing.assert_allclose(q["period_px"], 8.0, rtol=0.03)
    assert q["clarity"].min() > 0.85


@pytest.mark.parametrize("angle", [0.0, 77.0])
def test_block_quality_recovers_period_between_bins(angle):
    # regression: 32 px blocks snapped the period to the FFT bin (9.5 px read as 10.47 px)
    img = sinusoid((128, 128), 9.5, angle)
    q = block_quality(img, np.ones(img.shape, bool))
    np.testing.assert_allclose(q["period_px"], 9.5, rtol=0.02)
    assert q["clarity"].min() > 0.8


def test_block_quality_clean_ridges_clearer_than_noise():
    clean = block_quality(sinusoid((128, 128), 9.5), np.ones((128, 128), bool))
    noise = np.random.default_rng(0).standard_normal((128, 128))
    noisy = block_quality(noise, np.ones((128, 128), bool))
    assert clean["clarity"].min() > 0.4
    assert noisy["clarity"].max() < 0.2


# -- ridge_signal ----------------------------------------------------------------------------
def test_ridge_signal_plane_follows_the_relief():
    xyz, h = plane_with_relief()
    sig = ridge_signal(grid_scan(xyz, (4.0, 4.0, 100.0)), albedo_weight=0.0)
    assert sig.shape == h.shape and sig.dtype == np.float32
    assert np.isfinite(sig).mean() > 0.9
    assert _corr(sig, h) > 0.99
    ok = np.isfinite(sig)
    assert np.sqrt(np.mean(sig[ok] ** 2)) == pytest.approx(1.0, abs=0.05)  # unit local RMS


def test_ridge_signal_cylinder_follows_the_relief():
    xyz, h = cylinder_with_relief()
    sig = ridge_signal(grid_scan(xyz, (0.0, 0.0, 100.0)), albedo_weight=0.0)
    assert _corr(sig, h) > 0.9
    # away from the scan's rim, where the smooth surface is one-sided
    inner = ndi.binary_erosion(np.isfinite(sig), iterations=20)
    assert _corr(np.where(inner, sig, np.nan), h) > 0.98


def test_ridge_signal_sign_follows_the_camera_side():
    # the relief is measured along the normal towards the camera: seen from inside, crests flip
    xyz, h = cylinder_with_relief()
    sig = ridge_signal(grid_scan(xyz, (0.0, 0.0, -100.0)), albedo_weight=0.0)
    assert _corr(sig, h) < -0.9


def test_ridge_signal_with_ridge_albedo():
    xyz, h = plane_with_relief()
    albedo = (0.6 + 0.1 * h / RELIEF_MM).astype(np.float32)  # ridges brighter, as on skin
    sig = ridge_signal(grid_scan(xyz, (4.0, 4.0, 100.0), albedo=albedo))
    assert _corr(sig, h) > 0.99


def test_ridge_signal_nan_off_valid():
    xyz, h = plane_with_relief()
    valid = np.ones(h.shape, bool)
    valid[:, :30] = False
    valid[100:, 120:] = False
    sig = ridge_signal(grid_scan(xyz, (4.0, 4.0, 100.0), valid=valid), albedo_weight=0.0)
    assert np.isnan(sig[~valid]).all()
    assert _corr(np.where(valid, sig, np.nan), h) > 0.98


def test_camera_layer_weighs_every_valid_pixel_up_to_the_outline():
    # a camera alone on a patch of skin: its outline keeps a weight (a zero weight along it
    # left the fingertip's last mm out of the print), and the ramp is the merge's feather
    xyz, h = plane_with_relief()
    rr, cc = np.mgrid[0:h.shape[0], 0:h.shape[1]]
    valid = (rr - 80) ** 2 / 70**2 + (cc - 90) ** 2 / 83**2 < 1
    scan = grid_scan(xyz, (4.0, 4.0, 100.0), valid=valid)
    signal, weight = camera_layer(scan, albedo_weight=0.0, feather_px=40.0)
    ok = valid & np.isfinite(signal)
    assert ok.sum() > 0.95 * valid.sum()
    assert (weight[ok] > 0).all() and (weight[~valid] == 0).all()
    _, flat = camera_layer(scan, albedo_weight=0.0, feather_px=0.0)  # no ramp
    # the ramp from the edge of the pixels with a relief (the valid ones less a rim where the
    # smooth surface has no normal)
    np.testing.assert_allclose(weight[ok] / flat[ok], feather(ok, 40.0)[ok], rtol=1e-6)


def test_ridge_signal_no_valid_pixels():
    xyz, h = plane_with_relief((20, 20))
    scan = grid_scan(xyz, (0.0, 0.0, 100.0), valid=np.zeros(h.shape, bool), name="camX")
    with pytest.raises(ValueError, match="scan 'camX': no valid pixels"):
        ridge_signal(scan)


def test_ridge_signal_uniform_albedo_adds_nothing():
    xyz, h = plane_with_relief()
    with_albedo = ridge_signal(grid_scan(xyz, (4.0, 4.0, 100.0)))  # albedo 0.6 everywhere
    assert _corr(with_albedo, h) > 0.99


def test_local_normalize_of_a_constant_is_zero():
    values = np.full((160, 180), 0.6, np.float32)
    out = local_normalize(values, np.ones(values.shape, bool), 20.0, reduce=3)
    assert np.nanmax(np.abs(out)) < 1e-3


@pytest.mark.parametrize("reduce, tol", [(1, 1e-6), (2, 0.005), (3, 0.01), (4, 0.02)])
def test_masked_gaussian_reduced_agrees_with_full(reduce, tol):
    # the reduced-grid fast path against the full-resolution average of a smooth field (range
    # ±2): block averaging and bilinear interpolation cost of the order of 1/2 % at σ/reduce = 3
    rr, cc = np.mgrid[0:90, 0:110].astype(np.float32)
    values = np.sin(rr / 15.0) + np.cos(cc / 20.0)
    valid = np.ones(values.shape, bool)
    full = masked_gaussian(values, valid, 12.0)
    fast = masked_gaussian(values, valid, 12.0, reduce=reduce)
    assert fast.shape == full.shape
    inner = (slice(30, -30), slice(30, -30))
    np.testing.assert_allclose(fast[inner], full[inner], atol=tol)


def test_masked_gaussian_reduced_keeps_float32():
    values = np.ones((40, 50), np.float32)
    out = masked_gaussian(values, np.ones(values.shape, bool), 6.0, reduce=2)
    assert out.dtype == np.float32


def test_blend_cameras_keeps_a_large_piece_parted_by_a_gap():
    """A band of skin without samples parts the print: the smaller piece stays if it is large
    (a tip's cap beyond a shadow line), specks go."""
    grid = PrintGrid(10.0, 10.0, 0.05, (400, 400))
    rng = np.random.default_rng(3)
    st = rng.uniform(-9.9, 9.9, (400_000, 2))
    st = st[np.abs(st[:, 1] - 4.0) > 1.0]  # a 2 mm band without data: pieces of 6 and 12 mm
    speck = rng.uniform(-9.0, -8.8, (400, 2))  # 0.2 mm square, apart from both
    speck[:, 1] += 13.0
    st = np.concatenate([st[st[:, 1] < 3.0], st[st[:, 1] > 5.0], speck])
    _, mask, _ = blend_cameras(grid, [(st, np.ones(len(st)), np.ones(len(st)))])
    t = grid.plane(*np.nonzero(mask))[:, 1]
    assert (t > 5.5).sum() > 0.3 * (t < 2.5).sum()  # the smaller piece kept
    assert not ((t > 3.5) & (t < 4.5)).any()  # the gap stays a gap
    s = grid.plane(*np.nonzero(mask))[:, 0]
    assert not ((s < -8.7) & (t > 3.9) & (t < 4.3)).any()  # the speck dropped


@pytest.mark.parametrize("amount", [-0.5, 10.5, float("nan"), float("inf"), "2"])
def test_unroll_refuses_a_bad_sharpen_amount(amount):
    from nail2nail.unroll import unroll_scans

    xyz, _ = plane_with_relief((40, 40))
    scan = grid_scan(xyz, (0.0, 0.0, 100.0))
    with pytest.raises(ValueError, match="sharpen"):
        unroll_scans([scan], sharpen=amount)
