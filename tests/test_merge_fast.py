"""Issue 11: the fast merge gives the results of the implementation it replaced.

The NumPy implementations that the compiled and cached paths replaced are kept here, verbatim in
their arithmetic, as references: normals, view cosine, discontinuities, the whole
correspondence (k-d tree or brute force, float64 copies, per-call images) and the point-cloud
render. Speed is shown by ``bench/correspond.py``, not asserted here.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import scipy.ndimage
from PIL import Image

sys.path.insert(0, str(Path(__file__).parent))
from _synthetic import synthetic_scans

from nail2nail._interpolate import bilinear
from nail2nail.merge.correspondence import (
    _GRID_RINGS,
    DROP_REASONS,
    REJECT_REASONS,
    Correspondence,
    CorrespondenceCache,
    _correspond,
    _eroded,
    _grid_nearest,
    _grid_nearest_pixels,
    _relative_modulation,
    _without_jumps,
    correspond,
    grid_normals,
    nearest_bruteforce,
    nearest_grid,
    nearest_kdtree,
    refine_subpixel,
    sample_pixels,
    valid_mask,
    view_cosine,
)
from nail2nail.merge.statistics import _middle, local_outliers
from nail2nail.scan.results import Scan

SIZE = (96, 120)  # (width, height), as tests/test_merge_correspondence.py


@pytest.fixture(scope="module")
def noisy():
    return synthetic_scans(size=SIZE, noise_px=0.05, seed=3)


@pytest.fixture(scope="module")
def holed(noisy):
    """The noisy scans with a hole, a jump in the projector map and a lone valid pixel."""
    out = []
    for k, s in enumerate(noisy):
        mask = s.mask.copy()
        mask[50:58, 40:52] = False  # a hole the other cameras see through
        mask[5, 5] = True  # a lone pixel (outside the cylinder: xyz NaN, so still invalid)
        xp = s.xp.copy()
        xp[:, 70 + 3 * k:] += 6.0  # a depth-discontinuity-like step
        out.append(replace(s, mask=mask, xp=xp))
    return out


# -- references: the NumPy code the fast paths replaced ----------------------------------------
def reference_grid_normals(xyz, *, camera_center=None):
    xyz = np.asarray(xyz, dtype=np.float64)

    def derivative(axis):
        d = np.full_like(xyz, np.nan)
        n = xyz.shape[axis]

        def take(start, stop):
            s = [slice(None)] * 3
            s[axis] = slice(start, stop)
            return tuple(s)

        if n >= 3:
            d[take(1, n - 1)] = 0.5 * (xyz[take(2, n)] - xyz[take(0, n - 2)])
        if n >= 2:
            forward = np.full_like(xyz, np.nan)
            forward[take(0, n - 1)] = xyz[take(1, n)] - xyz[take(0, n - 1)]
            backward = np.full_like(xyz, np.nan)
            backward[take(1, n)] = forward[take(0, n - 1)]
            d = np.where(np.isnan(d), forward, d)
            d = np.where(np.isnan(d), backward, d)
        return d

    normal = np.cross(derivative(0), derivative(1))
    with np.errstate(invalid="ignore", divide="ignore"):
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
        if camera_center is not None:
            view = np.asarray(camera_center, dtype=np.float64) - xyz
            flip = np.einsum("...k,...k->...", normal, view) < 0
            normal[flip] *= -1
    return normal.astype(np.float32)


def reference_view_cosine(scan, *, normals=None, smooth_px=0.0, center=None):
    """The view cosine; with `center`, the cosine towards that point (the incidence)."""
    valid = valid_mask(scan)
    if normals is None:
        normals = reference_grid_normals(scan.xyz, camera_center=scan.camera_center)
    normals = np.asarray(normals, dtype=np.float64)
    center = scan.camera_center if center is None else center
    view = np.asarray(center, dtype=np.float64) - np.asarray(scan.xyz, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        view /= np.linalg.norm(view, axis=-1, keepdims=True)
        cos = np.clip(np.nan_to_num(np.einsum("...k,...k->...", normals, view)), 0, 1)
    cos[~valid] = 0.0
    if smooth_px > 0:
        norm = scipy.ndimage.gaussian_filter(valid.astype(np.float64), smooth_px)
        with np.errstate(invalid="ignore", divide="ignore"):
            cos = np.nan_to_num(scipy.ndimage.gaussian_filter(cos, smooth_px) / norm)
        cos[~valid] = 0.0
    return cos


def reference_without_jumps(scan, valid, max_jump_px):
    out = valid.copy()
    for f in (scan.xp, scan.yp):
        f = np.asarray(f, dtype=np.float32)
        for axis in (0, 1):
            forward = np.diff(f, axis=axis)
            lo, hi = [slice(None)] * 2, [slice(None)] * 2
            lo[axis], hi[axis] = slice(0, -1), slice(1, None)
            d_minus, d_plus = forward[tuple(lo)], forward[tuple(hi)]
            second = np.abs(d_plus - d_minus)
            with np.errstate(invalid="ignore"):
                jump = (second > max_jump_px) & (second > 0.5 * (np.abs(d_plus) + np.abs(d_minus)))
            inner = [slice(None)] * 2
            inner[axis] = slice(1, -1)
            out[tuple(inner)] &= ~jump
    return out


def reference_correspond(parent, child, *, stride=1, max_residual_px=0.5, border_px=2,
                         max_jump_px=2.0, refine=True, method="kdtree",
                         max_view_angle_deg=70.0, max_incidence_deg=65.0,
                         min_relative_modulation=1 / 3,
                         outlier_mm=0.025, outlier_mad=4.0, outlier_block_px=32):
    """The correspondence before issue 11: every image per call, float64 copies."""
    parent_valid, child_valid = valid_mask(parent), valid_mask(child)
    rows, cols = sample_pixels(parent_valid, stride=stride)
    n_sampled = rows.size
    dropped = dict.fromkeys(DROP_REASONS, 0)
    keep = _eroded(reference_without_jumps(parent, parent_valid, max_jump_px),
                   border_px)[rows, cols]
    dropped["parent_border"] = int(np.count_nonzero(~keep))
    rows, cols = rows[keep], cols[keep]
    search = nearest_kdtree if method == "kdtree" else nearest_bruteforce
    nr, nc, dist2 = search(parent, child, rows, cols)
    child_inner = _eroded(reference_without_jumps(child, child_valid, max_jump_px), border_px)
    keep = child_inner[nr, nc]
    rows, cols, nr, nc, dist2 = rows[keep], cols[keep], nr[keep], nc[keep], dist2[keep]
    if refine:
        f8 = np.float64
        sub_r, sub_c, residual = refine_subpixel(
            np.asarray(child.xp, f8), np.asarray(child.yp, f8),
            parent.xp[rows, cols].astype(f8), parent.yp[rows, cols].astype(f8), nr, nc)
        xyz_child = np.full((nr.size, 3), np.nan)
        ok = np.isfinite(sub_r)
        xyz_child[ok] = bilinear(np.asarray(child.xyz, f8), sub_r[ok], sub_c[ok])[0]
        finite = np.isfinite(residual) & np.isfinite(xyz_child).all(axis=-1)
    else:
        sub_r, sub_c, residual = nr.astype(np.float64), nc.astype(np.float64), np.sqrt(dist2)
        xyz_child = np.asarray(child.xyz, dtype=np.float64)[nr, nc]
        finite = np.ones(nr.size, dtype=bool)
    dropped["child_border"] = int(np.count_nonzero(~keep) + np.count_nonzero(~finite))
    with np.errstate(invalid="ignore"):
        good = finite & (residual <= max_residual_px)
    dropped["residual"] = int(np.count_nonzero(finite & ~good))
    pairs = {
        "parent_rc": np.stack([rows[good], cols[good]], axis=-1),
        "child_nearest": np.stack([nr[good], nc[good]], axis=-1),
        "child_rc": np.stack([sub_r[good], sub_c[good]], axis=-1),
        "xyz_parent": np.asarray(parent.xyz, dtype=np.float64)[rows[good], cols[good]],
        "xyz_child": xyz_child[good],
        "residual_px": residual[good],
    }
    n = pairs["parent_rc"].shape[0]
    reason = np.full(n, -1, dtype=np.int8)
    pr, pc = pairs["parent_rc"].T
    cr, cc = pairs["child_rc"].T
    for code, limit in enumerate((max_view_angle_deg, max_incidence_deg,
                                  min_relative_modulation)):
        if limit is None or n == 0:
            continue
        threshold = np.cos(np.radians(limit)) if code < 2 else limit
        ok = np.ones(n, dtype=bool)
        for scan, (r, c) in ((parent, (pr, pc)), (child, (cr, cc))):
            if code == 0 and scan.camera_center is None:
                continue
            if code == 1 and scan.projector_center is None:
                continue
            image = (reference_view_cosine(scan, smooth_px=2.0) if code == 0
                     else reference_view_cosine(scan, smooth_px=2.0,
                                                center=scan.projector_center) if code == 1
                     else _relative_modulation(scan))
            ok &= bilinear(image, r.astype(np.float64), c.astype(np.float64))[0] >= threshold
        reason[(reason < 0) & ~ok] = code
    if outlier_mm is not None and n:
        live = reason < 0
        distance = np.linalg.norm(pairs["xyz_parent"] - pairs["xyz_child"], axis=-1)
        out = local_outliers(pr[live], pc[live], distance[live], block_px=outlier_block_px,
                             floor_mm=outlier_mm, k_mad=outlier_mad)
        reason[np.flatnonzero(live)[out]] = 3
    for code, name in enumerate(REJECT_REASONS):
        dropped[name] = int(np.count_nonzero(reason == code))
    return pairs, reason, dropped, n_sampled


def reference_local_outliers(rows, cols, distance_mm, *, block_px=32, floor_mm=0.025,
                             k_mad=4.0):
    """local_outliers before issue 11's follow-up: block medians from one argsort by a
    (block, value) key, twice."""
    d = np.asarray(distance_mm, dtype=np.float64)
    rows, cols = np.asarray(rows, np.intp), np.asarray(cols, np.intp)
    if d.size == 0:
        return np.zeros(0, dtype=bool)

    def block_median(values, block):
        order = np.argsort(block * 4096.0 + np.clip(values, 0.0, 4000.0))
        counts = np.bincount(block, minlength=n_blocks)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        sv = values[order]
        lo = np.clip(starts + (counts - 1) // 2, 0, values.size - 1)
        hi = np.clip(starts + counts // 2, 0, values.size - 1)
        return 0.5 * (sv[lo] + sv[hi]), counts

    n_cols = int(cols.max()) // block_px + 1
    block = (rows // block_px) * n_cols + cols // block_px
    n_blocks = int(block.max()) + 1
    median, counts = block_median(d, block)
    mad, _ = block_median(np.abs(d - median[block]), block)
    few = counts < 8
    g_median = np.median(d)
    median[few], mad[few] = g_median, np.median(np.abs(d - g_median))
    return d - median[block] > np.maximum(floor_mm, k_mad * mad[block])


def reference_render(points, *, normals=None, colors=None, elev=0.0, azim=0.0,
                     size=(600, 800), splat=2):
    pts = np.asarray(points, dtype=np.float64)
    finite = np.isfinite(pts).all(axis=1)
    a, e = np.radians(azim), np.radians(elev)
    eye = np.array([np.sin(a) * np.cos(e), np.sin(e), np.cos(a) * np.cos(e)])
    right = np.cross([0.0, 1.0, 0.0], eye)
    if np.linalg.norm(right) < 1e-9:
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(eye, right)
    p = pts[finite] - pts[finite].mean(axis=0)
    u, v, depth = p @ right, p @ up, p @ eye
    width, height = int(size[0]), int(size[1])
    scale = 0.9 * min(width / max(np.ptp(u), 1e-9), height / max(np.ptp(v), 1e-9))
    ix = np.round(width / 2 + scale * (u - (u.max() + u.min()) / 2)).astype(np.int64)
    iy = np.round(height / 2 - scale * (v - (v.max() + v.min()) / 2)).astype(np.int64)
    if normals is not None:
        n = np.nan_to_num(np.asarray(normals, dtype=np.float64)[finite])
        n *= np.where(n @ eye < 0, -1.0, 1.0)[:, None]
        light = eye + 0.5 * up + 0.3 * right
        light /= np.linalg.norm(light)
        shade = 0.2 + 0.8 * np.clip(n @ light, 0, 1)
    else:
        shade = np.ones(p.shape[0])
    if colors is None:
        rgb = np.full((p.shape[0], 3), 200.0)
    else:
        rgb = np.asarray(colors, dtype=np.float64)[finite]
        rgb *= 230.0 / max(float(np.percentile(rgb, 99)), 1.0)
    rgb = np.clip(rgb * shade[:, None], 0, 255).astype(np.uint8)
    offsets = np.arange(-splat, splat + 1)
    dy, dx = (g.ravel() for g in np.meshgrid(offsets, offsets, indexing="ij"))
    px, py = (ix[:, None] + dx).ravel(), (iy[:, None] + dy).ravel()
    pd, pc = np.repeat(depth, dx.size), np.repeat(np.arange(p.shape[0]), dx.size)
    inside = (px >= 0) & (px < width) & (py >= 0) & (py < height)
    px, py, pd, pc = px[inside], py[inside], pd[inside], pc[inside]
    pixel = py * width + px
    order = np.lexsort((pd, pixel))
    last = np.r_[pixel[order][1:] != pixel[order][:-1], True]
    image = np.full((height * width, 3), 255, dtype=np.uint8)
    image[pixel[order][last]] = rgb[pc[order][last]]
    return image.reshape(height, width, 3)


def _same(a, b) -> bool:
    """Equal arrays, NaN equal to NaN, same shape."""
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and bool(np.all((a == b) | (np.isnan(a) & np.isnan(b))))


# -- normals and view cosine -----------------------------------------------------------------
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_grid_normals_are_the_numpy_normals_bit_for_bit(holed, dtype):
    for scan in holed:
        xyz = np.where(scan.mask[..., None], scan.xyz, np.nan).astype(dtype)
        xyz[10, 20, 1] = np.nan  # one component missing: handled per component, as NumPy
        for center in (None, scan.camera_center):
            assert _same(grid_normals(xyz, camera_center=center),
                         reference_grid_normals(xyz, camera_center=center))


@pytest.mark.parametrize("shape", [(1, 5), (2, 4), (3, 3), (5, 1)])
def test_grid_normals_of_tiny_grids(shape):
    rr, cc = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    xyz = np.stack([cc, -rr, 0.1 * cc * rr], -1)
    assert _same(grid_normals(xyz), reference_grid_normals(xyz))
    assert grid_normals(xyz.astype(np.int64)).dtype == np.float32  # other types as float64


@pytest.mark.parametrize("smooth_px", [0.0, 2.0, 0.7])
def test_view_cosine_is_the_numpy_cosine(holed, smooth_px):
    for scan in holed:
        # the same arithmetic in NumPy's order of summation (this platform's: a mismatch of
        # the last bit would not change a result of the merge)
        fast = view_cosine(scan, smooth_px=smooth_px)
        ref = reference_view_cosine(scan, smooth_px=smooth_px)
        assert _same(fast, ref)
    normals = grid_normals(holed[1].xyz, camera_center=holed[1].camera_center)
    assert _same(view_cosine(holed[1], normals=normals),
                 reference_view_cosine(holed[1], normals=normals))
    with pytest.raises(ValueError, match="normals: expected shape"):
        view_cosine(holed[1], normals=normals[:-1])


def test_view_cosine_smoothing_box_reaches_the_image_edge():
    # valid pixels at the image's edge: the box is cut there and scipy's reflection applies
    scan = synthetic_scans(size=(40, 30), angles_deg=(0.0,), shape="sphere", radius=14.0)[0]
    assert scan.mask[:, 0].any() or scan.mask[0].any()
    assert _same(view_cosine(scan, smooth_px=2.0), reference_view_cosine(scan, smooth_px=2.0))


def test_without_jumps_in_the_valid_box_is_the_whole_image_test(holed):
    for scan in holed:
        valid = valid_mask(scan)
        for jump in (0.5, 2.0):
            assert np.array_equal(_without_jumps(scan, valid, jump),
                                  reference_without_jumps(scan, valid, jump))
    empty = np.zeros(holed[0].mask.shape, bool)
    assert not _without_jumps(holed[0], empty, 2.0).any()


# -- nearest neighbour -----------------------------------------------------------------------
def _cloud_scan(xp, yp, name="cloud"):
    """A (3, ⌈N / 3⌉) scan of projector coordinates only (row-major; padding invalid): a point
    set for the searches."""
    n = xp.size
    m = max(-(-n // 3), 3)
    grids = []
    for values in (xp, yp):
        g = np.full(3 * m, np.nan, np.float32)
        g[:n] = values
        grids.append(g.reshape(3, m))
    mask = np.isfinite(grids[0])
    xyz = np.where(mask[..., None], np.zeros((3, m, 3)), np.nan).astype(np.float32)
    one = np.ones((3, m), np.float32)
    return Scan(name, xyz, grids[0], grids[1], one, one, one, mask)


def _all_pixels(scan):
    return np.nonzero(scan.mask)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_nearest_grid_is_the_brute_force_also_far_from_the_child(seed):
    rng = np.random.default_rng(seed)
    # a child covering an annulus (a large empty disc inside) with uneven density, and
    # parents everywhere: in it, in the hole, beyond it, far away
    angle, radius = rng.uniform(0, 2 * np.pi, 3000), rng.uniform(30, 60, 3000) ** 1.1
    child = _cloud_scan(400 + radius * np.cos(angle), 300 + radius * np.sin(angle))
    qx = np.concatenate([rng.uniform(250, 550, 1500), [400.0, 1e4, -3e3, 400.4]])
    qy = np.concatenate([rng.uniform(150, 450, 1500), [300.0, 2e3, 9.0, 300.1]])
    parent = _cloud_scan(qx, qy, "parent")
    rows, cols = _all_pixels(parent)
    b = nearest_bruteforce(parent, child, rows, cols)
    g = nearest_grid(parent, child, rows, cols)
    np.testing.assert_array_equal(g[0], b[0])
    np.testing.assert_array_equal(g[1], b[1])
    np.testing.assert_array_equal(g[2], b[2])  # the same formula: the same float64 distances
    # the ring search leaves the far ones to the edge k-d tree
    grid = CorrespondenceCache()._entry(child).grid
    _, _, done = _grid_nearest(qx.astype(np.float32).astype(float),
                               qy.astype(np.float32).astype(float), grid.sx,
                               grid.sy, grid.sindex, grid.start, grid.x0, grid.y0, grid.cell,
                               grid.nx, grid.ny, _GRID_RINGS)
    assert done.sum() > 100 and (~done).sum() > 100


def test_nearest_grid_ties_go_to_the_first_pixel_as_the_brute_force():
    # a lattice: every query at a cell centre is equally far from four pixels
    xx, yy = np.meshgrid(np.arange(20.0), np.arange(15.0))
    child = _cloud_scan(xx.ravel(), yy.ravel())
    qx, qy = np.array([3.5, 10.5, 0.5, 7.0]), np.array([2.5, 7.5, 13.5, 4.0])
    parent = _cloud_scan(qx, qy, "parent")
    rows, cols = _all_pixels(parent)
    b = nearest_bruteforce(parent, child, rows, cols)
    g = nearest_grid(parent, child, rows, cols)
    for x, y in zip(b, g, strict=True):
        np.testing.assert_array_equal(x, y)


def test_nearest_grid_matches_bruteforce_on_scans(holed):
    for i, j in ((0, 1), (1, 2), (2, 0), (1, 0)):
        rows, cols = sample_pixels(valid_mask(holed[i]), stride=2)
        b = nearest_bruteforce(holed[i], holed[j], rows, cols)
        g = nearest_grid(holed[i], holed[j], rows, cols)
        for x, y in zip(b, g, strict=True):
            np.testing.assert_array_equal(x, y)


def test_nearest_grid_on_degenerate_coordinates():
    # every child pixel at one projector point, and a spread far too wide for a fine grid
    child = _cloud_scan(np.full(50, 7.0), np.full(50, 3.0))
    parent = _cloud_scan(np.array([7.0, 8.0, -5.0]), np.array([3.0, 3.0, 1e5]), "parent")
    rows, cols = _all_pixels(parent)
    found = nearest_grid(parent, child, rows, cols)
    assert found[0].tolist() == [0, 0, 0] and found[1].tolist() == [0, 0, 0]  # ties: the first
    rng = np.random.default_rng(4)
    wide = _cloud_scan(rng.uniform(0, 1e7, 400), rng.uniform(0, 1e-3, 400))
    b = nearest_bruteforce(parent, wide, rows, cols)
    g = nearest_grid(parent, wide, rows, cols)
    for x, y in zip(b, g, strict=True):
        np.testing.assert_array_equal(x, y)
    assert CorrespondenceCache()._entry(wide).grid.start.size <= 1.5 * (4 * 400 + 1024) + 2


def test_bounded_grid_search_is_the_brute_force_where_done(holed):
    # the fused search (previous query's nearest as a bound, skipped cells and empty rings):
    # where it proves a query done, the brute force's pixel and distance; elsewhere the edge
    # k-d tree settles it, as nearest_grid
    rng = np.random.default_rng(7)
    angle, radius = rng.uniform(0, 2 * np.pi, 3000), rng.uniform(30, 60, 3000) ** 1.1
    annulus = _cloud_scan(400 + radius * np.cos(angle), 300 + radius * np.sin(angle))
    xx, yy = np.meshgrid(np.arange(20.0), np.arange(15.0))
    lattice = _cloud_scan(xx.ravel(), yy.ravel())
    queries = [
        _cloud_scan(np.concatenate([rng.uniform(250, 550, 1500), [400.0, 1e4, -3e3, 400.4]]),
                    np.concatenate([rng.uniform(150, 450, 1500), [300.0, 2e3, 9.0, 300.1]]),
                    "parent"),
        _cloud_scan(np.array([3.5, 3.5, 10.5, 0.5, 7.0, 7.0]),
                    np.array([2.5, 2.5, 7.5, 13.5, 4.0, 4.0]), "parent"),  # ties
    ]
    cases = [(queries[0], annulus), (queries[1], lattice)]
    cases += [(holed[i], holed[j]) for i, j in ((0, 1), (1, 2), (2, 0))]
    for parent, child in cases:
        rows, cols = np.nonzero(valid_mask(parent))
        grid = CorrespondenceCache()._entry(child).grid
        n = rows.size
        best, d2, done = np.empty(n, np.int64), np.empty(n), np.empty(n, bool)
        _grid_nearest_pixels(parent.xp, parent.yp, rows, cols, grid.sx, grid.sy, grid.sindex,
                             grid.start, grid.x0, grid.y0, grid.cell, grid.nx, grid.ny,
                             _GRID_RINGS, grid.empty, best, d2, done)
        br, bc, bd2 = nearest_bruteforce(parent, child, rows, cols)
        np.testing.assert_array_equal(grid.rows[best[done]], br[done])
        np.testing.assert_array_equal(grid.cols[best[done]], bc[done])
        np.testing.assert_array_equal(d2[done], bd2[done])
        index, dist2 = grid.nearest_pixels(parent.xp, parent.yp, rows, cols)
        np.testing.assert_array_equal(grid.rows[index], br)
        np.testing.assert_array_equal(grid.cols[index], bc)
        np.testing.assert_array_equal(dist2, bd2)
    assert done.sum() > 100


def exact_local_outliers(rows, cols, d, *, block_px, floor_mm, k_mad):
    """local_outliers by its definition: np.median per block."""
    n_cols = int(cols.max()) // block_px + 1
    block = (rows // block_px) * n_cols + cols // block_px
    g = np.median(d)
    g_mad = np.median(np.abs(d - g))
    out = np.zeros(d.size, bool)
    for b in np.unique(block):
        at = block == b
        m, mad = g, g_mad
        if at.sum() >= 8:
            m = np.median(d[at])
            mad = np.median(np.abs(d[at] - m))
        out[at] = d[at] - m > np.maximum(floor_mm, k_mad * mad)
    return out


@pytest.mark.parametrize("seed", range(6))
def test_local_outliers_are_the_argsort_implementation(seed):
    # continuous distances: the former argsort's results; rounded ones (many ties, which its
    # (block, value) key may order apart by 1e-9 mm): the per-block median by definition
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 20000))
    rows, cols = rng.integers(0, 300, n), rng.integers(0, 400, n)
    d = rng.gamma(2.0, 0.005, n)
    d[rng.random(n) < 0.01] *= 20.0
    reference = reference_local_outliers
    if seed % 2:
        d, reference = np.round(d, 3), exact_local_outliers
    for block_px in (8, 32, 100):
        for floor_mm, k_mad in ((0.025, 4.0), (0.0, 2.0)):
            np.testing.assert_array_equal(
                local_outliers(rows, cols, d, block_px=block_px, floor_mm=floor_mm, k_mad=k_mad),
                reference(rows, cols, d, block_px=block_px, floor_mm=floor_mm, k_mad=k_mad))


@pytest.mark.parametrize("n", [1, 2, 3, 4, 7, 8, 9, 100, 1001])
def test_middle_is_numpy_median(n):
    rng = np.random.default_rng(n)
    for values in (rng.random(n), rng.integers(0, 3, n).astype(float), np.full(n, 0.5)):
        assert _middle(values.copy()) == np.median(values)
    with_nan = rng.random(n)
    with_nan[0] = np.nan
    assert np.isnan(_middle(with_nan))


def test_fused_pairs_distance_is_numpy_norm(holed, monkeypatch):
    # the outlier test gets the world distances from the fused kernel: np.linalg.norm's values
    import nail2nail.merge.correspondence as mc

    seen = []

    def spy(rows, cols, distance, **kwargs):
        seen.append(distance)
        return local_outliers(rows, cols, distance, **kwargs)

    monkeypatch.setattr(mc, "local_outliers", spy)
    m = correspond(holed[0], holed[1], max_view_angle_deg=None, max_incidence_deg=None,
                   min_relative_modulation=None)
    both = m.all_pairs()  # kept, then rejected: back to the parent's row-major order
    order = np.lexsort(both.parent_rc.T[::-1])
    norm = np.linalg.norm(both.xyz_parent - both.xyz_child, axis=-1)[order]
    assert m.rejected.n_pairs > 0
    np.testing.assert_array_equal(seen[0], norm)


@pytest.mark.parametrize("border_px", [1, 2, 3])
def test_erosion_is_scipy_binary_erosion(holed, border_px):
    rng = np.random.default_rng(border_px)
    masks = [s.mask for s in holed] + [rng.random((40, 57)) < 0.9, np.ones((6, 5), bool),
                                      np.ones((1, 9), bool)]
    for mask in masks:
        expected = scipy.ndimage.binary_erosion(mask, structure=np.ones((3, 3), bool),
                                                iterations=border_px, border_value=0)
        np.testing.assert_array_equal(_eroded(mask, border_px), expected)


def test_valid_mask_and_relative_modulation_are_the_numpy_ones(holed):
    for s in holed:
        xyz = s.xyz.copy()
        xyz[3, 4, 2] = np.inf
        mod = s.modulation.copy()
        r, c = np.nonzero(s.mask)
        mod[r[:5], c[:5]] = np.nan
        mod[r[7], c[7]] = np.inf
        scan = replace(s, xyz=xyz, modulation=mod)
        valid = valid_mask(scan)
        np.testing.assert_array_equal(
            valid, scan.mask & np.isfinite(xyz).all(-1) & np.isfinite(s.xp) & np.isfinite(s.yp))
        m = np.nan_to_num(np.asarray(mod, dtype=np.float64))
        median = float(np.median(m[valid]))
        with np.errstate(over="ignore"):
            expected = np.where(valid, m / median, 0.0)
        assert _same(_relative_modulation(scan, valid), expected)
        assert not _relative_modulation(scan, np.zeros_like(valid)).any()


# -- the whole correspondence ----------------------------------------------------------------
def _assert_matches_reference(m: Correspondence, ref) -> None:
    pairs, reason, dropped, n_sampled = ref
    assert m.dropped == dropped and m.n_sampled == n_sampled
    both = m.all_pairs() if m.rejected is not None else m
    kept, bad = reason < 0, reason >= 0
    for name, value in pairs.items():
        np.testing.assert_array_equal(getattr(m, name), value[kept], err_msg=name)
        if m.rejected is not None:
            np.testing.assert_array_equal(getattr(m.rejected, name), value[bad], err_msg=name)
    if m.rejected is not None:
        assert m.rejected.reason.tolist() == np.asarray(REJECT_REASONS)[reason[bad]].tolist()
    assert both.n_pairs == reason.size


@pytest.mark.parametrize("options", [
    {},
    {"stride": 3},
    {"refine": False, "max_residual_px": 5.0},
    {"border_px": 1, "max_jump_px": 0.8},
    {"max_view_angle_deg": 55.0, "min_relative_modulation": 0.9},
    {"max_incidence_deg": 45.0, "max_view_angle_deg": None},
    {"max_view_angle_deg": None, "max_incidence_deg": None, "min_relative_modulation": None,
     "outlier_mm": None},
])
def test_correspond_gives_the_reference_results(holed, options):
    for i, j in ((0, 1), (1, 2), (2, 1), (0, 2)):
        ref = reference_correspond(holed[i], holed[j], **options)
        for method in ("grid", "kdtree"):
            _assert_matches_reference(correspond(holed[i], holed[j], method=method, **options),
                                      ref)
    weak = replace(holed[1], modulation=holed[1].modulation * np.float32(0.2))
    _assert_matches_reference(correspond(holed[0], weak, **options),
                              reference_correspond(holed[0], weak, **options))


def test_correspond_matches_the_brute_force_reference(holed):
    ref = reference_correspond(holed[0], holed[1], stride=4, method="bruteforce")
    _assert_matches_reference(correspond(holed[0], holed[1], stride=4), ref)
    _assert_matches_reference(correspond(holed[0], holed[1], stride=4, method="bruteforce"), ref)


def test_cache_is_reused_and_gives_the_uncached_results(holed):
    cache = CorrespondenceCache()
    first = [correspond(holed[i], holed[j], cache=cache) for i, j in ((0, 1), (1, 2), (2, 0))]
    assert len(cache) == 3
    grid = cache._entry(holed[1]).grid
    again = correspond(holed[0], holed[1], cache=cache, stride=2)
    assert cache._entry(holed[1]).grid is grid  # built once
    assert again.n_pairs < first[0].n_pairs
    for m, (i, j) in zip(first, ((0, 1), (1, 2), (2, 0)), strict=True):
        plain = correspond(holed[i], holed[j])
        np.testing.assert_array_equal(m.parent_rc, plain.parent_rc)
        np.testing.assert_array_equal(m.xyz_child, plain.xyz_child)
        assert m.dropped == plain.dropped
    # a replaced scan is a new scan: its images are derived again
    moved = replace(holed[1], xp=holed[1].xp + np.float32(0.3))
    _assert_matches_reference(correspond(holed[0], moved, cache=cache),
                              reference_correspond(holed[0], moved))
    assert len(cache) == 4
    assert cache.valid_mask(holed[1]) is cache._entry(holed[1]).valid
    assert np.array_equal(cache.valid_mask(holed[1]), valid_mask(holed[1]))
    cache.clear()
    assert len(cache) == 0
    with pytest.raises(TypeError, match="cache: expected a CorrespondenceCache"):
        correspond(holed[0], holed[1], cache={})


def test_fusion_call_with_a_quality_dict_still_works(holed):
    # fuse_scans' call: every option by keyword, its own view cosine through `quality`
    quality = {id(s): [view_cosine(s, smooth_px=2.0), None, None] for s in holed}
    kwargs = {"stride": 1, "max_residual_px": 0.5, "border_px": 1, "max_jump_px": 2.0,
              "refine": True, "method": "kdtree", "workers": -1, "max_view_angle_deg": 70.0,
              "max_incidence_deg": 65.0, "min_relative_modulation": 1 / 3, "outlier_mm": 0.025,
              "outlier_mad": 4.0, "outlier_block_px": 32}
    a = _correspond(holed[0], holed[1], **kwargs, quality=quality)
    assert all(v is not None for v in quality[id(holed[1])])  # filled, as before
    b = _correspond(holed[0], holed[1], **{**kwargs, "method": "grid"}, quality=quality,
                    cache=CorrespondenceCache())
    _assert_matches_reference(a, reference_correspond(holed[0], holed[1], border_px=1))
    _assert_matches_reference(b, reference_correspond(holed[0], holed[1], border_px=1))


def test_refinement_reads_float32_as_its_float64_copy(noisy):
    wide = [replace(s, xp=s.xp.astype(float), yp=s.yp.astype(float), xyz=s.xyz.astype(float))
            for s in noisy[:2]]
    single = correspond(noisy[0], noisy[1], stride=2)
    double = correspond(*wide, stride=2)
    for name in ("parent_rc", "child_rc", "xyz_child", "residual_px"):
        assert _same(getattr(single, name), getattr(double, name)), name


# -- figures ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def cloud():
    rng = np.random.default_rng(5)
    t, y = rng.uniform(-2.0, 2.0, 4000), rng.uniform(-10, 10, 4000)
    pts = np.stack([8 * np.sin(t), y, 8 * np.cos(t)], -1)
    pts[::97] = np.nan
    normals = pts / 8.0
    colors = rng.integers(0, 120, (4000, 3)).astype(np.uint8)
    return pts, normals, colors


@pytest.mark.parametrize(("elev", "azim", "splat"), [(10.0, 0.0, 2), (15.0, 70.0, 1),
                                                     (90.0, 0.0, 0), (-30.0, 200.0, 3)])
def test_render_image_is_the_numpy_z_buffer(cloud, elev, azim, splat):
    from nail2nail.merge.figures import _render_image

    pts, normals, colors = cloud
    for kwargs in ({"normals": normals, "colors": colors}, {}, {"colors": colors.astype(float)}):
        fast = _render_image(pts, elev=elev, azim=azim, size=(120, 90), splat=splat, **kwargs)
        ref = reference_render(pts, elev=elev, azim=azim, size=(120, 90), splat=splat, **kwargs)
        assert np.mean(np.all(fast == ref, axis=-1)) > 0.999  # rounding of the projection


def test_render_points_png_with_and_without_title(cloud, tmp_path):
    from nail2nail.merge.figures import _render_image, render_points

    pts, normals, colors = cloud
    out = render_points(pts, tmp_path / "a.png", normals=normals, colors=colors, size=(200, 150),
                        title="super scan (front): 3959 points")
    with Image.open(out) as im:
        assert im.size == (200, 190)
        pixels = np.asarray(im.convert("RGB"))
    assert np.array_equal(pixels[40:], _render_image(pts, normals=normals, colors=colors,
                                                     size=(200, 150)))
    assert (pixels[:40] < 128).any()  # the title is drawn
    with Image.open(render_points(pts, tmp_path / "b.png", size=(200, 150))) as im:
        assert im.size == (200, 150)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "b.png"]


@pytest.mark.parametrize("n", [1, 2, 3, 100, 1001, 30000])
def test_percentile_of_uint8_from_the_histogram(n):
    from nail2nail.merge.figures import _percentile_99

    values = np.random.default_rng(n).integers(0, 256, (n, 3)).astype(np.uint8)
    assert _percentile_99(values) == np.percentile(values.astype(float), 99)
    assert _percentile_99(np.full(n, 7, np.uint8)) == 7.0


def test_block_mean_ignores_nan():
    from nail2nail.merge.figures import _block_mean

    image = np.arange(35, dtype=float).reshape(5, 7)
    image[0, :2] = np.nan
    image[3:, 6] = np.nan
    out = _block_mean(image, 2)
    assert out.shape == (3, 4)
    assert out[0, 0] == pytest.approx(np.nanmean(image[:2, :2]))
    assert out[2, 3] != out[2, 3]  # the corner block holds only NaN
    assert out[1, 3] == image[2, 6]  # a block cut at the edges
    assert _block_mean(image, 1) is image


def test_mapping_file_reads_back(noisy, tmp_path):
    from nail2nail.merge.report import _save_mapping

    m = correspond(noisy[0], noisy[1])
    path = _save_mapping(tmp_path / "m.npz", m)
    with np.load(path) as f:
        np.testing.assert_array_equal(f["mapping"], m.mapping)
        np.testing.assert_array_equal(f["parent_rc"], m.parent_rc)
        np.testing.assert_array_equal(f["xyz_child"], m.xyz_child.astype(np.float32))
        assert f["rejected_reason"].tolist() == m.rejected.reason.tolist()


def test_threads_do_not_change_the_result(noisy, monkeypatch):
    import nail2nail.merge.correspondence as mc

    monkeypatch.setattr(mc, "_THREAD_MIN_ITEMS", 50)  # split even these small scans
    serial = correspond(noisy[0], noisy[1], workers=1)
    for workers in (-1, 3):
        m = correspond(noisy[0], noisy[1], workers=workers)
        np.testing.assert_array_equal(m.parent_rc, serial.parent_rc)
        np.testing.assert_array_equal(m.child_rc, serial.child_rc)
        np.testing.assert_array_equal(m.xyz_child, serial.xyz_child)
        assert m.dropped == serial.dropped


def test_write_merge_figure_failure_raises_and_writes_nothing(noisy, tmp_path, monkeypatch):
    # figures are drawn on a thread beside the merge: a failure there still fails the merge
    import nail2nail.merge.figures as figures
    from nail2nail.merge.report import write_merge

    def failing(*args, **kwargs):
        raise OSError("histogram: disk full")

    monkeypatch.setattr(figures, "plot_merge_histogram", failing)
    with pytest.raises(OSError, match="disk full"):
        write_merge(noisy, tmp_path / "out", stride=3, super_scan=False)
    assert not (tmp_path / "out").exists()
    monkeypatch.undo()
    summary = write_merge(noisy, tmp_path / "out", stride=3, super_scan=True)
    assert list(summary["merge"]["0-1"]["files"]) == ["mapping", "heatmap", "histogram",
                                                      "points3d", "marked"]
    assert list(summary["super_scan"]["files"]) == ["ply", "mat5", "render_front", "render_side"]
    assert summary["outputs"][:5] == list(summary["merge"]["0-1"]["files"].values())
    assert summary["outputs"][-3:-1] == [summary["super_scan"]["files"][k]
                                         for k in ("render_front", "render_side")]
    assert all(Path(p).exists() for p in summary["outputs"])
