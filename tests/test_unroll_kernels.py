"""Tests of the compiled steps of the unroll (nail2nail.unroll._kernels).

Each kernel against the NumPy code it replaced, to the last bit (the print must not change):
the block means and the bilinear upsampling of ``masked_gaussian``, the normals and relief of
``camera_layer``, the rolled map, the splat, the cylinder fit's residual and the print grid's
percentiles; then the whole ``unroll_scans`` on a small virtual finger against the same
pipeline run with the former NumPy steps.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.ndimage as ndi

from nail2nail._quantile import weighted_quantiles
from nail2nail.calibration.files import RigCalibration
from nail2nail.io.capture import Capture
from nail2nail.scan.capture import scan_capture
from nail2nail.simulation.capture import simulate
from nail2nail.simulation.rig import default_rig, ideal_calibration
from nail2nail.unroll import _kernels as K
from nail2nail.unroll import flatten, render, ridges, rolled, unroll_scans
from nail2nail.unroll.render import PrintGrid


# -- the former NumPy code -------------------------------------------------------------------
def ref_block_mean(v, m, f):
    """``masked_gaussian``'s former block means: masked, zero-padded, reshaped, averaged."""
    v = np.where(m[..., None], v, 0).astype(np.float32)
    m = m.astype(np.float32)
    h, w = m.shape
    hp, wp = -(-h // f) * f, -(-w // f) * f
    vp = np.zeros((hp, wp, v.shape[2]), np.float32)
    mp = np.zeros((hp, wp), np.float32)
    vp[:h, :w], mp[:h, :w] = v, m
    return (vp.reshape(hp // f, f, wp // f, f, -1).mean(axis=(1, 3)),
            mp.reshape(hp // f, f, wp // f, f).mean(axis=(1, 3)))


def ref_upsample(out, r0, r1, fr, c0, c1, fc):
    fr, fc = fr[:, None, None], fc[None, :, None]
    tall = out[r0] * (1 - fr) + out[r1] * fr
    return tall[:, c0] * (1 - fc) + tall[:, c1] * fc


def ref_masked_gaussian(values, valid, sigma_px, *, reduce=1, curvature=False):
    """``masked_gaussian`` as it was before the compiled steps (the curvature correction, on
    the reduced grid, as ``ridges`` has it)."""
    v = np.asarray(values, dtype=np.float32)
    m = np.asarray(valid, dtype=np.float32)
    squeeze = v.ndim == 2
    if squeeze:
        v = v[..., None]
    h, w = m.shape
    f = max(1, int(reduce))
    if f > 1:
        v, m = ref_block_mean(v, m > 0, f)
    else:
        v = np.where(m[..., None] > 0, v, 0).astype(np.float32)
    s = sigma_px / f
    num = np.stack([ndi.gaussian_filter(v[..., k], s, truncate=3.0) for k in range(v.shape[2])],
                   -1)
    den = ndi.gaussian_filter(m, s, truncate=3.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(den[..., None] > 1e-3, num / den[..., None], np.nan).astype(np.float32)
    if curvature:
        out = out - np.float32(0.5 * s * s) * ridges._laplacian(out)
    if f > 1:
        rows = (np.arange(h, dtype=np.float32) - (f - 1) / 2) / f
        cols = (np.arange(w, dtype=np.float32) - (f - 1) / 2) / f
        rows = np.clip(rows, 0, out.shape[0] - 1)
        cols = np.clip(cols, 0, out.shape[1] - 1)
        r0 = np.minimum(rows.astype(np.intp), out.shape[0] - 2) if out.shape[0] > 1 \
            else np.zeros(h, np.intp)
        c0 = np.minimum(cols.astype(np.intp), out.shape[1] - 2) if out.shape[1] > 1 \
            else np.zeros(w, np.intp)
        r1 = np.minimum(r0 + 1, out.shape[0] - 1)
        c1 = np.minimum(c0 + 1, out.shape[1] - 1)
        out = ref_upsample(out, r0, r1, (rows - r0).astype(np.float32), c0, c1,
                           (cols - c0).astype(np.float32))
    out = out.astype(np.float32, copy=False)
    return out[..., 0] if squeeze else out


def ref_local_normalize(values, valid, sigma_px, *, reduce=1, floor_fraction=0.0,
                        floor_percentile=90.0, level_weights=None):
    """``local_normalize`` as it was before the compiled steps (with the RMS floor)."""
    v = np.where(valid, values, np.nan).astype(np.float32)
    mean = ref_masked_gaussian(v, valid, sigma_px, reduce=reduce)
    d = v - mean
    ok = valid & np.isfinite(d)
    mean_square = ref_masked_gaussian(d * d, ok, sigma_px, reduce=reduce)
    rms = np.sqrt(mean_square)
    floor = 1e-4 * float(np.nanmean(np.abs(v))) + 1e-12 if valid.any() else 1e-12
    use = ok & np.isfinite(mean_square)
    if floor_fraction > 0 and use.any():
        w = np.ones(int(use.sum())) if level_weights is None \
            else np.nan_to_num(np.asarray(level_weights, np.float64)[use])
        level = np.sqrt(weighted_quantiles(mean_square[use], w, [floor_percentile / 100])[0])
        floor = max(floor, floor_fraction * float(level))
    with np.errstate(invalid="ignore", divide="ignore"):
        out = d / np.maximum(rms, floor)
    return np.where(valid, out, np.nan).astype(np.float32)


def ref_splat(grid, st, values, weights):
    """The former ``np.bincount`` splat: ``Σ w·k·v``, ``Σ w·k``, ``Σ k``."""
    h, w = grid.shape
    r, c = grid.pixel(st)
    r0, c0 = np.floor(r).astype(np.intp), np.floor(c).astype(np.intp)
    fr, fc = (r - r0).astype(np.float32), (c - c0).astype(np.float32)
    values = np.asarray(values, np.float32)
    weights = np.asarray(weights, np.float32)
    num, den, cnt = (np.zeros(h * w) for _ in range(3))
    wv = weights * values
    for dr, dc, k in ((0, 0, (1 - fr) * (1 - fc)), (0, 1, (1 - fr) * fc),
                      (1, 0, fr * (1 - fc)), (1, 1, fr * fc)):
        rr, cc = r0 + dr, c0 + dc
        ok = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
        idx = rr[ok] * w + cc[ok]
        kk = k[ok]
        num += np.bincount(idx, kk * wv[ok], minlength=h * w)
        den += np.bincount(idx, kk * weights[ok], minlength=h * w)
        cnt += np.bincount(idx, kk, minlength=h * w)
    return num.reshape(h, w), den.reshape(h, w), cnt.reshape(h, w)


def ref_print_grid(st_all, *, ppi, margin_mm=1.0):
    if isinstance(st_all, list):  # unroll_scans concatenated the cameras' samples
        st_all = np.concatenate(st_all)
    pitch = render.MM_PER_INCH / ppi
    lo = np.percentile(st_all, 0.01, axis=0) - margin_mm
    hi = np.percentile(st_all, 99.99, axis=0) + margin_mm
    s0 = np.ceil(hi[0] / pitch) * pitch
    t0 = np.ceil(hi[1] / pitch) * pitch
    w = int(np.ceil((s0 - lo[0]) / pitch)) + 1
    h = int(np.ceil((t0 - lo[1]) / pitch)) + 1
    return PrintGrid(s0, t0, pitch, (h, w))


def ref_axis_distance(d, axis, radius=0.0):
    return np.linalg.norm(d - np.outer(d @ axis, axis), axis=1) - radius


def ref_scan_valid(scan):
    return np.asarray(scan.mask, dtype=bool) & ridges.finite_points(scan.xyz)


def same(a, b) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b, equal_nan=True)


# -- kernels ---------------------------------------------------------------------------------
@pytest.mark.parametrize("k", [1, 2, 3])
@pytest.mark.parametrize("f", [2, 3, 7, 8, 12, 17])
def test_block_mean_matches_numpy(k, f):
    rng = np.random.default_rng(f * 10 + k)
    v = (rng.normal(size=(101, 67, k)) * 30 + 40).astype(np.float32)
    m = rng.random((101, 67)) > 0.2
    vs, ms = K.block_mean(v, m, f)
    rv, rm = ref_block_mean(v, m, f)
    assert same(vs, rv) and same(ms, rm)


def test_block_mean_nan_inside_mask_propagates():
    v = np.ones((8, 8, 1), np.float32)
    v[1, 1] = np.nan
    vs, _ = K.block_mean(v, np.ones((8, 8), bool), 4)
    assert np.isnan(vs[0, 0, 0]) and np.isfinite(vs[1, 1, 0])


@pytest.mark.parametrize("k", [1, 3])
def test_upsample_matches_numpy(k):
    rng = np.random.default_rng(k)
    small = rng.normal(size=(13, 9, k)).astype(np.float32)
    small[3, 4] = np.nan
    h, w, f = 97, 70, 8
    rows = np.clip((np.arange(h, dtype=np.float32) - (f - 1) / 2) / f, 0, 12)
    cols = np.clip((np.arange(w, dtype=np.float32) - (f - 1) / 2) / f, 0, 8)
    r0 = np.minimum(rows.astype(np.intp), 11)
    c0 = np.minimum(cols.astype(np.intp), 7)
    fr, fc = (rows - r0).astype(np.float32), (cols - c0).astype(np.float32)
    args = (small, r0, np.minimum(r0 + 1, 12), fr, c0, np.minimum(c0 + 1, 8), fc)
    assert same(K.upsample(*args), ref_upsample(*args))


@pytest.mark.parametrize("reduce", [1, 4, 7, 8])
def test_masked_gaussian_matches_former(reduce):
    rng = np.random.default_rng(reduce)
    v = (rng.normal(size=(90, 75, 3)) * 5 + 20).astype(np.float32)
    m = np.zeros((90, 75), bool)
    m[10:80, 5:60] = rng.random((70, 55)) > 0.05
    for values in (v, v[..., 1]):
        assert same(ridges.masked_gaussian(values, m, 6.0, reduce=reduce),
                    ref_masked_gaussian(values, m, 6.0, reduce=reduce))


@pytest.mark.parametrize("reduce", [1, 5])
def test_local_normalize_matches_former(reduce):
    rng = np.random.default_rng(reduce + 20)
    v = (rng.normal(size=(80, 70)) * 0.02).astype(np.float32)
    m = np.zeros((80, 70), bool)
    m[5:75, 10:65] = rng.random((70, 55)) > 0.05
    v[40, 40] = np.nan  # a NaN inside the mask
    const = np.full((80, 70), 3.0, np.float32)
    for values in (v, const):
        assert same(ridges.local_normalize(values, m, 7.0, reduce=reduce),
                    ref_local_normalize(values, m, 7.0, reduce=reduce))


@pytest.mark.parametrize("center", [(3.0, -2.0, 60.0), None])
def test_surface_relief_matches_numpy(center):
    rng = np.random.default_rng(1)
    rr, cc = np.mgrid[0:40, 0:50].astype(np.float32)
    smooth = np.stack([cc * 0.05, rr * 0.05, 0.002 * (cc - 25) ** 2], -1).astype(np.float32)
    xyz = smooth + rng.normal(scale=0.01, size=smooth.shape).astype(np.float32)
    smooth[5, 5] = np.nan
    xyz[7, 9] = np.nan
    smooth[20:22, 30:32] = smooth[20, 30]  # a degenerate patch: zero normals
    got = K.surface_relief(smooth, xyz, center)
    want = ridges._surface_relief(smooth, xyz, center)
    for g, w in zip(got, want, strict=True):
        assert same(g, w)


def test_rolled_map_and_axis_distance_match_numpy():
    rng = np.random.default_rng(2)
    theta = rng.uniform(-2.0, 2.0, 5000)
    pts = np.stack([7 * np.sin(theta), rng.uniform(-12, 12, 5000), 7 * np.cos(theta)], -1)
    pts += rng.normal(scale=0.05, size=pts.shape)
    flat, _ = flatten.fit_flattening(pts, "rolled")
    wide = pts * 1.2  # beyond the tables on every side
    for xyz in (pts, wide, pts.astype(np.float32)):
        assert same(K.rolled_map(flat, xyz), flat(np.asarray(xyz, np.float64)))
        d = np.asarray(xyz, np.float64) - flat.cylinder.center
        assert same(K.rolled_map(flat, offsets=d), flat(np.asarray(xyz, np.float64)))
    d = pts - pts.mean(axis=0)
    axis = np.array([0.1, 0.99, 0.05]) / np.linalg.norm([0.1, 0.99, 0.05])
    assert same(K.axis_distance(d, axis, 6.5), ref_axis_distance(d, axis, 6.5))


def test_camera_points_match_boolean_indexing():
    rng = np.random.default_rng(3)
    xyz = rng.normal(size=(30, 40, 3)).astype(np.float32)
    signal = rng.normal(size=(30, 40)).astype(np.float32)
    weight = np.clip(rng.normal(size=(30, 40)), 0, None).astype(np.float32)
    signal[weight > 1] = np.nan
    center = np.array([0.3, -0.1, 2.0])
    d, value, wt = K.camera_points(xyz, signal, weight, center)
    ok = (weight > 0) & np.isfinite(signal)
    assert same(d, np.asarray(xyz[ok], np.float64) - center)
    assert same(value, signal[ok]) and same(wt, weight[ok])


def test_splat_matches_bincount():
    rng = np.random.default_rng(4)
    grid = PrintGrid(5.0, 6.0, 0.0508, (230, 200))
    st = np.stack([rng.uniform(-6, 6, 20000), rng.uniform(-6, 7, 20000)], -1)  # some outside
    values = rng.normal(size=20000).astype(np.float32)
    weights = rng.uniform(0, 1, 20000).astype(np.float32)
    for got, want in zip(K.splat(grid, st, values, weights),
                         ref_splat(grid, st, values, weights), strict=True):
        assert same(got, want)


@pytest.mark.parametrize("q", [0.0, 0.01, 0.3, 99.7, 99.99, 100.0, 50.0])
def test_tail_percentile_matches_numpy(q):
    rng = np.random.default_rng(5)
    for x in (rng.normal(size=123457), np.round(rng.normal(size=50001), 2),
              np.sort(rng.normal(size=40000))[::-1], rng.normal(size=7),
              np.array([1.0, np.nan, 2.0] * 1000)):
        want = np.percentile(x, q)
        for got in (K.tail_percentile(x, q), K.tail_percentile([x[:3], x[3:]], q)):
            assert got == want or (np.isnan(got) and np.isnan(want))


def test_print_grid_of_parts_matches_former():
    rng = np.random.default_rng(7)
    parts = [rng.normal(size=(n, 2)) * (4, 9) for n in (30000, 17, 45000)]
    for st in (parts, np.concatenate(parts)):
        got = render.print_grid(st, ppi=500)
        want = ref_print_grid(np.concatenate(parts), ppi=500)
        assert (got.s0, got.t0, got.pitch, got.shape) == (want.s0, want.t0, want.pitch,
                                                          want.shape)


# -- the whole unroll against the former NumPy steps -----------------------------------------
@pytest.fixture(scope="module")
def small_finger():
    """Scans of the virtual finger at a quarter of the scanner's resolution."""
    rig = default_rig(0.25)
    sim = simulate("finger", rig=rig, seed=1)
    names = list(sim.frames)
    capture = Capture(
        path=None,
        manifest={"cameras": [{"name": n} for n in names], "bit_depth": 8},
        pattern_set=sim.pattern_set,
        frames={n: sim.frames[n].astype(np.float32) / np.float32(255) for n in names},
    )
    return scan_capture(capture, RigCalibration.from_dict(ideal_calibration(rig)))


class _NotARolledMap:
    """Stands in for RolledMap in ``render`` so that camera_samples takes the NumPy path."""


def test_unroll_matches_former_numpy_pipeline(small_finger, monkeypatch):
    new = unroll_scans(small_finger)
    calls = []

    def counted(fn):
        def wrapper(*args, **kwargs):
            calls.append(fn.__name__)
            return fn(*args, **kwargs)
        return wrapper

    with monkeypatch.context() as mp:
        mp.setattr(ridges, "masked_gaussian", counted(ref_masked_gaussian))
        mp.setattr(ridges, "local_normalize", counted(ref_local_normalize))
        mp.setattr(ridges, "scan_valid", counted(ref_scan_valid))
        mp.setattr(rolled, "scan_valid", counted(ref_scan_valid))
        mp.setattr(render, "masked_gaussian", counted(ref_masked_gaussian))
        mp.setattr(ridges, "surface_relief", counted(ridges._surface_relief))
        mp.setattr(render, "splat", counted(ref_splat))
        mp.setattr(render, "RolledMap", _NotARolledMap)
        mp.setattr(rolled, "print_grid", counted(ref_print_grid))
        mp.setattr(flatten, "axis_distance", counted(ref_axis_distance))
        old = unroll_scans(small_finger)
    assert {"ref_masked_gaussian", "ref_local_normalize", "ref_scan_valid", "_surface_relief",
            "ref_splat", "ref_print_grid", "ref_axis_distance"} <= set(calls)
    assert new.mask.sum() > 10000
    for name in ("image", "mask", "binary", "ridge", "share"):
        assert same(getattr(new, name), getattr(old, name)), name
    a, b = new.metadata(), old.metadata()
    a.pop("timings_s"), b.pop("timings_s")
    assert a == b


def test_row_steps_match_numpy():
    rng = np.random.default_rng(6)
    xyz = rng.normal(size=(40, 33, 3)).astype(np.float32)
    valid = rng.random((40, 33)) > 0.3
    want = ridges._norm3(np.diff(xyz, axis=1))[valid[:, 1:] & valid[:, :-1]]
    assert same(K.row_steps(xyz, valid), want)
    assert ridges.pixel_spacing_mm(xyz, valid) == float(np.median(want))


def test_valid_points_match_numpy():
    rng = np.random.default_rng(8)
    xyz = rng.normal(size=(20, 30, 3)).astype(np.float32)
    xyz[3, 4, 1] = np.nan
    xyz[5, 6, 2] = np.inf
    xyz[7, 8] = 3e38  # finite coordinates whose sum overflows
    mask = rng.random((20, 30)) > 0.1
    with np.errstate(over="ignore"):
        want = mask & ridges.finite_points(xyz)
    assert same(K.valid_points(mask, xyz), want)


def test_layer_outputs_match_numpy():
    rng = np.random.default_rng(9)
    shape, box = (30, 40), (slice(4, 24), slice(6, 36))
    modulation = rng.normal(size=(20, 30)).astype(np.float32)
    modulation[0, :3] = [np.nan, np.inf, -0.0]
    cos = rng.uniform(0, 1, (20, 30)).astype(np.float32)
    cos[1, :2] = [np.nan, np.float32(np.cos(np.radians(75.0)))]
    feather = rng.uniform(0, 1, (20, 30)).astype(np.float32)
    valid = rng.random((20, 30)) > 0.2
    signal = rng.normal(size=(20, 30)).astype(np.float32)
    signal[2, 3] = np.nan
    cos_min = np.cos(np.radians(75.0))
    got = K.layer_outputs(modulation, cos, feather, valid, signal, cos_min, box, shape)
    # the former NumPy code of camera_layer
    c = np.nan_to_num(cos)
    weight = np.clip(np.nan_to_num(modulation), 0, None) * c**2 * feather
    weight[c < cos_min] = 0
    out_signal = np.full(shape, np.nan, dtype=np.float32)
    out_signal[box] = np.where(valid, signal, np.nan)
    out_weight = np.zeros(shape, dtype=np.float32)
    out_weight[box] = np.where(valid & np.isfinite(signal), weight, 0)
    assert same(got[0], out_signal) and same(got[1], out_weight)


def test_ratio_matches_numpy():
    rng = np.random.default_rng(10)
    num = rng.normal(size=(15, 12, 2)).astype(np.float32)
    den = rng.uniform(-0.001, 0.01, (15, 12)).astype(np.float32)
    den[0, 0] = np.float32(1e-3)
    with np.errstate(invalid="ignore", divide="ignore"):
        want = np.where(den[..., None] > 1e-3, num / den[..., None], np.nan).astype(np.float32)
    assert same(K.ratio(num, den), want)
