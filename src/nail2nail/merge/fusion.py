"""The super scan: one nail-to-nail point cloud and mesh fused from all cameras.

Every camera's scan is a grid of world points. Where two cameras see the same surface, the
projector-space correspondence of :mod:`nail2nail.merge` pairs their pixels; :func:`fuse_scans`
keeps each surface point once, on the grid of the camera with the highest priority that sees it,
and moves it to the weighted mean of every camera's point for it. The weight of a camera's point
is its fringe modulation × the cosine of its viewing angle × a feather that falls to zero at the
edge of the camera's valid region, so the fused surface joins the single-camera surfaces beside
it without a step. Only reliable pairs are averaged (:data:`nail2nail.merge.REJECT_REASONS`:
a rejected pair keeps the better-viewed camera's point), and points that stand off their
neighbours (spikes) or, left unfused, off the other cameras' surface are dropped. Holes stay
holes; the mesh joins neighbouring pixels of one grid (two triangles per 2 × 2 block, no
triangle with a long edge), so the fused region is meshed from one camera.

The **super mat5** (the thesis's merged file set, chapter five) is defined here as one mat5 grid
holding the cameras side by side, left to right in scan order, separated by `gap_px` invalid
columns: each column block is a camera's own pixel grid with the fused world points on the pixels
it owns and NaN (intensity 0) elsewhere, so every valid pixel of the super mat5 is exactly one
vertex of the super scan and legacy tools that mesh a mat5 grid mesh each camera separately.

Each per-pixel step runs as a compiled kernel (numba) repeating the float64 arithmetic of the
NumPy formulation it replaced (kept as the reference in ``tests/test_merge_fusion_fast.py``), each
per-scan image is computed once, and the two 3D searches (duplicates, points off the surface) use
one grid of columns per camera instead of k-d trees: on a full-resolution finger the fusion
takes a few hundred milliseconds besides the correspondences (``bench/fusion.py``).
"""

from __future__ import annotations

import itertools
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numba
import numpy as np

from nail2nail._feather import feather
from nail2nail._interpolate import bilinear_value
from nail2nail._numba_cache import cache_enabled
from nail2nail._timing import StepClock
from nail2nail._validation import as_int
from nail2nail.io.mat5 import write_mat5
from nail2nail.io.ply import write_ply
from nail2nail.merge.correspondence import (
    REJECT_REASONS,
    Correspondence,
    CorrespondenceCache,
    _check_scan,
    _correspond,
    _view_cosine,
    grid_normals,
    same_pixel_pairs,
    valid_mask,
    view_cosine,
)
from nail2nail.scan.results import Scan

__all__ = [
    "SuperScan",
    "fuse_scans",
    "grid_mesh",
    "grid_normals",
    "spikes",
    "super_mat5_scan",
    "view_weights",
    "write_super_mat5",
    "write_super_ply",
]

# -- compiled kernels ------------------------------------------------------------------------
# They repeat NumPy's float64 arithmetic operation by operation (no fastmath), so the fused
# surface does not depend on which path computed it: a norm sums its squares left to right,
# einsum sums three products as (p0 + p2) + p1 and np.sum eight values as a pairwise tree.
_CACHE = cache_enabled()
_JIT = {"cache": _CACHE, "nogil": True, "error_model": "numpy"}
_DBL_MAX = float(np.finfo(np.float64).max)


@numba.njit(**_JIT)
def _nan_to_num(v):
    """``np.nan_to_num`` of one float64."""
    if v != v:
        return 0.0
    if v == np.inf:
        return _DBL_MAX
    if v == -np.inf:
        return -_DBL_MAX
    return v


@numba.njit(**_JIT)
def _dot3(a0, a1, a2, b0, b1, b2):
    """``np.einsum("...k,...k->...")`` of two float64 3-vectors, in its order of summation."""
    return (a0 * b0 + a2 * b2) + a1 * b1


@numba.njit(**_JIT)
def _norm3(a0, a1, a2):
    """``np.linalg.norm`` of a float64 3-vector."""
    return np.sqrt((a0 * a0 + a1 * a1) + a2 * a2)


_STEP_R = (1, 0, 1, 1)  # the four lines through a pixel (spikes): column, row, diagonals
_STEP_C = (0, 1, 1, -1)


@numba.njit(**_JIT)
def _is_spike(xyz, ok, r, c, spike_mm):
    """:func:`spikes` at one pixel, the full test."""
    h, w = ok.shape
    chord = np.empty((4, 3))
    mid = np.empty((4, 3))
    line = np.zeros(4, np.bool_)
    for k in range(4):
        rb, cb = r - _STEP_R[k], c - _STEP_C[k]
        ra, ca = r + _STEP_R[k], c + _STEP_C[k]
        line[k] = (0 <= rb < h and 0 <= cb < w and 0 <= ra < h and 0 <= ca < w and ok[rb, cb]
                   and ok[ra, ca])
        if line[k]:
            for d in range(3):
                before, after = np.float64(xyz[rb, cb, d]), np.float64(xyz[ra, ca, d])
                chord[k, d] = after - before
                mid[k, d] = 0.5 * (before + after)
    n0 = n1 = n2 = 0.0
    for k in range(4):
        for m in range(k + 1, 4):
            if not (line[k] and line[m]):
                continue  # a NaN cross product: nan_to_num adds 0
            # orient every pair's cross product alike: by the sign of the pixel steps' own
            sign = 1.0 if _STEP_R[k] * _STEP_C[m] - _STEP_C[k] * _STEP_R[m] > 0 else -1.0
            a0, a1, a2 = chord[k, 0], chord[k, 1], chord[k, 2]
            b0, b1, b2 = chord[m, 0], chord[m, 1], chord[m, 2]
            n0 += _nan_to_num(sign * (a1 * b2 - a2 * b1))
            n1 += _nan_to_num(sign * (a2 * b0 - a0 * b2))
            n2 += _nan_to_num(sign * (a0 * b1 - a1 * b0))
    length = _norm3(n0, n1, n2)
    n0, n1, n2 = n0 / length, n1 / length, n2 / length
    x0, x1, x2 = np.float64(xyz[r, c, 0]), np.float64(xyz[r, c, 1]), np.float64(xyz[r, c, 2])
    smallest = np.inf
    lines = 0
    for k in range(4):
        if line[k]:
            lines += np.isfinite(mid[k, 0])
            offset = abs(_dot3(x0 - mid[k, 0], x1 - mid[k, 1], x2 - mid[k, 2], n0, n1, n2))
            if offset < smallest:  # np.fmin: a NaN offset leaves it
                smallest = offset
    return lines >= 2 and np.isfinite(smallest) and smallest > spike_mm


@numba.njit(**_JIT)
def _spike_kernel(xyz, valid, spike_mm):  # pragma: no cover - compiled
    """:func:`spikes` pixel by pixel.

    The offset on a line is at most the distance from the pixel to the line's midpoint (the
    normal is a unit vector), so a pixel within `spike_mm` of a midpoint is no spike (with a
    margin far above the rounding): only the others (spikes, steps) take the full test.
    """
    h, w = valid.shape
    ok = np.empty((h, w), np.bool_)
    for r in range(h):
        for c in range(w):
            ok[r, c] = (valid[r, c] and np.isfinite(xyz[r, c, 0]) and np.isfinite(xyz[r, c, 1])
                        and np.isfinite(xyz[r, c, 2]))
    near2 = (spike_mm * (1.0 - 1e-9)) ** 2
    out = np.zeros((h, w), np.bool_)
    for r in range(h):
        for c in range(w):
            if not ok[r, c]:
                continue
            near = False
            for k in range(4):
                rb, cb = r - _STEP_R[k], c - _STEP_C[k]
                ra, ca = r + _STEP_R[k], c + _STEP_C[k]
                if (0 <= rb < h and 0 <= cb < w and 0 <= ra < h and 0 <= ca < w and ok[rb, cb]
                        and ok[ra, ca]):
                    d2 = 0.0
                    for d in range(3):
                        before, after = np.float64(xyz[rb, cb, d]), np.float64(xyz[ra, ca, d])
                        e = np.float64(xyz[r, c, d]) - 0.5 * (before + after)
                        d2 += e * e
                    if d2 < near2:
                        near = True
                        break
            if not near:
                out[r, c] = _is_spike(xyz, ok, r, c, spike_mm)
    return out


@numba.njit(**_JIT)
def _weight_kernel(valid, modulation, normals, xyz, center, feather, use_modulation,
                   use_cosine):  # pragma: no cover - compiled
    """:func:`view_weights` without smoothing: modulation × view cosine × feather, 0 invalid."""
    h, w = valid.shape
    out = np.zeros((h, w))
    for r in range(h):
        for c in range(w):
            if not valid[r, c]:
                continue
            weight = 1.0
            if use_modulation:
                weight *= max(_nan_to_num(np.float64(modulation[r, c])), 0.0)
            if use_cosine:
                v0 = center[0] - np.float64(xyz[r, c, 0])
                v1 = center[1] - np.float64(xyz[r, c, 1])
                v2 = center[2] - np.float64(xyz[r, c, 2])
                length = _norm3(v0, v1, v2)
                cos = _nan_to_num(_dot3(np.float64(normals[r, c, 0]), np.float64(normals[r, c, 1]),
                                        np.float64(normals[r, c, 2]), v0 / length, v1 / length,
                                        v2 / length))
                weight *= min(max(cos, 0.0), 1.0)
            out[r, c] = weight * feather[r, c]
    return out


@numba.njit(**_JIT)
def _score_kernel(valid, cosine, feather):  # pragma: no cover - compiled
    """The ownership score: smoothed view cosine × feather on the valid pixels, else 0."""
    h, w = valid.shape
    out = np.zeros((h, w))
    for r in range(h):
        for c in range(w):
            if valid[r, c]:
                out[r, c] = cosine[r, c] * feather[r, c]
    return out


@numba.njit(**_JIT)
def _row_steps(xyz):  # pragma: no cover - compiled
    """Finite distances between horizontally adjacent pixels, in `xyz`'s dtype (as
    ``np.linalg.norm(np.diff(xyz, axis=1), axis=-1)``)."""
    h, w = xyz.shape[:2]
    out = np.empty(h * max(w - 1, 0), xyz.dtype)
    n = 0
    for r in range(h):
        for c in range(w - 1):
            d0 = xyz[r, c + 1, 0] - xyz[r, c, 0]
            d1 = xyz[r, c + 1, 1] - xyz[r, c, 1]
            d2 = xyz[r, c + 1, 2] - xyz[r, c, 2]
            d = np.sqrt((d0 * d0 + d1 * d1) + d2 * d2)
            if np.isfinite(d):
                out[n] = d
                n += 1
    return out[:n]


@numba.njit(**_JIT)
def _ownership_kernel(keep, index, score, other_score, parent_rc, child_rc, by_priority,
                      other_first):  # pragma: no cover - compiled
    """Drop from `keep` (indexed through `index`) each parent pixel whose child views it better
    (a larger `other_score` at the sub-pixel child position; ties to `other_first`), or with
    `by_priority` each one whose child comes first."""
    for k in range(parent_rc.shape[0]):
        r, c = parent_rc[k, 0], parent_rc[k, 1]
        if by_priority:
            lose = other_first
        else:
            other = bilinear_value(other_score, child_rc[k, 0], child_rc[k, 1])
            mine = score[r, c]
            lose = other > mine or (other == mine and other_first)
        if lose and index[r, c] >= 0:
            keep[index[r, c]] = False


@numba.njit(**_JIT)
def _fusion_init(keep, rows, cols, xyz, weight):  # pragma: no cover - compiled
    """Weight sum, weighted point sum and count of each kept pixel, its own point only."""
    n = rows.size
    w_sum = np.zeros(n)
    acc = np.zeros((n, 3))
    count = np.zeros(n, np.uint8)
    for k in range(n):
        if keep[k]:
            r, c = rows[k], cols[k]
            w_sum[k] = weight[r, c]
            for d in range(3):
                acc[k, d] = np.float64(xyz[r, c, d]) * w_sum[k]
            count[k] = 1
    return w_sum, acc, count


@numba.njit(**_JIT)
def _fusion_add(keep, index, w_sum, acc, count, parent_rc, child_rc, xyz_child,
                other_weight):  # pragma: no cover - compiled
    """Add one child camera's corresponding points, weighted at their sub-pixel positions."""
    for k in range(parent_rc.shape[0]):
        i = index[parent_rc[k, 0], parent_rc[k, 1]]
        if i < 0 or not keep[i]:
            continue
        w = bilinear_value(other_weight, child_rc[k, 0], child_rc[k, 1])
        w_sum[i] += w
        for d in range(3):
            acc[i, d] += w * xyz_child[k, d]
        count[i] += 1


@numba.njit(**_JIT)
def _fusion_mean(keep, rows, cols, xyz, w_sum, acc):  # pragma: no cover - compiled
    """The weighted mean of each kept pixel (its own point where the weights sum to 0)."""
    out = np.empty((rows.size, 3))
    for k in range(rows.size):
        for d in range(3):
            own = np.float64(xyz[rows[k], cols[k], d])
            out[k, d] = acc[k, d] / w_sum[k] if keep[k] and w_sum[k] > 0 else own
    return out


@numba.njit(**_JIT)
def _confirm_kernel(trust, index, parent_rc, xyz_parent, xyz_child, surface_mm):
    """Trust ∞ for the parent pixels of kept pairs closer than `surface_mm` (confirmed)."""
    for k in range(parent_rc.shape[0]):
        d = _norm3(xyz_parent[k, 0] - xyz_child[k, 0], xyz_parent[k, 1] - xyz_child[k, 1],
                   xyz_parent[k, 2] - xyz_child[k, 2])
        i = index[parent_rc[k, 0], parent_rc[k, 1]]
        if d <= surface_mm and i >= 0:
            trust[i] = np.inf


# -- a uniform grid of columns over each camera's points: fixed-radius and nearest searches ----
# Columns are squares of `size` mm from `origin` across the first two of `axes`, clamped to
# `shape` (a cell index is monotone in the coordinate, so clamping loses no neighbour), running
# along the third. The points are sorted by (group, column, coordinate along the column), so a
# query reads a few contiguous runs, each found by a binary search.
@numba.njit(**_JIT)
def _cell(x, origin, size, n):
    """Cell index along one axis, clamped to ``[0, n)``."""
    return np.int64(min(max((x - origin) / size, 0.0), n - 1.0))


@numba.njit(**_JIT)
def _grid_build(points, group_start, size, max_cells, low, high):  # pragma: no cover - compiled
    """Sort each group's points (``points[group_start[g]:group_start[g + 1]]``) by column and
    coordinate along it, with columns of `size` from the corner `low` of the box
    ``[low, high]`` (:func:`_grid_box`: the bulk of the points; points beyond fall in the
    border columns), at most `max_cells` across along ``axes[0]`` and ``axes[1]`` (the box's
    extents, longest first; the columns run along ``axes[2]``).

    Returns ``(column_start, sorted_points, sorted_index, origin, shape, axes)``: column
    ``t = (g × shape[0] + a) × shape[1] + b`` holds the sorted points
    ``column_start[t]:column_start[t + 1]`` (ascending along ``axes[2]``), `sorted_index` their
    rows in `points`.
    """
    n = points.shape[0]
    n_groups = group_start.size - 1
    extent = high - low
    axes = np.argsort(-extent, kind="mergesort")
    shape = np.empty(3, np.int64)
    for k in range(3):
        shape[k] = np.int64(min(np.floor(extent[axes[k]] / size) + 1.0, max_cells[k]))
    n_columns = n_groups * shape[0] * shape[1]
    column = np.empty(n, np.int32)
    column_start = np.zeros(n_columns + 1, np.int64)
    sorted_points = np.empty((n, 3), points.dtype)
    sorted_index = np.empty(n, np.int32)
    for g in range(n_groups):
        for i in range(group_start[g], group_start[g + 1]):
            a = _cell(points[i, axes[0]], low[axes[0]], size, shape[0])
            b = _cell(points[i, axes[1]], low[axes[1]], size, shape[1])
            column[i] = (g * shape[0] + a) * shape[1] + b
            column_start[column[i] + 1] += 1
    for t in range(n_columns):
        column_start[t + 1] += column_start[t]
    cursor = column_start[:-1].copy()
    for i in range(n):  # by column, in the points' order
        p = cursor[column[i]]
        cursor[column[i]] += 1
        sorted_index[p] = i
        for d in range(3):
            sorted_points[p, d] = points[i, d]
    along = axes[2]
    for t in range(n_columns):  # then along a column: insertion (a pixel row's run is sorted)
        for p in range(column_start[t] + 1, column_start[t + 1]):
            key = sorted_points[p, along]
            if sorted_points[p - 1, along] <= key:
                continue
            index = sorted_index[p]
            x0, x1, x2 = sorted_points[p, 0], sorted_points[p, 1], sorted_points[p, 2]
            m = p
            while m > column_start[t] and sorted_points[m - 1, along] > key:
                sorted_index[m] = sorted_index[m - 1]
                for d in range(3):
                    sorted_points[m, d] = sorted_points[m - 1, d]
                m -= 1
            sorted_index[m] = index
            sorted_points[m, 0], sorted_points[m, 1], sorted_points[m, 2] = x0, x1, x2
    return column_start, sorted_points, sorted_index, low, shape, axes


@numba.njit(**_JIT)
def _reach(radius):
    """`radius` widened far above the rounding of a squared distance: the search bound that
    keeps every point whose computed distance is below `radius`."""
    return radius * (1.0 + 1e-9) + 1e-12


@numba.njit(**_JIT)
def _run(column_start, sorted_points, along, column, lo, hi):
    """The sorted points of `column` with a coordinate `along` in ``[lo, hi]``:
    ``(first, stop)``."""
    first, stop = column_start[column], column_start[column + 1]
    while first < stop:  # binary search of the first coordinate ≥ lo
        half = (first + stop) // 2
        if sorted_points[half, along] < lo:
            first = half + 1
        else:
            stop = half
    stop = first
    end = column_start[column + 1]
    while stop < end and sorted_points[stop, along] <= hi:
        stop += 1
    return first, stop


@numba.njit(**_JIT)
def _dedupe_kernel(column_start, sorted_points, sorted_index, origin, size, shape, axes,
                   searched, sorted_keep, keep, query, query_start,
                   radius):  # pragma: no cover - compiled
    """Drop from `keep` each point of `query` (``keep[query_start + k]``) that lies closer than
    `radius` to a point of a `searched` group kept in `sorted_keep`; return how many."""
    r2 = radius * radius  # cKDTree's bound: squared, strict
    removed = 0
    for k in range(query.shape[0]):
        if not keep[query_start + k]:
            continue
        q0, q1, q2 = np.float64(query[k, 0]), np.float64(query[k, 1]), np.float64(query[k, 2])
        reach = _reach(radius)
        x, y, z = query[k, axes[0]], query[k, axes[1]], np.float64(query[k, axes[2]])
        a_lo = _cell(x - reach, origin[axes[0]], size, shape[0])
        a_hi = _cell(x + reach, origin[axes[0]], size, shape[0])
        b_lo = _cell(y - reach, origin[axes[1]], size, shape[1])
        b_hi = _cell(y + reach, origin[axes[1]], size, shape[1])
        near = False
        for g in range(searched.size):
            if not searched[g] or near:
                continue
            for a in range(a_lo, a_hi + 1):
                for b in range(b_lo, b_hi + 1):
                    if near:
                        break
                    first, stop = _run(column_start, sorted_points, axes[2],
                                       (g * shape[0] + a) * shape[1] + b, z - reach, z + reach)
                    for p in range(first, stop):
                        if not sorted_keep[p]:
                            continue
                        d0 = q0 - np.float64(sorted_points[p, 0])
                        d1 = q1 - np.float64(sorted_points[p, 1])
                        d2 = q2 - np.float64(sorted_points[p, 2])
                        if (d0 * d0 + d1 * d1) + d2 * d2 < r2:
                            near = True
                            break
        if near:
            keep[query_start + k] = False
            removed += 1
    return removed


@numba.njit(**_JIT)
def _smallest_eigen(a00, a01, a02, a11, a12, a22):
    """Eigenvalues (ascending) of a symmetric 3 × 3 matrix and the unit eigenvector of the
    smallest (trigonometric solution of the characteristic cubic; Smith 1961)."""
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    q = (a00 + a11 + a22) / 3.0
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p2 = b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * p1
    if p2 == 0.0:
        return q, q, q, 1.0, 0.0, 0.0
    p = np.sqrt(p2 / 6.0)
    det = (b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02)
           + a02 * (a01 * a12 - b11 * a02))
    half = min(max(det / (2.0 * p * p * p), -1.0), 1.0)
    phi = np.arccos(half) / 3.0
    l2 = q + 2.0 * p * np.cos(phi)
    l0 = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    l1 = 3.0 * q - l2 - l0
    # the eigenvector of l0: the longest cross product of two rows of A - l0 I
    m00, m11, m22 = a00 - l0, a11 - l0, a22 - l0
    best, v0, v1, v2 = -1.0, 1.0, 0.0, 0.0
    for rows in range(3):
        if rows == 0:  # row 0 × row 1
            u0, u1, u2, w0, w1, w2 = m00, a01, a02, a01, m11, a12
        elif rows == 1:  # row 0 × row 2
            u0, u1, u2, w0, w1, w2 = m00, a01, a02, a02, a12, m22
        else:  # row 1 × row 2
            u0, u1, u2, w0, w1, w2 = a01, m11, a12, a02, a12, m22
        c0, c1, c2 = u1 * w2 - u2 * w1, u2 * w0 - u0 * w2, u0 * w1 - u1 * w0
        length = c0 * c0 + c1 * c1 + c2 * c2
        if length > best:
            best, v0, v1, v2 = length, c0, c1, c2
    length = np.sqrt(best)
    if length > 0:
        v0, v1, v2 = v0 / length, v1 / length, v2 / length
    else:
        v0, v1, v2 = 1.0, 0.0, 0.0
    return l0, l1, l2, v0, v1, v2


@numba.njit(**_JIT)
def _off_surface_kernel(column_start, sorted_points, sorted_index, origin, size, shape, axes,
                         trust, own_group, query, score, radius,
                        surface_mm):  # pragma: no cover - compiled
    """For each query point: off the plane of its 8 nearest points of the other groups within
    `radius` (at least 3, sorted by distance) by more than `surface_mm`, where those are planar
    and their mean `trust` exceeds the point's `score`. See :func:`fuse_scans`, step 4."""
    k_max = 8
    r2 = radius * radius
    out = np.zeros(query.shape[0], np.bool_)
    best_d = np.empty(k_max)
    best_i = np.empty(k_max, np.int64)
    best_p = np.empty(k_max, np.int64)
    t = np.zeros(k_max)
    n_groups = (column_start.size - 1) // (shape[0] * shape[1])
    for q in range(query.shape[0]):
        q0, q1, q2 = query[q, 0], query[q, 1], query[q, 2]
        reach = _reach(radius)
        x, y, z = query[q, axes[0]], query[q, axes[1]], np.float64(query[q, axes[2]])
        a_lo = _cell(x - reach, origin[axes[0]], size, shape[0])
        a_hi = _cell(x + reach, origin[axes[0]], size, shape[0])
        b_lo = _cell(y - reach, origin[axes[1]], size, shape[1])
        b_hi = _cell(y + reach, origin[axes[1]], size, shape[1])
        found = 0
        for g in range(n_groups):
            if g == own_group:
                continue
            for a in range(a_lo, a_hi + 1):
                for b in range(b_lo, b_hi + 1):
                    first, stop = _run(column_start, sorted_points, axes[2],
                                       (g * shape[0] + a) * shape[1] + b, z - reach, z + reach)
                    for p in range(first, stop):
                        d0 = q0 - np.float64(sorted_points[p, 0])
                        d1 = q1 - np.float64(sorted_points[p, 1])
                        d2 = q2 - np.float64(sorted_points[p, 2])
                        d = (d0 * d0 + d1 * d1) + d2 * d2
                        if d >= r2:
                            continue
                        j = sorted_index[p]
                        last = best_d[k_max - 1]
                        if found == k_max and (d > last or (d == last and j > best_i[k_max - 1])):
                            continue
                        m = found if found < k_max else k_max - 1  # insert, in (d, j) order
                        while m > 0 and (best_d[m - 1] > d or (best_d[m - 1] == d
                                                               and best_i[m - 1] > j)):
                            best_d[m] = best_d[m - 1]
                            best_i[m] = best_i[m - 1]
                            best_p[m] = best_p[m - 1]
                            m -= 1
                        best_d[m], best_i[m], best_p[m] = d, j, p
                        found = min(found + 1, k_max)
        if found < 3:
            continue
        c0 = c1 = c2 = 0.0
        for m in range(found):
            p = best_p[m]
            c0 += np.float64(sorted_points[p, 0])
            c1 += np.float64(sorted_points[p, 1])
            c2 += np.float64(sorted_points[p, 2])
        c0, c1, c2 = c0 / found, c1 / found, c2 / found
        a00 = a01 = a02 = a11 = a12 = a22 = 0.0
        for m in range(found):
            p = best_p[m]
            d0 = np.float64(sorted_points[p, 0]) - c0
            d1 = np.float64(sorted_points[p, 1]) - c1
            d2 = np.float64(sorted_points[p, 2]) - c2
            a00 += d0 * d0
            a01 += d0 * d1
            a02 += d0 * d2
            a11 += d1 * d1
            a12 += d1 * d2
            a22 += d2 * d2
        _, l1, l2, n0, n1, n2 = _smallest_eigen(a00, a01, a02, a11, a12, a22)
        # points along a line (a grazing view's single row) define no plane
        planar = l1 > 0.05 * l2
        offset = abs(_dot3(q0 - c0, q1 - c1, q2 - c2, n0, n1, n2))
        for m in range(k_max):
            t[m] = trust[best_i[m]] if m < found else 0.0
        mean = (((t[0] + t[1]) + (t[2] + t[3])) + ((t[4] + t[5]) + (t[6] + t[7]))) / found
        out[q] = planar and offset > surface_mm and mean > score[q]
    return out


# -- the fused grid: normals and mesh ---------------------------------------------------------
@numba.njit(**_JIT)
def _fused_normals(xyz, index, keep, fused, rows, cols, center, use_center):  # pragma: no cover
    """:func:`grid_normals` of the grid holding the fused points on the kept pixels (and the
    scan's own elsewhere), at the kept pixels `rows`, `cols` only (same arithmetic)."""
    h, w = index.shape
    out = np.empty((rows.size, 3), np.float32)
    # the pixel and its neighbours above, below, left and right; NaN beyond the image
    near = np.empty((5, 3))
    step_r = (0, -1, 1, 0, 0)
    step_c = (0, 0, 0, -1, 1)
    deriv = np.empty((2, 3))
    for k in range(rows.size):
        r, c = rows[k], cols[k]
        for m in range(5):
            rr, cc = r + step_r[m], c + step_c[m]
            if 0 <= rr < h and 0 <= cc < w:
                i = index[rr, cc]
                if i >= 0 and keep[i]:
                    for d in range(3):
                        near[m, d] = fused[i, d]
                else:
                    for d in range(3):
                        near[m, d] = np.float64(xyz[rr, cc, d])
            else:
                for d in range(3):
                    near[m, d] = np.nan
        for axis in range(2):  # central difference, else forward, else backward
            before, after = 1 + 2 * axis, 2 + 2 * axis
            for d in range(3):
                value = 0.5 * (near[after, d] - near[before, d])
                if value != value:
                    value = near[after, d] - near[0, d]
                if value != value:
                    value = near[0, d] - near[before, d]
                deriv[axis, d] = value
        a0, a1, a2 = deriv[0, 0], deriv[0, 1], deriv[0, 2]
        b0, b1, b2 = deriv[1, 0], deriv[1, 1], deriv[1, 2]
        n0, n1, n2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
        length = _norm3(n0, n1, n2)
        n0, n1, n2 = n0 / length, n1 / length, n2 / length
        if use_center and _dot3(n0, n1, n2, center[0] - near[0, 0], center[1] - near[0, 1],
                                center[2] - near[0, 2]) < 0:
            n0, n1, n2 = -n0, -n1, -n2
        out[k, 0], out[k, 1], out[k, 2] = n0, n1, n2
    return out


@numba.njit(**_JIT)
def _vertex_index(keep, fused):  # pragma: no cover - compiled
    """Each kept point's vertex number (−1: not kept, or not finite in float32), and how many."""
    vertex = np.full(keep.size, -1, np.int64)
    n = 0
    for i in range(keep.size):
        if keep[i] and np.isfinite(np.float32(fused[i, 0])) and np.isfinite(
                np.float32(fused[i, 1])) and np.isfinite(np.float32(fused[i, 2])):
            vertex[i] = n
            n += 1
    return vertex, n


@numba.njit(**_JIT)
def _vertex_fill(keep, vertex, fused, rows, cols, normals, albedo, camera, offset, out_points,
                 out_normals, out_colors, out_camera, out_pixel):  # pragma: no cover - compiled
    """Write one camera's vertices from ``out_*[offset]`` on: point (float32), normal (of the
    kept pixels, in their order), grey albedo ``clip(255 a + 0.5, 0, 255)`` as uint8, camera and
    pixel."""
    k = 0
    for i in range(keep.size):
        if not keep[i]:
            continue
        v = vertex[i]
        if v >= 0:
            o = offset + v
            a = 255.0 * _nan_to_num(np.float64(albedo[rows[i], cols[i]])) + 0.5
            grey = np.uint8(min(max(a, 0.0), 255.0))
            for d in range(3):
                out_points[o, d] = np.float32(fused[i, d])
                out_normals[o, d] = normals[k, d]
                out_colors[o, d] = grey
            out_camera[o] = camera
            out_pixel[o, 0] = rows[i]
            out_pixel[o, 1] = cols[i]
        k += 1


@numba.njit(**_JIT)
def _triangle(points, normals, a, b, e, max_edge_mm, below2, above2):
    """Whether the triangle ``(a, b, e)`` has no edge longer than `max_edge_mm` (the norms
    taken only when a squared length lies between `below2` and `above2`, i.e. at the
    threshold), and whether its winding disagrees with the sum of its vertex normals."""
    for u, v in ((a, b), (b, e), (e, a)):
        d0 = np.float64(points[v, 0]) - np.float64(points[u, 0])
        d1 = np.float64(points[v, 1]) - np.float64(points[u, 1])
        d2 = np.float64(points[v, 2]) - np.float64(points[u, 2])
        length2 = (d0 * d0 + d1 * d1) + d2 * d2
        if length2 > below2 and not (length2 <= above2 and np.sqrt(length2) <= max_edge_mm):
            return False, False
    u0 = np.float64(points[b, 0]) - np.float64(points[a, 0])
    u1 = np.float64(points[b, 1]) - np.float64(points[a, 1])
    u2 = np.float64(points[b, 2]) - np.float64(points[a, 2])
    v0 = np.float64(points[e, 0]) - np.float64(points[a, 0])
    v1 = np.float64(points[e, 1]) - np.float64(points[a, 1])
    v2 = np.float64(points[e, 2]) - np.float64(points[a, 2])
    s0 = _nan_to_num((np.float64(normals[a, 0]) + np.float64(normals[b, 0]))
                     + np.float64(normals[e, 0]))
    s1 = _nan_to_num((np.float64(normals[a, 1]) + np.float64(normals[b, 1]))
                     + np.float64(normals[e, 1]))
    s2 = _nan_to_num((np.float64(normals[a, 2]) + np.float64(normals[b, 2]))
                     + np.float64(normals[e, 2]))
    flip = _dot3(u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0, s0, s1, s2) < 0
    return True, flip


@numba.njit(**_JIT)
def _mesh_kernel(index, vertex, points, normals, max_edge_mm, offset, out,
                 start):  # pragma: no cover - compiled
    """:func:`grid_mesh`'s triangles into ``out[start:]``: every block's first triangle
    (top-left, bottom-left, top-right) in row-major order, then every block's second
    (top-right, bottom-left, bottom-right); a pixel's vertex is ``vertex[index[r, c]]`` (−1:
    none), `offset` is added. Returns the end in `out`."""
    h, w = index.shape
    below2 = (max_edge_mm * (1.0 - 1e-9)) ** 2
    above2 = (max_edge_mm * (1.0 + 1e-9)) ** 2
    second = np.empty((points.shape[0], 3), np.int32)
    n_first = n_second = 0
    for r in range(h - 1):
        for c in range(w):  # the top-left of block (r, c) and the top-right of block (r, c - 1)
            i = index[r, c]
            if i < 0 or vertex[i] < 0:
                continue
            top = vertex[i]
            j = index[r + 1, c]
            below = vertex[j] if j >= 0 else -1
            if below < 0:
                continue
            if c + 1 < w:  # (top-left, bottom-left, top-right)
                j = index[r, c + 1]
                right = vertex[j] if j >= 0 else -1
                if right >= 0:
                    ok, flip = _triangle(points, normals, top, below, right, max_edge_mm,
                                         below2, above2)
                    if ok:
                        m = start + n_first
                        out[m, 0] = top + offset
                        out[m, 1] = (right if flip else below) + offset
                        out[m, 2] = (below if flip else right) + offset
                        n_first += 1
            if c >= 1:  # (top-right, bottom-left, bottom-right) of block (r, c - 1)
                j = index[r + 1, c - 1]
                left = vertex[j] if j >= 0 else -1
                if left >= 0:
                    ok, flip = _triangle(points, normals, top, left, below, max_edge_mm,
                                         below2, above2)
                    if ok:
                        second[n_second, 0] = top + offset
                        second[n_second, 1] = (below if flip else left) + offset
                        second[n_second, 2] = (left if flip else below) + offset
                        n_second += 1
    end = start + n_first
    out[end:end + n_second] = second[:n_second]
    return end + n_second


@numba.njit(**_JIT)
def _fused_images(index, keep, fused, normals, count, xp, yp, intensity, out_xyz, out_normals,
                  out_mask, out_views, out_xp, out_yp, out_intensity):  # pragma: no cover
    """One camera's fused grids: points and normals on the kept pixels (NaN elsewhere), the
    mask, the number of views, ``xp``/``yp`` (NaN off the mask) and the intensity (0 off)."""
    h, w = index.shape
    k = 0
    for r in range(h):
        for c in range(w):
            i = index[r, c]
            if i >= 0 and keep[i]:
                for d in range(3):
                    out_xyz[r, c, d] = fused[i, d]
                    out_normals[r, c, d] = normals[k, d]
                k += 1
                out_mask[r, c] = True
                out_views[r, c] = count[i]
                out_xp[r, c] = xp[r, c]
                out_yp[r, c] = yp[r, c]
                out_intensity[r, c] = intensity[r, c]
            else:
                for d in range(3):
                    out_xyz[r, c, d] = np.nan
                    out_normals[r, c, d] = np.nan
                out_mask[r, c] = False
                out_views[r, c] = 0
                out_xp[r, c] = np.nan
                out_yp[r, c] = np.nan
                out_intensity[r, c] = 0


#: Far outliers are left out of the box the fusion's search grid spans (:func:`_grid_box`):
#: per axis, the box reaches from the median this many times the median's distance to the
#: 5th and 95th percentiles (and no further than the points): a finger's points all lie within
#: it, and up to 5 % of the points on either side may be far outliers.
GRID_BOX_FACTOR = 2.0


def _grid_box(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)`` (3,) float64: the box of the bulk of `points` that the search grid spans.

    A scan's far outliers (a stray point metres away) would otherwise stretch the grid's 512
    columns across so wide a box that the whole finger falls into one column, and the search
    becomes quadratic in the points (minutes instead of seconds on a full-resolution finger).
    Points outside the box fall in its border columns (``_cell`` clamps), which loses none.
    """
    if not len(points):
        return np.zeros(3), np.zeros(3)
    low, high = points.min(axis=0).astype(np.float64), points.max(axis=0).astype(np.float64)
    sample = np.asarray(points[::max(1, len(points) // 200_000)], np.float64)
    q05, q50, q95 = np.percentile(sample, [5, 50, 95], axis=0)
    low = np.maximum(low, q50 - GRID_BOX_FACTOR * (q50 - q05))
    high = np.minimum(high, q50 + GRID_BOX_FACTOR * (q95 - q50))
    return low, np.maximum(high, low)


def _grid(points: np.ndarray, group_start: np.ndarray, size: float) -> tuple:
    """The cell grid of :func:`_grid_build` over `points` with cells of `size` mm: the leading
    arguments of :func:`_dedupe_kernel` and :func:`_off_surface_kernel`. At most 512 × 512
    columns over the bulk of the points (:func:`_grid_box`; points beyond fall in the border
    cells, which only slows the search); they run along the shortest extent, so they cross a
    finger's surface (and hold points) only where it faces that axis: a column is short."""
    low, high = _grid_box(points)
    column_start, sorted_points, index, origin, shape, axes = _grid_build(
        points, group_start, size, np.array([512, 512, 1 << 20]), low, high)
    return column_start, sorted_points, index, origin, size, shape, axes


# -- public functions --------------------------------------------------------------------------
def view_weights(
    scan: Scan,
    *,
    normals=None,
    feather_px: float = 8.0,
    use_modulation: bool = True,
    smooth_px: float = 0.0,
) -> np.ndarray:
    """Fusion weight of each pixel: modulation × cos(viewing angle) × edge feather.

    Parameters
    ----------
    scan : Scan
    normals : (H, W, 3) float, optional
        Surface normals (:func:`grid_normals` if omitted).
    feather_px : float
        Distance from the edge of the valid region (or of the image) over which the weight ramps
        from 0 to 1, px; 0 for no feather.
    use_modulation : bool
        Include the fringe modulation (``False``: a purely geometric score).
    smooth_px : float
        Gaussian smoothing (σ, px) of the cosine over the valid pixels; 0 for none.

    Returns
    -------
    (H, W) float64
        Non-negative weights; 0 on invalid pixels. Without ``scan.camera_center`` the cosine
        factor is 1.

    Examples
    --------
    >>> rr, cc = np.mgrid[0:20, 0:20].astype(np.float32)
    >>> one = np.ones((20, 20), np.float32)
    >>> scan = Scan("a", np.stack([cc, rr, 0 * rr], -1), cc, rr, one, one, one, one > 0)
    >>> w = view_weights(scan, feather_px=4)
    >>> float(w[0, 0]), float(w[10, 10])
    (0.125, 1.0)
    """
    _check_scan(scan, "scan")
    valid = valid_mask(scan)
    return _view_weights(scan, valid, normals, feather(valid, feather_px),
                         use_modulation=use_modulation, smooth_px=smooth_px)


def _view_weights(scan, valid, normals, feather, *, use_modulation, smooth_px) -> np.ndarray:
    """:func:`view_weights` with the valid mask and the feather given."""
    center = scan.camera_center
    if center is not None and normals is None:
        normals = grid_normals(scan.xyz, camera_center=center)
    if center is not None and smooth_px > 0:
        weight = valid.astype(np.float64)
        if use_modulation:
            weight *= np.clip(np.nan_to_num(np.asarray(scan.modulation, np.float64)), 0, None)
        weight *= view_cosine(scan, normals=normals, smooth_px=smooth_px)
        weight *= feather
        weight[~valid] = 0.0
        return weight
    xyz = np.ascontiguousarray(scan.xyz)
    return _weight_kernel(
        valid, np.ascontiguousarray(scan.modulation),
        np.ascontiguousarray(normals) if center is not None else np.zeros((1, 1, 3), np.float32),
        xyz, np.asarray(center if center is not None else (0, 0, 0), np.float64).reshape(3),
        feather, use_modulation, center is not None)


def spikes(xyz, valid, *, spike_mm: float = 0.05) -> np.ndarray:
    """Points that stand off the surface of their neighbours: lone decoding errors.

    For each valid pixel, the lines through it (row, column, two diagonals) whose two
    neighbours are valid; with at least two such lines, the local normal ``n`` is the
    normalised sum of the cross products of their chords (the pixel itself is not used), and
    the offset on a line is ``|n · (X − (X₋ + X₊) / 2)|``. A pixel is a spike when the offset
    exceeds `spike_mm` on every line (the smallest: a ridge, a step or a grazing view bends the
    surface along one direction, not across all). On a smooth surface the offset is the
    curvature term ``κ h² / 2`` (h the pixel spacing: about 4 µm on the finger's ridges at full
    resolution) plus the noise. Pixels with fewer than two lines (the outermost row of a valid
    region) are not tested: with one line, a spike and its neighbour look alike.

    Parameters
    ----------
    xyz : (H, W, 3) float
        World points, mm.
    valid : (H, W) bool
    spike_mm : float
        Largest accepted offset, mm.

    Returns
    -------
    (H, W) bool

    Raises
    ------
    ValueError
        If `xyz` is not ``(H, W, 3)`` for `valid`'s ``(H, W)``.

    Examples
    --------
    >>> rr, cc = np.mgrid[0:5, 0:5].astype(float)
    >>> xyz = np.stack([cc, -rr, 0 * cc], -1)
    >>> xyz[2, 2, 2] = 0.2
    >>> np.argwhere(spikes(xyz, np.ones((5, 5), bool))).tolist()
    [[2, 2]]
    """
    xyz = np.asarray(xyz)
    if not np.issubdtype(xyz.dtype, np.floating) or xyz.dtype.itemsize < 4:
        xyz = xyz.astype(np.float64)
    valid = np.ascontiguousarray(valid, dtype=bool)
    if valid.ndim != 2 or xyz.shape != (*valid.shape, 3):
        raise ValueError(f"xyz: expected shape {(*valid.shape, 3)} for valid {valid.shape}, "
                         f"got {xyz.shape}")
    return _spike_kernel(np.ascontiguousarray(xyz), valid, float(spike_mm))


def grid_mesh(xyz, keep, *, max_edge_mm: float, normals=None) -> tuple[np.ndarray, np.ndarray]:
    """Triangles joining neighbouring kept pixels of one grid.

    Each 2 × 2 block gives the triangles (top-left, bottom-left, top-right) and (top-right,
    bottom-left, bottom-right) when their three pixels are kept and no edge is longer than
    `max_edge_mm`; each triangle is wound counter-clockwise seen from the side `normals` point to.
    The first triangles of all blocks (row-major) come before the second ones.

    Parameters
    ----------
    xyz : (H, W, 3) float
        World points, mm.
    keep : (H, W) bool
        Pixels that are vertices.
    max_edge_mm : float
        Longest edge of a kept triangle, mm (depth discontinuities are not bridged).
    normals : (H, W, 3) float, optional
        Vertex normals used for the winding (:func:`grid_normals` if omitted).

    Returns
    -------
    vertex_index : (H, W) int64
        Index of each kept pixel among the vertices (row-major order), −1 elsewhere.
    faces : (F, 3) int64
        Vertex indices of each triangle.

    Examples
    --------
    >>> rr, cc = np.mgrid[0:2, 0:3].astype(float)
    >>> _, faces = grid_mesh(np.stack([cc, -rr, 0 * cc], -1), np.ones((2, 3), bool), max_edge_mm=2)
    >>> faces.shape
    (4, 3)
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    keep = np.asarray(keep, dtype=bool) & np.isfinite(xyz).all(axis=-1)
    index = np.full(keep.shape, -1, dtype=np.int64)
    n = int(np.count_nonzero(keep))
    index[keep] = np.arange(n)
    if normals is None:
        normals = grid_normals(xyz)
    faces = np.empty((2 * n, 3), dtype=np.int32)
    end = _mesh_kernel(index, np.arange(n), np.ascontiguousarray(xyz[keep]),
                       np.ascontiguousarray(np.asarray(normals)[keep]), float(max_edge_mm), 0,
                       faces, 0)
    return index, faces[:end].astype(np.int64)


@dataclass
class SuperScan:
    """A nail-to-nail scan fused from several cameras.

    Attributes
    ----------
    scans : list of Scan
        Per camera, its grid with fused world points on the pixels it owns; ``mask`` marks them
        and ``xyz`` is NaN elsewhere.
    normals : list of (H, W, 3) float32
        Per camera, unit normals of the fused grid (NaN off the owned pixels).
    n_views : list of (H, W) uint8
        Per camera, the number of cameras fused into each owned pixel (1: seen by its owner only).
    vertices : (N, 3) float32
        Every owned pixel of every camera, world mm (camera order, then row-major).
    vertex_normals : (N, 3) float32
    colors : (N, 3) uint8
        Albedo as grey.
    faces : (F, 3) int32
        Triangles, indices into `vertices`.
    camera : (N,) int16
        Index of the camera each vertex comes from.
    pixel : (N, 2) int32
        ``(row, col)`` of each vertex in its camera.
    correspondences : dict
        The :class:`~nail2nail.merge.Correspondence` of each ordered pair ``(i, j)`` used.
    valid_masks : list of (H, W) bool
        Per camera, the valid pixels the correspondences searched (spikes taken out): what
        :func:`~nail2nail.merge.restrict_pairs` needs to narrow a correspondence.
    priority : list of int
        Camera indices, highest priority first.
    duplicates_removed : dict[str, int]
        Per camera, owned points dropped as 3D duplicates of a higher-priority camera's points.
    points_rejected : dict[str, dict[str, int]]
        Per camera, points dropped as ``"spike"`` (before fusion, :func:`spikes`) and as
        ``"off_surface"`` (unfused points off the other cameras' fused surface).
    timings : dict[str, float]
        Wall time of each step of :func:`fuse_scans`, s, in order (``"correspond"``: the
        correspondences of all ordered pairs).
    """

    scans: list[Scan]
    normals: list[np.ndarray]
    n_views: list[np.ndarray]
    vertices: np.ndarray
    vertex_normals: np.ndarray
    colors: np.ndarray
    faces: np.ndarray
    camera: np.ndarray
    pixel: np.ndarray
    correspondences: dict = field(default_factory=dict)
    valid_masks: list = field(default_factory=list)
    priority: list[int] = field(default_factory=list)
    duplicates_removed: dict = field(default_factory=dict)
    points_rejected: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)

    @property
    def n_vertices(self) -> int:
        """Number of vertices."""
        return int(self.vertices.shape[0])

    def summary(self) -> dict:
        """JSON-ready counts: vertices, faces, per camera owned and fused pixels."""
        return {
            "vertices": self.n_vertices,
            "faces": int(self.faces.shape[0]),
            "priority": [self.scans[i].name for i in self.priority],
            "duplicates_removed": dict(self.duplicates_removed),
            "points_rejected": {k: dict(v) for k, v in self.points_rejected.items()},
            "rejected_pairs": {
                f"{i}-{j}": {k: int(m.dropped.get(k, 0)) for k in REJECT_REASONS}
                for (i, j), m in self.correspondences.items()
            },
            "cameras": {
                s.name: {"owned": int(s.mask.sum()), "fused": int(np.count_nonzero(v > 1))}
                for s, v in zip(self.scans, self.n_views, strict=True)
            },
        }


def scan_groups(n: int, projectors=None, cameras=None) -> tuple[list[int], list[int]]:
    """The projector and the camera of each of `n` scans, checked.

    Default: one projector, every scan its own camera (the thesis rig). ``ValueError`` for
    lists of another length than `n`, or two scans that share both their camera and their
    projector.
    """
    proj = [0] * n if projectors is None else [int(k) for k in projectors]
    cams = list(range(n)) if cameras is None else [int(k) for k in cameras]
    if len(proj) != n or len(cams) != n:
        raise ValueError(f"projectors, cameras: expected one index per scan ({n}), got "
                         f"{len(proj)} and {len(cams)}")
    if len(set(zip(proj, cams, strict=True))) != n:
        raise ValueError("projectors, cameras: two scans share both their camera and their "
                         "projector")
    return proj, cams


def pair_kind(groups, i: int, j: int) -> str | None:
    """How scans `i` and `j` of a rig are matched: ``"projector"`` when they share a
    projector (in its projector space), ``"camera"`` when they share a camera (at the same
    pixel), None when neither. `groups` is :func:`scan_groups`'s ``(projectors, cameras)``."""
    projectors, cameras = groups
    if projectors[i] == projectors[j]:
        return "projector"
    return "camera" if cameras[i] == cameras[j] else None


def fuse_scans(
    scans,
    *,
    priority=None,
    ownership: str = "angle",
    max_residual_px: float = 0.5,
    border_px: int = 1,
    feather_px: float = 8.0,
    max_edge_mm: float | None = None,
    dedupe_mm: float | None = None,
    spike_mm: float | None = 0.05,
    surface_mm: float | None = 0.05,
    max_view_angle_deg: float | None = 70.0,
    max_incidence_deg: float | None = 65.0,
    min_relative_modulation: float | None = 1 / 3,
    outlier_mm: float | None = 0.025,
    outlier_mad: float = 4.0,
    projectors=None,
    cameras=None,
    pair_by: str = "auto",
) -> SuperScan:
    """Fuse the scans of several cameras into one nail-to-nail point cloud and mesh.

    0. Spikes (:func:`spikes`: points off their neighbours' surface by more than `spike_mm`)
       are dropped from each camera's scan.
    1. Correspondence of every ordered pair of cameras in projector space
       (:func:`nail2nail.merge.correspond`, every pixel, paired by `pair_by`; with several
       projectors, the pairs of one projector so, the pairs of one camera under two
       projectors at the same pixel, :func:`nail2nail.merge.same_pixel_pairs`), with the
       unreliable pairs rejected
       (a view beyond `max_view_angle_deg`, the projector's light beyond `max_incidence_deg`
       from the normal, modulation below `min_relative_modulation` of the
       camera's median, a distance that is a local outlier: `outlier_mm`, `outlier_mad`).
    2. Ownership (duplicates removed): a pixel is dropped as a duplicate when another camera has
       a correspondence for it (kept or rejected: a rejected pair is still the same surface
       point, only too inaccurate to average) and views it better (``ownership="angle"``: a
       larger smoothed cos(viewing angle) × edge feather, `priority` breaking ties) or has a
       higher `priority` (``ownership="priority"``; for rejected pairs the better view decides
       in both modes); then points within `dedupe_mm` of a point kept by a camera of higher
       priority go too. The rest are the super scan's vertices, so an overlap is meshed from
       one camera.
    3. Fusion: each owned pixel moves to the weighted mean of its own point and its
       corresponding points in every other camera, over the kept pairs only (weights:
       :func:`view_weights`, interpolated at the sub-pixel correspondence). A point whose pair
       was rejected keeps the better-viewed camera's point: it is not averaged.
    4. A point left unfused (no kept pair) that lies farther than `surface_mm` from the plane
       of the other cameras' points around it (8 nearest within 3 pixel spacings) is dropped
       when those are confirmed (a kept pair closer than `surface_mm`) or view the surface
       better (the ownership score): a corrupted point at a mask edge or a shadow border,
       where no pair could be tested. Of two disagreeing lone points the better view stays.
    5. Normals of the fused grids (:func:`grid_normals`) and a mesh per camera grid
       (:func:`grid_mesh`).

    Every per-pixel step runs compiled (numba), each per-scan image (valid mask, normals, view
    cosine, feather, weights) is computed once, and the 3D searches of steps 2 and 4 share one
    uniform grid of cells over all cameras' valid points; :attr:`SuperScan.timings` holds each
    step's time.

    Parameters
    ----------
    scans : sequence of Scan
        At least one; names should differ.
    priority : sequence of int, optional
        Camera indices, highest priority first. Default: by decreasing number of valid pixels
        (the camera that sees most of the finger first).
    ownership : {"angle", "priority"}
        Which camera keeps a point seen by several.
    max_residual_px, border_px :
        Passed to :func:`~nail2nail.merge.correspond` (the overlap test).
    feather_px : float
        Width of the weight ramp at the edge of each camera's valid region, px.
    max_edge_mm : float, optional
        Longest mesh edge; default 4 × the median distance of horizontally adjacent pixels.
    dedupe_mm : float, optional
        After ownership, a point closer than this to a point owned by a camera of higher
        `priority` is dropped too (edges of valid regions, where correspondences are refused);
        default half the pixel spacing, 0 to skip.
    spike_mm : float or None
        Spike threshold of step 0, mm; None skips it.
    surface_mm : float or None
        Off-surface threshold of step 4, mm; None skips it.
    max_view_angle_deg, max_incidence_deg, min_relative_modulation, outlier_mm, outlier_mad :
        The rejection tests, passed to :func:`~nail2nail.merge.correspond`; None skips one.
    projectors, cameras : sequence of int, optional
        A rig of several projectors (:mod:`nail2nail.simulation.projectors`): per scan, the
        index of the projector and of the camera it was measured with; scans of one camera
        share its pixel grid. Default: one projector, every scan its own camera (the thesis
        rig). No two scans may share both.
    pair_by : {"auto", "xpyp", "xp", "yp"}
        What pairs two scans of one projector (:func:`~nail2nail.merge.correspond`): by
        default both projector coordinates, or the one coordinate both scans were triangulated
        from and the surface along it.

    Returns
    -------
    SuperScan

    Raises
    ------
    ValueError
        For no scans, a bad priority, or a scan without valid pixels.
    """
    clock = StepClock()
    scans = list(scans)
    if not scans:
        raise ValueError("scans: expected at least one Scan")
    for i, s in enumerate(scans):
        _check_scan(s, f"scans[{i}]")
    n = len(scans)
    # each scan's masks, view cosine and search grid, once for all its pairs
    cache = CorrespondenceCache()
    valid = [cache.valid_mask(s) for s in scans]
    for s, v in zip(scans, valid, strict=True):
        if not v.any():
            raise ValueError(f"scans: {s.name!r} has no valid pixels")
    if priority is None:
        priority = sorted(range(n), key=lambda i: (-int(valid[i].sum()), i))
    priority = [int(p) for p in priority]
    if sorted(priority) != list(range(n)):
        raise ValueError(f"priority: expected a permutation of 0..{n - 1}, got {priority}")
    border_px = as_int(border_px, "border_px", minimum=1)
    if ownership not in ("angle", "priority"):
        raise ValueError(f"ownership: expected 'angle' or 'priority', got {ownership!r}")
    for name, value in (("spike_mm", spike_mm), ("surface_mm", surface_mm)):
        if value is not None and not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name}: expected a positive number or None, got {value}")
    rank = {cam: k for k, cam in enumerate(priority)}
    projector_of, camera_of = scan_groups(n, projectors, cameras)
    for i, j in itertools.combinations(range(n), 2):
        if camera_of[i] == camera_of[j] and np.shape(scans[i].mask) != np.shape(scans[j].mask):
            raise ValueError(f"cameras: scans {scans[i].name!r} and {scans[j].name!r} are of "
                             "one camera but differ in size")

    normals0 = [grid_normals(s.xyz, camera_center=s.camera_center) for s in scans]
    clock("scan_normals")
    spikes_removed = dict.fromkeys((s.name for s in scans), 0)
    if spike_mm is not None:
        for i, s in enumerate(scans):
            bad = _spike_kernel(np.ascontiguousarray(s.xyz), valid[i], float(spike_mm))
            spikes_removed[s.name] = int(np.count_nonzero(bad))
            if spikes_removed[s.name]:
                valid[i] = valid[i] & ~bad
                scans[i] = replace(s, mask=valid[i], xyz=np.where(valid[i][..., None], s.xyz,
                                                                   np.float32(np.nan)))
                normals0[i] = grid_normals(scans[i].xyz, camera_center=s.camera_center)
    clock("spikes")

    # per scan, once: feather, fusion weights, and the smoothed view cosine that serves the
    # rejection test (through `quality`) and the ownership score
    feathers = [feather(v, feather_px) for v in valid]
    weights = [_view_weights(s, v, nm, f, use_modulation=True, smooth_px=0.0)
               for s, v, nm, f in zip(scans, valid, normals0, feathers, strict=True)]
    quality = {id(s): [_view_cosine(s, v, normals=nm, smooth_px=2.0),
                       None if s.projector_center is None or max_incidence_deg is None
                       else _view_cosine(s, v, normals=nm, smooth_px=2.0,
                                         center=s.projector_center), None]
               for s, v, nm in zip(scans, valid, normals0, strict=True)
               if s.camera_center is not None}
    scores = []  # view_weights(use_modulation=False, smooth_px=2) from the cached cosine
    for s, v, f in zip(scans, valid, feathers, strict=True):
        cos = quality[id(s)][0] if id(s) in quality else v.astype(np.float64)
        scores.append(_score_kernel(v, np.ascontiguousarray(cos, dtype=np.float64), f))
    del feathers, normals0  # what is held from here on is freed as soon as it is done with
    clock("weights")

    # pairs that share a projector match in its space (the thesis's merge), pairs that share
    # a camera at the same pixel; others have no correspondence of their own
    tests = {"max_view_angle_deg": max_view_angle_deg, "max_incidence_deg": max_incidence_deg,
             "min_relative_modulation": min_relative_modulation, "outlier_mm": outlier_mm,
             "outlier_mad": outlier_mad, "outlier_block_px": 32, "quality": quality,
             "cache": cache}
    corr: dict[tuple[int, int], Correspondence] = {}
    for i in range(n):
        for j in range(n):
            kind = None if i == j else pair_kind((projector_of, camera_of), i, j)
            if kind == "projector":
                corr[i, j] = _correspond(
                    scans[i], scans[j], stride=1, max_residual_px=max_residual_px,
                    border_px=border_px, max_jump_px=2.0, refine=True, method="grid",
                    workers=-1, pair_by=pair_by, **tests)
            elif kind == "camera":
                corr[i, j] = same_pixel_pairs(scans[i], scans[j], border_px=border_px,
                                              max_jump_px=2.0, **tests)
    del quality, cache, tests
    clock("correspond")

    # the valid pixels of all cameras, numbered camera by camera in row-major order: `keep`
    # (and `trust`) hold one entry per valid pixel, `index[i]` maps camera i's pixels to theirs
    pixels = [np.flatnonzero(v) for v in valid]
    sizes = np.array([p.size for p in pixels])
    start = np.concatenate([[0], np.cumsum(sizes)])
    index = []
    for v, p in zip(valid, pixels, strict=True):
        m = np.full(v.shape, -1, dtype=np.int32)
        m.ravel()[p] = np.arange(p.size, dtype=np.int32)
        index.append(m)
    keep_all = np.ones(int(start[-1]), dtype=bool)
    keeps = [keep_all[start[i]:start[i + 1]] for i in range(n)]  # views
    for i in range(n):
        for j in range(n):
            if (i, j) not in corr:
                continue
            m, j_first = corr[i, j], rank[j] < rank[i]
            _ownership_kernel(keeps[i], index[i], scores[i], scores[j], m.parent_rc, m.child_rc,
                              ownership == "priority", j_first)
            if m.rejected is not None and m.rejected.n_pairs:  # by the better view, always
                _ownership_kernel(keeps[i], index[i], scores[i], scores[j],
                                  m.rejected.parent_rc, m.rejected.child_rc, False, j_first)
    clock("ownership")

    steps = np.concatenate([_row_steps(np.ascontiguousarray(s.xyz)) for s in scans])
    spacing = float(np.median(steps)) if steps.size else np.inf
    del steps
    if max_edge_mm is None:
        max_edge_mm = 4.0 * spacing
    if dedupe_mm is None:
        dedupe_mm = 0.5 * spacing
    dedupe = bool(dedupe_mm > 0 and np.isfinite(dedupe_mm))
    radius = 3 * spacing  # of the off-surface test
    surface = surface_mm is not None and n > 1 and bool(np.isfinite(spacing) and radius > 0)
    clock("spacing")

    grid = None
    if dedupe or surface:  # one grid of cells per camera over its valid points
        points = np.concatenate([np.take(np.asarray(s.xyz).reshape(-1, 3), p, axis=0)
                                 for s, p in zip(scans, pixels, strict=True)])
        grid = _grid(points, start, float(radius if surface else dedupe_mm))
    clock("grid")
    # duplicates the correspondence cannot see (edges of valid regions): points closer than
    # dedupe_mm to a point of a camera ranked higher are dropped
    removed = dict.fromkeys((s.name for s in scans), 0)
    if dedupe:
        for k in range(1, n):
            i = priority[k]
            searched = np.zeros(n, dtype=bool)
            searched[priority[:k]] = True
            sorted_keep = np.take(keep_all, grid[2])
            removed[scans[i].name] = int(_dedupe_kernel(
                *grid, searched, sorted_keep, keep_all, points[start[i]:start[i + 1]],
                int(start[i]), float(dedupe_mm)))
    if grid is not None:
        del points
    clock("dedupe")

    fused, counts, rows, cols = [], [], [], []
    for i, s in enumerate(scans):
        r, c = np.divmod(pixels[i], valid[i].shape[1])
        xyz = np.ascontiguousarray(s.xyz)
        w_sum, acc, count = _fusion_init(keeps[i], r, c, xyz, weights[i])
        for j in range(n):
            if (i, j) in corr:
                m = corr[i, j]
                _fusion_add(keeps[i], index[i], w_sum, acc, count, m.parent_rc, m.child_rc,
                            m.xyz_child, weights[j])
        fused.append(_fusion_mean(keeps[i], r, c, xyz, w_sum, acc))
        counts.append(count)
        rows.append(r)
        cols.append(c)
    del weights
    clock("fusion")

    # a lone point (no kept pair) off the surface of the other cameras nearby is dropped when
    # they are confirmed there (a kept pair within surface_mm) or view it better
    off_surface = dict.fromkeys((s.name for s in scans), 0)
    if surface:
        trust = np.concatenate([sc.ravel()[p] for sc, p in zip(scores, pixels, strict=True)])
        for j in range(n):
            for k in range(n):
                if (j, k) in corr:
                    m = corr[j, k]
                    _confirm_kernel(trust[start[j]:start[j + 1]], index[j], m.parent_rc,
                                    m.xyz_parent, m.xyz_child, float(surface_mm))
        for i in range(n):
            lone = np.flatnonzero(keeps[i] & (counts[i] == 1))
            if not lone.size or sizes.sum() == sizes[i]:
                continue
            off = _off_surface_kernel(*grid, trust, i, fused[i][lone],
                                      scores[i].ravel()[pixels[i][lone]], float(radius),
                                      float(surface_mm))
            keeps[i][lone[off]] = False
            off_surface[scans[i].name] = int(np.count_nonzero(off))
        del trust
    del grid, scores
    clock("off_surface")

    # normals from every valid pixel (fused where owned), so ownership edges keep them
    normals = []  # per camera, of its kept pixels in row-major order
    for i, s in enumerate(scans):
        kept = np.flatnonzero(keeps[i])
        center = s.camera_center
        normals.append(_fused_normals(
            np.ascontiguousarray(s.xyz), index[i], keeps[i], fused[i], rows[i][kept],
            cols[i][kept], np.asarray(center if center is not None else (0, 0, 0),
                                      np.float64).reshape(3), center is not None))
    clock("normals")

    # the vertices: kept points finite in float32, camera by camera in row-major order
    vertex, first = [], [0]
    for i in range(n):
        v, count = _vertex_index(keeps[i], fused[i])
        vertex.append(v)
        first.append(first[-1] + count)
    vertices = np.empty((first[-1], 3), dtype=np.float32)
    vertex_normals = np.empty((first[-1], 3), dtype=np.float32)
    colors = np.empty((first[-1], 3), dtype=np.uint8)
    camera = np.empty(first[-1], dtype=np.int16)
    pixel = np.empty((first[-1], 2), dtype=np.int32)
    faces = np.empty((2 * first[-1], 3), dtype=np.int32)  # at most two per vertex
    end = 0
    for i, s in enumerate(scans):
        _vertex_fill(keeps[i], vertex[i], fused[i], rows[i], cols[i], normals[i],
                     np.ascontiguousarray(s.albedo), i, first[i], vertices, vertex_normals,
                     colors, camera, pixel)
        part = slice(first[i], first[i + 1])
        end = _mesh_kernel(index[i], vertex[i], vertices[part], vertex_normals[part],
                           float(max_edge_mm), first[i], faces, end)
    faces = faces[:end]
    clock("mesh")

    fused_scans, fused_normals, n_views = [], [], []
    for i, s in enumerate(scans):
        h, w = valid[i].shape
        xyz = np.empty((h, w, 3), dtype=np.float32)
        nm = np.empty((h, w, 3), dtype=np.float32)
        mask = np.empty((h, w), dtype=bool)
        views = np.empty((h, w), dtype=np.uint8)
        xp, yp = np.asarray(s.xp), np.asarray(s.yp)
        xp_out = np.empty((h, w), dtype=np.result_type(xp.dtype, 0.0))  # np.where(mask, xp, nan)
        yp_out = np.empty((h, w), dtype=np.result_type(yp.dtype, 0.0))
        intensity = np.empty((h, w), dtype=np.float32)
        _fused_images(index[i], keeps[i], fused[i], normals[i], counts[i], xp, yp,
                      np.asarray(s.intensity), xyz, nm, mask, views, xp_out, yp_out, intensity)
        fused_scans.append(Scan(
            name=s.name, xyz=xyz, xp=xp_out, yp=yp_out, albedo=s.albedo, intensity=intensity,
            modulation=s.modulation, mask=mask, camera_center=s.camera_center,
            projector_center=s.projector_center,
        ))
        fused_normals.append(nm)
        n_views.append(views)
    clock("output")
    return SuperScan(
        scans=fused_scans, normals=fused_normals, n_views=n_views, vertices=vertices,
        vertex_normals=vertex_normals, colors=colors, faces=faces, camera=camera, pixel=pixel,
        correspondences=corr, valid_masks=valid, priority=priority, duplicates_removed=removed,
        points_rejected={s.name: {"spike": spikes_removed[s.name],
                                  "off_surface": off_surface[s.name]} for s in scans},
        timings=clock.seconds,
    )


def super_mat5_scan(superscan: SuperScan, *, gap_px: int = 1, name: str = "super") -> Scan:
    """The super mat5 grid: every camera's fused grid side by side (see the module docstring).

    Parameters
    ----------
    superscan : SuperScan
    gap_px : int
        Invalid columns between two cameras' blocks.
    name : str

    Returns
    -------
    Scan
        Shape ``(max H, ΣW + gap_px × (n − 1))``; ``camera_center`` is None.
    """
    gap_px = as_int(gap_px, "gap_px", minimum=0)
    scans = superscan.scans
    height = max(s.shape[0] for s in scans)
    width = sum(s.shape[1] for s in scans) + gap_px * (len(scans) - 1)
    # every element written once: the blocks copied, the rest filled (NaN; 0 for the images)
    fill = {"xyz": np.nan, "xp": np.nan, "yp": np.nan, "albedo": 0, "intensity": 0,
            "modulation": 0}
    grids = {k: np.empty((height, width, 3) if k == "xyz" else (height, width), np.float32)
             for k in fill}
    mask = np.zeros((height, width), dtype=bool)
    col = 0
    for s in scans:
        h, w = s.shape
        mask[:h, col:col + w] = s.mask
        for k, grid in grids.items():
            grid[:h, col:col + w] = getattr(s, k)
            grid[h:, col:col + w] = fill[k]  # below a shorter camera
            grid[:, col + w:col + w + gap_px] = fill[k]  # the gap after it
        col += w + gap_px
    xyz = grids.pop("xyz")
    return Scan(name=name, xyz=xyz, mask=mask, camera_center=None, **grids)


def write_super_mat5(
    prefix: str | os.PathLike, superscan: SuperScan, *, gap_px: int = 1
) -> list[Path]:
    """Write the super mat5 (:func:`super_mat5_scan`) with :func:`nail2nail.io.mat5.write_mat5`.

    Returns
    -------
    list of Path
        The seven files of the set.
    """

    return write_mat5(prefix, super_mat5_scan(superscan, gap_px=gap_px))


def write_super_ply(path: str | os.PathLike, superscan: SuperScan, *, faces=None) -> Path:
    """Write the super scan as binary PLY: vertices, normals, grey colours, triangles.

    `faces` replaces the super scan's own triangles (the cameras' grids): the seamless mesh of
    :func:`nail2nail.merge.mesh.seamless_mesh`, say.

    Returns
    -------
    Path
        `path`.
    """

    names = ", ".join(s.name for s in superscan.scans)
    seamless = faces is not None
    return write_ply(path, superscan.vertices, colors=superscan.colors,
                     normals=superscan.vertex_normals,
                     faces=superscan.faces if faces is None else faces,
                     comments=[f"nail2nail super scan fused from {names}"
                               + ("; one seamless mesh" if seamless else "")])
