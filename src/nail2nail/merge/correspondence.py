"""Correspondence between cameras in projector space, and the merge error (thesis chapter four).

All cameras of the scanner look at one projector, so a surface point seen by two cameras has the
same projector coordinates ``(xp, yp)`` in both scans. For every (sampled) pixel of a *parent*
scan, :func:`correspond` finds the *child* pixel with the nearest ``(xp, yp)`` (a bucket grid over
the child's valid pixels in projector space, :func:`nearest_grid`, instead of the appendix's
``closest_proj_point`` loop over the whole child frame), refines it to the sub-pixel position
where the child's interpolated projector coordinates equal the parent's, and interpolates the
child's world point there. The world distance between
the two points of a pair is the merge error (thesis "Merging in Projector Space", Fig. 32–35).

A nearest neighbour always exists, even where the child never saw the point, so the overlap is
decided, not assumed: a pair is dropped when the parent pixel lies at the border of the parent's
valid region, when the child position lies at the border of the child's valid region, or when
the projector-coordinate residual after refinement exceeds the decoding noise. The counts per
reason are kept in :attr:`Correspondence.dropped`.

A pair that is found may still be wrong: at a grazing view or a shadow border a camera's projector
coordinates are biased (blur spreads a pixel over much surface, and the fringe signal is weak),
which shifts its point along the surface. Such pairs are *rejected* (kept apart in
:attr:`Correspondence.rejected`, with the reason): either camera views the point beyond
`max_view_angle_deg`, the projector's light meets the surface beyond `max_incidence_deg` from its
normal (it stretches the fringes over the surface, and a phase error with them), either camera's
fringe modulation there is below a fraction of its median, or the pair's distance is an outlier
among the pairs around it (above their median by more than ``max(outlier_mm, outlier_mad × MAD)``).
The statistics report the merge error of the kept pairs and of all pairs before rejection.

:func:`nearest_bruteforce` is the appendix's search (vectorised over the child for each parent
pixel), kept as the reference the grid and k-d tree searches are tested against. What
:func:`correspond` derives from a scan (masks, view and incidence cosines, modulation, search grid)
can be kept across calls in a :class:`CorrespondenceCache`: matching one scan several times, pass
one.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np
import scipy.ndimage
import scipy.spatial

from nail2nail._interpolate import bilinear, bilinear_gradient, bilinear_value
from nail2nail._numba_cache import cache_enabled
from nail2nail._validation import as_int
from nail2nail.merge.statistics import _middle, local_outliers, merge_statistics
from nail2nail.scan.results import Scan

__all__ = [
    "DROP_REASONS",
    "PAIR_BY",
    "REJECT_REASONS",
    "Correspondence",
    "CorrespondenceCache",
    "check_pair_by",
    "correspond",
    "grid_normals",
    "incidence_cosine",
    "nearest_bruteforce",
    "nearest_grid",
    "nearest_kdtree",
    "pairing_coordinates",
    "refine_subpixel",
    "sample_pixels",
    "valid_mask",
    "view_cosine",
]

#: Reasons a pair found in projector space is rejected as unreliable, in the order tested
#: (:func:`correspond`): a grazing view, grazing projector light, a weak fringe signal, a
#: distance far above its neighbours'. Rejected pairs are kept apart in
#: :attr:`Correspondence.rejected`.
REJECT_REASONS = ("view_angle", "incidence", "modulation", "outlier")
#: Reasons a sampled parent pixel gets no (kept) correspondence, in the order they are tested.
DROP_REASONS = ("parent_border", "child_border", "residual", *REJECT_REASONS)

_MAX_SHIFT_PX = 1.5  # a refined position further than this from the nearest pixel is not trusted
_ALONG = {"xpyp": 0, "xp": 1, "yp": 2}  # pair_by → the pairs kernel's `along`
#: What :func:`correspond`'s `pair_by` takes: ``"auto"`` or the coordinates that pair
PAIR_BY = ("auto", *_ALONG)
_SLIDE_STEPS = 3  # iterations of the slide along one coordinate's curve (pair_by "xp", "yp")
_NEWTON_STEPS = 2  # Newton steps on the bilinear model after the affine step


# -- input checks ----------------------------------------------------------------------------
def _check_angles(max_view_angle_deg, max_incidence_deg) -> None:
    for value, label in ((max_view_angle_deg, "max_view_angle_deg"),
                         (max_incidence_deg, "max_incidence_deg")):
        if value is not None and not 0 < value <= 90:
            raise ValueError(f"{label}: expected a number in (0, 90] or None, got {value}")


def _check_scan(scan, name: str) -> Scan:
    if not isinstance(scan, Scan):
        raise TypeError(
            f"{name}: expected a nail2nail.scan.results.Scan, got {type(scan).__name__}"
        )
    mask = np.asarray(scan.mask)
    if mask.ndim != 2 or mask.dtype != bool:
        raise ValueError(
            f"{name}.mask: expected a (H, W) bool array, got {mask.dtype} {mask.shape}"
        )
    shape = mask.shape
    if np.shape(scan.xyz) != (*shape, 3):
        raise ValueError(f"{name}.xyz: expected shape {(*shape, 3)}, got {np.shape(scan.xyz)}")
    for attr in ("xp", "yp", "modulation"):
        if np.shape(getattr(scan, attr)) != shape:
            raise ValueError(
                f"{name}.{attr}: expected shape {shape}, got {np.shape(getattr(scan, attr))}"
            )
    if min(shape) < 3:
        raise ValueError(f"{name}: image {shape} is too small (need at least 3 × 3 pixels)")
    return scan


def valid_mask(scan: Scan) -> np.ndarray:
    """Pixels usable for merging: ``scan.mask`` and finite ``xyz``, ``xp``, ``yp``.

    Returns
    -------
    (H, W) bool
    """
    mask = np.ascontiguousarray(scan.mask, dtype=bool)
    xyz, xp, yp = _float_image(scan.xyz), _float_image(scan.xp), _float_image(scan.yp)
    if xyz.shape != (*mask.shape, 3) or xp.shape != mask.shape or yp.shape != mask.shape:
        return mask & np.isfinite(xyz).all(axis=-1) & np.isfinite(xp) & np.isfinite(yp)
    return _valid_kernel(mask, xyz, xp, yp)


@numba.njit(cache=cache_enabled(), nogil=True)
def _valid_kernel(mask, xyz, xp, yp):
    """:func:`valid_mask` in one pass."""
    h, w = mask.shape
    out = np.zeros((h, w), dtype=np.bool_)
    for r in range(h):
        for c in range(w):
            out[r, c] = (mask[r, c] and np.isfinite(xp[r, c]) and np.isfinite(yp[r, c])
                         and np.isfinite(xyz[r, c, 0]) and np.isfinite(xyz[r, c, 1])
                         and np.isfinite(xyz[r, c, 2]))
    return out


def _without_jumps(scan: Scan, valid: np.ndarray, max_jump_px: float) -> np.ndarray:
    """`valid` less the pixels where ``xp`` or ``yp`` jumps.

    A jump in projector coordinates between neighbouring camera pixels is a depth discontinuity
    (or a decoding error): interpolating across it would invent surface, so such pixels are
    treated as the edge of the valid region. A pixel jumps along a row or column when the second
    difference ``|Δ²f|`` exceeds both `max_jump_px` and the mean of the two one-sided
    differences ``(|Δ⁺f| + |Δ⁻f|) / 2`` (a step more than twice the local slope; a steep but
    smooth map, as at grazing views, does not jump).
    """
    out = valid.copy()
    box = _valid_box(valid, 1)  # the rest of the image holds no valid pixel to test
    if box is None:
        return out
    inside = out[box]
    for f in (scan.xp, scan.yp):
        f = np.asarray(f)[box].astype(np.float32)
        for axis in (0, 1):
            forward = np.diff(f, axis=axis)
            lo = [slice(None)] * 2
            hi = [slice(None)] * 2
            lo[axis], hi[axis] = slice(0, -1), slice(1, None)
            d_minus, d_plus = forward[tuple(lo)], forward[tuple(hi)]
            second = np.abs(d_plus - d_minus)
            with np.errstate(invalid="ignore"):
                jump = (second > max_jump_px) & (second > 0.5 * (np.abs(d_plus) + np.abs(d_minus)))
            inner = [slice(None)] * 2
            inner[axis] = slice(1, -1)
            inside[tuple(inner)] &= ~jump
    return out


def _valid_box(valid: np.ndarray, margin: int) -> tuple[slice, slice] | None:
    """Rows and columns of the bounding box of `valid`, widened by `margin` px within the
    image; None without a valid pixel."""
    rows, cols = np.flatnonzero(valid.any(axis=1)), np.flatnonzero(valid.any(axis=0))
    if rows.size == 0:
        return None
    h, w = valid.shape
    return (slice(max(rows[0] - margin, 0), min(rows[-1] + margin + 1, h)),
            slice(max(cols[0] - margin, 0), min(cols[-1] + margin + 1, w)))


def _eroded(mask: np.ndarray, border_px: int) -> np.ndarray:
    """`mask` eroded `border_px` times by the 3 × 3 square, outside the image false
    (scipy.ndimage.binary_erosion): the pixels whose (2 `border_px` + 1)² square is in it."""
    if border_px == 0:
        return mask
    return _erosion_kernel(np.ascontiguousarray(mask, dtype=bool), int(border_px))


@numba.njit(cache=cache_enabled(), nogil=True)
def _erosion_kernel(mask, radius):
    """Pixels whose square of half-size `radius` lies in `mask` (and in the image): runs of
    true pixels along rows, then along columns."""
    h, w = mask.shape
    rowwise = np.zeros((h, w), dtype=np.bool_)
    for r in range(h):
        run = 0  # true pixels ending at c
        for c in range(w):
            run = run + 1 if mask[r, c] else 0
            if run >= 2 * radius + 1:
                rowwise[r, c - radius] = True
    out = np.zeros((h, w), dtype=np.bool_)
    run_col = np.zeros(w, dtype=np.int64)
    for r in range(h):
        for c in range(w):
            run_col[c] = run_col[c] + 1 if rowwise[r, c] else 0
            if run_col[c] >= 2 * radius + 1:
                out[r - radius, c] = True
    return out


def sample_pixels(mask, *, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of the valid pixels on the every-`stride`-th grid (thesis: 5 and 20).

    Parameters
    ----------
    mask : (H, W) bool
    stride : int
        Sampling step along rows and columns, from pixel ``(0, 0)``.

    Returns
    -------
    rows, cols : (N,) intp
        In row-major order.

    Examples
    --------
    >>> rows, cols = sample_pixels(np.ones((4, 5), bool), stride=2)
    >>> rows.tolist(), cols.tolist()
    ([0, 0, 0, 2, 2, 2], [0, 2, 4, 0, 2, 4])
    """
    stride = as_int(stride, "stride", minimum=1)
    mask = np.asarray(mask, dtype=bool)
    grid = np.zeros_like(mask)
    grid[::stride, ::stride] = True
    rows, cols = np.nonzero(mask & grid)
    return rows, cols


def grid_normals(xyz, *, camera_center=None) -> np.ndarray:
    """Unit normals of a gridded surface from neighbour differences.

    ``n = (∂X/∂row) × (∂X/∂col)``, with central differences where both neighbours are valid and
    one-sided ones at the edge of the valid region; the normal points towards the camera (towards
    `camera_center` if given, else by the handedness of the camera frame: x right, y down).
    One compiled pass over the image, in float64 (the arithmetic of the NumPy formulation).

    Parameters
    ----------
    xyz : (H, W, 3) float
        World points, mm; NaN invalid.
    camera_center : (3,) float, optional
        Camera centre, world mm.

    Returns
    -------
    (H, W, 3) float32
        Unit normals; NaN where a pixel has no valid neighbour along a direction.

    Raises
    ------
    ValueError
        If `xyz` is not ``(H, W, 3)``.

    Examples
    --------
    >>> rr, cc = np.mgrid[0:3, 0:4].astype(float)
    >>> n = grid_normals(np.stack([cc, -rr, 0 * cc], -1))
    >>> np.abs(n[1, 1]).tolist()
    [0.0, 0.0, 1.0]
    """
    xyz = _float_image(xyz)
    if xyz.ndim != 3 or xyz.shape[2] != 3:
        raise ValueError(f"xyz: expected shape (H, W, 3), got {xyz.shape}")
    if camera_center is None:
        return _normals_kernel(xyz, np.zeros(3), False)
    center = np.asarray(camera_center, dtype=np.float64).reshape(3)
    return _normals_kernel(xyz, center, True)


def _float_image(a) -> np.ndarray:
    """`a` as a C-contiguous float32 or float64 array (other types as float64), for the kernels."""
    a = np.asarray(a)
    if a.dtype not in (np.float32, np.float64):
        a = a.astype(np.float64)
    return np.ascontiguousarray(a)


@numba.njit(cache=cache_enabled(), nogil=True, error_model="numpy")
def _one_sided(xyz, r, c, k, dr, dc, i, n):
    """``∂X_k`` at ``(r, c)`` along ``(dr, dc)`` where the central difference is NaN: forward,
    else backward (`i`: the pixel's index along the direction, `n`: the image's extent)."""
    d = np.nan
    if i < n - 1:
        d = np.float64(xyz[r + dr, c + dc, k]) - np.float64(xyz[r, c, k])
    if np.isnan(d) and i > 0:
        d = np.float64(xyz[r, c, k]) - np.float64(xyz[r - dr, c - dc, k])
    return d


@numba.njit(cache=cache_enabled(), nogil=True, error_model="numpy")
def _normals_kernel(xyz, center, toward_center):
    """:func:`grid_normals` per pixel: the same float64 operations in the same order."""
    h, w = xyz.shape[0], xyz.shape[1]
    out = np.empty((h, w, 3), dtype=np.float32)
    nan = np.nan
    for r in range(h):
        for c in range(w):
            a0 = a1 = a2 = b0 = b1 = b2 = nan
            if 0 < r < h - 1:  # central differences, the common case
                a0 = 0.5 * (np.float64(xyz[r + 1, c, 0]) - np.float64(xyz[r - 1, c, 0]))
                a1 = 0.5 * (np.float64(xyz[r + 1, c, 1]) - np.float64(xyz[r - 1, c, 1]))
                a2 = 0.5 * (np.float64(xyz[r + 1, c, 2]) - np.float64(xyz[r - 1, c, 2]))
            if 0 < c < w - 1:
                b0 = 0.5 * (np.float64(xyz[r, c + 1, 0]) - np.float64(xyz[r, c - 1, 0]))
                b1 = 0.5 * (np.float64(xyz[r, c + 1, 1]) - np.float64(xyz[r, c - 1, 1]))
                b2 = 0.5 * (np.float64(xyz[r, c + 1, 2]) - np.float64(xyz[r, c - 1, 2]))
            # one-sided differences where a central one is missing (per component, as NumPy);
            # both need the pixel itself
            x0 = np.float64(xyz[r, c, 0])
            x1 = np.float64(xyz[r, c, 1])
            x2 = np.float64(xyz[r, c, 2])
            if np.isnan(a0) and not np.isnan(x0):
                a0 = _one_sided(xyz, r, c, 0, 1, 0, r, h)
            if np.isnan(a1) and not np.isnan(x1):
                a1 = _one_sided(xyz, r, c, 1, 1, 0, r, h)
            if np.isnan(a2) and not np.isnan(x2):
                a2 = _one_sided(xyz, r, c, 2, 1, 0, r, h)
            if np.isnan(b0) and not np.isnan(x0):
                b0 = _one_sided(xyz, r, c, 0, 0, 1, c, w)
            if np.isnan(b1) and not np.isnan(x1):
                b1 = _one_sided(xyz, r, c, 1, 0, 1, c, w)
            if np.isnan(b2) and not np.isnan(x2):
                b2 = _one_sided(xyz, r, c, 2, 0, 1, c, w)
            n0 = a1 * b2 - a2 * b1
            n1 = a2 * b0 - a0 * b2
            n2 = a0 * b1 - a1 * b0
            # NumPy's orders of summation: norm (x0 + x1) + x2, einsum (x0 + x2) + x1
            norm = np.sqrt((n0 * n0 + n1 * n1) + n2 * n2)
            n0, n1, n2 = n0 / norm, n1 / norm, n2 / norm
            if toward_center:
                v0 = center[0] - x0
                v1 = center[1] - x1
                v2 = center[2] - x2
                if (n0 * v0 + n2 * v2) + n1 * v1 < 0:
                    n0, n1, n2 = -n0, -n1, -n2
            out[r, c, 0] = n0
            out[r, c, 1] = n1
            out[r, c, 2] = n2
    return out


def view_cosine(scan: Scan, *, normals=None, smooth_px: float = 0.0) -> np.ndarray:
    """Cosine of the viewing angle of each pixel: its normal against the ray to the camera.

    Parameters
    ----------
    scan : Scan
        Needs ``camera_center``.
    normals : (H, W, 3) float, optional
        Surface normals (:func:`grid_normals` if omitted).
    smooth_px : float
        Gaussian smoothing (σ, px) of the cosine over the valid pixels (the surface's ridges
        tilt the per-pixel normal; the view of the finger's shape is what limits decoding); 0
        for none.

    Returns
    -------
    (H, W) float64
        In ``[0, 1]``; 0 on invalid pixels and where the normal is undefined.

    Raises
    ------
    ValueError
        If `scan` has no ``camera_center``, or `normals` is not ``(H, W, 3)``.
    """
    _check_scan(scan, "scan")
    if scan.camera_center is None:
        raise ValueError(f"scan {scan.name!r}: camera_center is needed for the viewing angle")
    return _view_cosine(scan, valid_mask(scan), normals=normals, smooth_px=smooth_px)


def incidence_cosine(scan: Scan, *, normals=None, smooth_px: float = 0.0) -> np.ndarray:
    """Cosine of the angle of incidence of the projector's light at each pixel: its normal
    against the ray to the projector.

    Grazing light stretches the fringes over the surface by 1 / cos: a phase error of the
    same size on the panel moves the point farther along the surface, and the points of two
    cameras paired through the projector's coordinates lie farther apart (the merge's tail on
    the far sides of a finger lit from one side).

    Parameters
    ----------
    scan : Scan
        Needs ``projector_center``.
    normals : (H, W, 3) float, optional
        Surface normals (:func:`grid_normals` if omitted).
    smooth_px : float
        Gaussian smoothing (σ, px) over the valid pixels, as :func:`view_cosine`'s.

    Returns
    -------
    (H, W) float64
        In ``[0, 1]``; 0 on invalid pixels and where the normal is undefined.

    Raises
    ------
    ValueError
        If `scan` has no ``projector_center``, or `normals` is not ``(H, W, 3)``.
    """
    _check_scan(scan, "scan")
    if scan.projector_center is None:
        raise ValueError(f"scan {scan.name!r}: projector_center is needed for the angle of "
                         "incidence")
    return _view_cosine(scan, valid_mask(scan), normals=normals, smooth_px=smooth_px,
                        center=scan.projector_center)


def _view_cosine(scan: Scan, valid: np.ndarray, *, normals=None, smooth_px: float = 0.0,
                 center=None):
    """:func:`view_cosine` of a checked scan with a camera centre, its valid mask given; with
    `center`, the cosine of the ray to that point instead (:func:`incidence_cosine`). The
    normals, computed here when not given, face the camera (the projector without one: a lit
    point faces both)."""
    center = np.asarray(scan.camera_center if center is None else center,
                        dtype=np.float64).reshape(3)
    orient = (center if scan.camera_center is None
              else np.asarray(scan.camera_center, dtype=np.float64).reshape(3))
    xyz = _float_image(scan.xyz)
    if normals is None:
        # normals on the valid pixels' box widened by one pixel: a valid pixel's normal reads
        # its neighbours only, and the box ends where the image does (the same differences)
        cos = np.zeros(valid.shape)
        box = _valid_box(valid, 1)
        if box is not None:
            inside = np.ascontiguousarray(xyz[box])
            cos[box] = _cosine_kernel(_normals_kernel(inside, orient, True), inside, center,
                                      np.ascontiguousarray(valid[box]))
    else:
        normals = _float_image(normals)
        if normals.shape != xyz.shape:
            raise ValueError(f"normals: expected shape {xyz.shape}, got {normals.shape}")
        cos = _cosine_kernel(normals, xyz, center, valid)
    # smoothed over the valid pixels' box widened by the Gaussian's radius (scipy's truncate
    # 4 σ): beyond it both images are 0, so the box gives the whole image's values
    box = _valid_box(valid, int(4.0 * float(smooth_px) + 0.5)) if smooth_px > 0 else None
    if box is not None:
        inside = valid[box]
        norm = scipy.ndimage.gaussian_filter(inside.astype(np.float64), smooth_px)
        with np.errstate(invalid="ignore", divide="ignore"):
            smooth = np.nan_to_num(scipy.ndimage.gaussian_filter(cos[box], smooth_px) / norm)
        smooth[~inside] = 0.0
        cos[box] = smooth
    return cos


@numba.njit(cache=cache_enabled(), nogil=True, error_model="numpy")
def _cosine_kernel(normals, xyz, center, valid):
    """:func:`view_cosine` before smoothing: ``clip(n · (C − X) / |C − X|, 0, 1)`` in float64,
    NaN as 0 and 0 on invalid pixels."""
    h, w = valid.shape
    out = np.zeros((h, w), dtype=np.float64)
    for r in range(h):
        for c in range(w):
            if not valid[r, c]:
                continue
            v0 = center[0] - np.float64(xyz[r, c, 0])
            v1 = center[1] - np.float64(xyz[r, c, 1])
            v2 = center[2] - np.float64(xyz[r, c, 2])
            norm = np.sqrt((v0 * v0 + v1 * v1) + v2 * v2)  # NumPy's orders, as above
            v0, v1, v2 = v0 / norm, v1 / norm, v2 / norm
            cos = (np.float64(normals[r, c, 0]) * v0 + np.float64(normals[r, c, 2]) * v2) \
                + np.float64(normals[r, c, 1]) * v1
            if np.isnan(cos):
                cos = 0.0
            out[r, c] = min(max(cos, 0.0), 1.0)
    return out


# -- nearest neighbour in projector space ----------------------------------------------------
def _match_inputs(parent: Scan, child: Scan, rows, cols):
    """Checked parent pixels ``rows, cols`` (intp) and the valid child pixels ``cr, cc``."""
    _check_scan(parent, "parent")
    _check_scan(child, "child")
    rows, cols = np.asarray(rows, dtype=np.intp), np.asarray(cols, dtype=np.intp)
    cr, cc = np.nonzero(valid_mask(child))
    if cr.size == 0:
        raise ValueError("child: no valid pixels")
    return rows, cols, cr, cc


def nearest_bruteforce(
    parent: Scan, child: Scan, rows, cols
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest child pixel in projector space by exhaustive search (``closest_proj_point``).

    For each parent pixel, the squared projector distance
    ``(xp - xp2)² + (yp - yp2)²`` to every valid child pixel, and its minimum (first in row-major
    order on ties, as the appendix loop). A reference for :func:`nearest_kdtree`: its cost grows
    with the product of the two pixel counts.

    Parameters
    ----------
    parent, child : Scan
    rows, cols : (N,) int
        Parent pixels to match.

    Returns
    -------
    child_rows, child_cols : (N,) intp
    distance2_px2 : (N,) float64
        Squared projector distance, panel px².
    """
    rows, cols, cr, cc = _match_inputs(parent, child, rows, cols)
    xp2 = np.asarray(child.xp, dtype=np.float64)[cr, cc]
    yp2 = np.asarray(child.yp, dtype=np.float64)[cr, cc]
    xp1 = np.asarray(parent.xp, dtype=np.float64)[rows, cols]
    yp1 = np.asarray(parent.yp, dtype=np.float64)[rows, cols]
    best = np.empty(rows.size, dtype=np.intp)
    dist2 = np.empty(rows.size, dtype=np.float64)
    for i in range(rows.size):  # one parent pixel at a time, as the appendix
        d = (xp1[i] - xp2) ** 2 + (yp1[i] - yp2) ** 2
        best[i] = np.argmin(d)
        dist2[i] = d[best[i]]
    return cr[best], cc[best], dist2


def nearest_kdtree(
    parent: Scan, child: Scan, rows, cols, *, workers: int = -1
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest child pixel in projector space with a k-d tree (same output as the brute force).

    Parameters
    ----------
    parent, child : Scan
    rows, cols : (N,) int
        Parent pixels to match.
    workers : int
        Threads for the query (``-1``: all cores).

    Returns
    -------
    child_rows, child_cols : (N,) intp
    distance2_px2 : (N,) float64
        Squared projector distance, panel px².
    """
    rows, cols, cr, cc = _match_inputs(parent, child, rows, cols)
    child_xy = np.stack([child.xp[cr, cc], child.yp[cr, cc]], axis=-1).astype(np.float64)
    tree = scipy.spatial.cKDTree(child_xy, leafsize=16, balanced_tree=False, compact_nodes=False)
    query = np.stack([parent.xp[rows, cols], parent.yp[rows, cols]], axis=-1).astype(np.float64)
    dist, index = tree.query(query, k=1, workers=workers)
    return cr[index], cc[index], dist**2


def nearest_grid(
    parent: Scan, child: Scan, rows, cols, *, cache: CorrespondenceCache | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest child pixel in projector space with a bucket grid (the brute force's output).

    The child's valid pixels are sorted into square cells of about two pixels in projector
    space; each parent pixel searches the cells around its own, ring by ring, until no cell
    left can hold a nearer pixel (a parent pixel the child never saw falls back to a k-d tree of
    the pixels at the edge of the child's coverage). Exact: the same pixels and distances as
    :func:`nearest_bruteforce`, ties to the first child pixel in row-major order.

    Parameters
    ----------
    parent, child : Scan
    rows, cols : (N,) int
        Parent pixels to match.
    cache : CorrespondenceCache, optional
        Keeps the child's grid for the next search in the same child.

    Returns
    -------
    child_rows, child_cols : (N,) intp
    distance2_px2 : (N,) float64
        Squared projector distance, panel px².

    Raises
    ------
    ValueError
        If the child has no valid pixels.
    """
    rows, cols = _match_pixels(parent, child, rows, cols)
    grid = (cache if cache is not None else CorrespondenceCache())._entry(child).grid
    index, dist2 = grid.nearest(np.asarray(parent.xp)[rows, cols].astype(np.float64),
                                np.asarray(parent.yp)[rows, cols].astype(np.float64))
    return grid.rows[index], grid.cols[index], dist2


def _match_pixels(parent: Scan, child: Scan, rows, cols) -> tuple[np.ndarray, np.ndarray]:
    """Checked scans; the parent pixels ``rows, cols`` as intp."""
    _check_scan(parent, "parent")
    _check_scan(child, "child")
    return np.asarray(rows, dtype=np.intp), np.asarray(cols, dtype=np.intp)


class CorrespondenceCache:
    """What :func:`correspond` derives from a scan, kept for the next call with the same scan.

    Matching one scan several times (the merge report's camera pairs; fusion's every ordered
    pair) then computes its valid mask, its inner region (jumps and border removed), its
    smoothed view cosine and relative modulation, the rows and columns of its inner pixels,
    and the bucket grid of its projector coordinates (:func:`nearest_grid`) once. Scans are
    recognised by identity, and the cache holds them: do not change a cached scan's arrays in
    place (:func:`dataclasses.replace` makes a new scan). About 45 bytes per pixel of each
    scan (60 MB for a 1280 × 1024 camera seeing the finger).

    Examples
    --------
    >>> rr, cc = np.mgrid[0:20, 0:20].astype(np.float32)
    >>> one = np.ones((20, 20), np.float32)
    >>> a = Scan("a", np.stack([cc, rr, 0 * rr], -1), cc, rr, one, one, one, one > 0)
    >>> cache = CorrespondenceCache()
    >>> m = correspond(a, a, stride=4, cache=cache)
    >>> n = correspond(a, a, stride=2, cache=cache)  # a's images and grid reused
    >>> len(cache), m.n_pairs, n.n_pairs
    (1, 16, 64)
    """

    def __init__(self) -> None:
        self._entries: dict[int, _ScanImages] = {}

    def __len__(self) -> int:
        return len(self._entries)

    def clear(self) -> None:
        """Forget every scan."""
        self._entries.clear()

    def valid_mask(self, scan: Scan) -> np.ndarray:
        """(H, W) bool :func:`valid_mask` of `scan`, computed once (do not modify it)."""
        return self._entry(scan).valid

    def _entry(self, scan: Scan) -> _ScanImages:
        entry = self._entries.get(id(scan))
        if entry is None or entry.scan is not scan:
            entry = self._entries[id(scan)] = _ScanImages(scan)
        return entry


class _ScanImages:
    """One scan's images for :func:`correspond`, each computed when first asked for."""

    def __init__(self, scan: Scan):
        self.scan = scan
        self.valid = valid_mask(scan)
        self._inner: dict[tuple[float, int], np.ndarray] = {}
        self._pixels: dict[tuple[float, int, int], tuple[int, np.ndarray, np.ndarray]] = {}
        self._grid: _ProjectorGrid | None = None
        self._cosine: np.ndarray | None = None
        self._incidence: np.ndarray | None = None
        self._modulation: np.ndarray | None = None

    def inner(self, max_jump_px: float, border_px: int) -> np.ndarray:
        """(H, W) bool valid pixels without jumps, eroded by `border_px`."""
        key = (float(max_jump_px), int(border_px))
        if key not in self._inner:
            self._inner[key] = _eroded(_without_jumps(self.scan, self.valid, max_jump_px),
                                       border_px)
        return self._inner[key]

    def inner_pixels(self, max_jump_px: float, border_px: int, stride: int):
        """``(n_sampled, rows, cols)``: the count of valid pixels on the `stride` grid
        (:func:`sample_pixels`) and the rows and columns (intp, row-major) of those among them
        in :meth:`inner`."""
        key = (float(max_jump_px), int(border_px), int(stride))
        if key not in self._pixels:
            inner = self.inner(max_jump_px, border_px)
            if stride == 1:
                n_sampled = int(np.count_nonzero(self.valid))
            else:
                n_sampled = int(np.count_nonzero(self.valid[::stride, ::stride]))
                grid = np.zeros_like(inner)
                grid[::stride, ::stride] = True
                inner = inner & grid
            inner_rows, inner_cols = np.nonzero(inner)
            self._pixels[key] = (n_sampled, inner_rows, inner_cols)
        return self._pixels[key]

    @property
    def grid(self) -> _ProjectorGrid:
        if self._grid is None:
            self._grid = _ProjectorGrid(self.scan, self.valid)
        return self._grid

    def cosine(self) -> np.ndarray:
        """(H, W) float64 :func:`view_cosine` smoothed over 2 px."""
        if self._cosine is None:
            _check_scan(self.scan, "scan")
            if self.scan.camera_center is None:
                raise ValueError(f"scan {self.scan.name!r}: camera_center is needed for the "
                                 "viewing angle")
            self._cosine = _view_cosine(self.scan, self.valid, smooth_px=2.0)
        return self._cosine

    def incidence(self) -> np.ndarray:
        """(H, W) float64 :func:`incidence_cosine` smoothed over 2 px."""
        if self._incidence is None:
            _check_scan(self.scan, "scan")
            if self.scan.projector_center is None:
                raise ValueError(f"scan {self.scan.name!r}: projector_center is needed for "
                                 "the angle of incidence")
            self._incidence = _view_cosine(self.scan, self.valid, smooth_px=2.0,
                                           center=self.scan.projector_center)
        return self._incidence

    def modulation(self) -> np.ndarray:
        """(H, W) float64 relative modulation (:func:`_relative_modulation`)."""
        if self._modulation is None:
            self._modulation = _relative_modulation(self.scan, self.valid)
        return self._modulation


_GRID_RINGS = 3  # rings of cells searched around a query before the boundary fallback (≥ 3)


class _ProjectorGrid:
    """A bucket grid over a child scan's valid pixels in projector space: exact nearest search.

    The valid pixels' ``(xp, yp)`` are sorted into square cells of about two pixels each. A
    query searches the cells around its own ring by ring (:func:`_grid_nearest`) until the best
    distance is below the distance to any cell not yet searched, at most `_GRID_RINGS` rings.
    A query still undecided then (a parent pixel the child never saw, farther than that ring
    from every child pixel) has its nearest child pixel at the edge of an empty region of the
    grid: those pixels (cells with an empty cell within ``⌈_GRID_RINGS / 2⌉`` cells, see
    :meth:`_boundary_tree`) are searched with a k-d tree. Ties go to the first child pixel in
    row-major order, as in :func:`nearest_bruteforce` (in the grid; the k-d tree's tie is its
    own, but ties between float coordinates do not occur in measured data).
    """

    def __init__(self, scan: Scan, valid: np.ndarray):
        valid = np.ascontiguousarray(valid, dtype=bool)
        self.rows, self.cols, x, y, box = _gather_valid(valid, _float_image(scan.xp),
                                                        _float_image(scan.yp))
        if self.rows.size == 0:
            raise ValueError(f"child {scan.name!r}: no valid pixels")
        self.x, self.y = x, y
        self.x0, self.y0 = float(box[0]), float(box[1])
        span_x, span_y = float(box[2]) - self.x0, float(box[3]) - self.y0
        n = x.size
        cell = _pixel_spacing(scan, valid) * np.sqrt(2.0)  # about two pixels per cell
        # at most 1.5 m + 1 cells (m = 4 n + 1024), whatever the spread of the coordinates:
        # (sx / c + 1)(sy / c + 1) with sx sy / c² ≤ m / 2 and (sx + sy) / c ≤ m
        m = 4.0 * n + 1024.0
        cell = max(cell, np.sqrt(2.0 * span_x * span_y / m), 2.0 * span_x / m,
                   2.0 * span_y / m, 1e-6)
        self.cell = float(cell)
        self.nx = int(span_x / cell) + 1
        self.ny = int(span_y / cell) + 1
        self.start, self.sindex, self.sx, self.sy, self.cell_of = _grid_build(
            x, y, self.x0, self.y0, self.cell, self.nx, self.ny)
        self._tree = None
        self._empty: np.ndarray | None = None

    @property
    def empty(self) -> np.ndarray:
        """(ny, nx) int8 Chebyshev distance of each cell to an occupied cell, in cells, at most
        ``_GRID_RINGS + 1`` (0: occupied)."""
        if self._empty is None:
            occupied = (np.diff(self.start) > 0).reshape(self.ny, self.nx)
            distance = scipy.ndimage.distance_transform_cdt(~occupied, metric="chessboard")
            self._empty = np.minimum(distance, _GRID_RINGS + 1).astype(np.int8)
        return self._empty

    def nearest(self, qx, qy, *, workers: int = -1) -> tuple[np.ndarray, np.ndarray]:
        """Index (into the valid pixels, row-major) and squared distance of each query's nearest.

        Parameters
        ----------
        qx, qy : (N,) float64
            Projector coordinates, finite.
        workers : int
            Threads (``-1``: all cores).
        """
        qx = np.ascontiguousarray(qx, dtype=np.float64)
        qy = np.ascontiguousarray(qy, dtype=np.float64)
        best, d2, done = _in_threads(
            lambda a, b: _grid_nearest(qx[a:b], qy[a:b], self.sx, self.sy, self.sindex,
                                       self.start, self.x0, self.y0, self.cell, self.nx,
                                       self.ny, _GRID_RINGS), qx.size, workers)
        todo = np.flatnonzero(~done)
        return self._settle(best, d2, todo, qx[todo], qy[todo], workers)

    def nearest_pixels(self, xp, yp, rows, cols, *, workers: int = -1):
        """:meth:`nearest` of the projector coordinates ``xp, yp`` (float32 or float64 images)
        of the pixels ``(rows, cols)``, read in place."""
        xp, yp = _float_image(xp), _float_image(yp)
        n = rows.size
        best, d2 = np.empty(n, dtype=np.int64), np.empty(n)
        done = np.empty(n, dtype=bool)
        _in_chunks(lambda a, b: _grid_nearest_pixels(
            xp, yp, rows[a:b], cols[a:b], self.sx, self.sy, self.sindex, self.start, self.x0,
            self.y0, self.cell, self.nx, self.ny, _GRID_RINGS, self.empty, best[a:b], d2[a:b],
            done[a:b]),
            n, workers)
        todo = np.flatnonzero(~done)
        qx = xp[rows[todo], cols[todo]].astype(np.float64)
        qy = yp[rows[todo], cols[todo]].astype(np.float64)
        return self._settle(best, d2, todo, qx, qy, workers)

    def _settle(self, best, d2, todo, qx, qy, workers):
        """`best`, `d2` with the queries `todo` (at ``qx, qy``) left undecided by the rings
        answered from the edge k-d tree."""
        if todo.size:
            tree, members = self._boundary_tree()
            _, j = tree.query(np.stack([qx, qy], axis=-1), workers=workers)
            other = members[j]
            other_d2 = (qx - self.x[other]) ** 2 + (qy - self.y[other]) ** 2
            b, bd2 = best[todo], d2[todo]
            take = (b < 0) | (other_d2 < bd2) | ((other_d2 == bd2) & (other < b))
            best[todo] = np.where(take, other, b)
            d2[todo] = np.where(take, other_d2, bd2)
        return best, d2

    def _boundary_tree(self):
        """k-d tree of the pixels whose cell has an empty cell within ``⌈rings / 2⌉`` cells.

        A query undecided after `rings` rings has no pixel within ``rings × cell`` of it, so
        the open disc through its nearest pixel ``p`` centred on the query is empty; the disc of
        radius ``rings × cell / 2`` inside it and tangent at ``p`` then holds a whole cell
        (``rings / 2 > √2``), empty, within ``⌈rings / 2⌉`` cells of ``p``'s: ``p`` is in the
        tree.
        """
        if self._tree is None:
            occupied = (np.diff(self.start) > 0).reshape(self.ny, self.nx)
            reach = 2 * (-(-_GRID_RINGS // 2)) + 1
            inner = scipy.ndimage.minimum_filter(occupied, size=reach, mode="constant", cval=0)
            members = np.flatnonzero(~inner.ravel()[self.cell_of])
            tree = scipy.spatial.cKDTree(np.stack([self.x[members], self.y[members]], axis=-1),
                                         balanced_tree=False, compact_nodes=False)
            self._tree = (tree, members)
        return self._tree


_THREAD_MIN_ITEMS = 65536  # fewer items: one thread (starting threads costs more)


def _in_threads(kernel, n: int, workers: int) -> tuple:
    """``kernel(start, stop)`` over ``[0, n)`` in contiguous chunks, one per thread, and its
    output arrays concatenated: the one-call result for a kernel that treats every item alone
    (the compiled kernels release the GIL). `workers`: threads, ``-1`` all cores."""
    parts = _in_chunks(kernel, n, workers)
    if len(parts) == 1:
        return parts[0]
    return tuple(np.concatenate(arrays) for arrays in zip(*parts, strict=True))


def _in_chunks(kernel, n: int, workers: int) -> list:
    """``kernel(start, stop)`` over ``[0, n)`` in contiguous chunks, one per thread: the list
    of its return values, in the order of the chunks (one chunk for few items)."""
    threads = (os.cpu_count() or 1) if workers == -1 else max(int(workers), 1)
    threads = min(threads, n // _THREAD_MIN_ITEMS)
    if threads <= 1:
        return [kernel(0, n)]
    bounds = np.linspace(0, n, threads + 1).astype(np.int64)
    with ThreadPoolExecutor(threads) as pool:
        return list(pool.map(kernel, bounds[:-1], bounds[1:]))


def _pixel_spacing(scan: Scan, valid: np.ndarray) -> float:
    """Typical distance of neighbouring valid pixels in projector space, panel px (geometric
    mean of the median steps along rows and columns; on every fourth row and column)."""
    xp = np.asarray(scan.xp)[::4, ::4].astype(np.float64)
    yp = np.asarray(scan.yp)[::4, ::4].astype(np.float64)
    ok = valid[::4, ::4]
    steps = []
    for axis in (0, 1):
        lo = (slice(None, -1), slice(None)) if axis == 0 else (slice(None), slice(None, -1))
        hi = (slice(1, None), slice(None)) if axis == 0 else (slice(None), slice(1, None))
        both = ok[lo] & ok[hi]
        d = np.hypot(xp[hi] - xp[lo], yp[hi] - yp[lo])[both] / 4.0
        steps.append(float(np.median(d)) if d.size else np.nan)
    spacing = float(np.sqrt(steps[0] * steps[1]))
    return spacing if np.isfinite(spacing) and spacing > 0 else 0.0


@numba.njit(cache=cache_enabled(), nogil=True)
def _gather_valid(valid, xp, yp):
    """Rows and columns of the valid pixels (row-major, as np.nonzero), their ``xp``, ``yp``
    as float64, and ``[min x, min y, max x, max y]``."""
    h, w = valid.shape
    n = 0
    for r in range(h):
        for c in range(w):
            if valid[r, c]:
                n += 1
    rows = np.empty(n, dtype=np.intp)
    cols = np.empty(n, dtype=np.intp)
    x = np.empty(n)
    y = np.empty(n)
    box = np.array([np.inf, np.inf, -np.inf, -np.inf])
    k = 0
    for r in range(h):
        for c in range(w):
            if valid[r, c]:
                rows[k], cols[k] = r, c
                x[k], y[k] = np.float64(xp[r, c]), np.float64(yp[r, c])
                box[0] = min(box[0], x[k])
                box[1] = min(box[1], y[k])
                box[2] = max(box[2], x[k])
                box[3] = max(box[3], y[k])
                k += 1
    return rows, cols, x, y, box


@numba.njit(cache=cache_enabled(), nogil=True)
def _grid_build(x, y, x0, y0, cell, nx, ny):
    """The cells of the points (``min(int((x − x0) / cell), nx − 1)``, row-major ids), their
    counting sort (:func:`_bucket_sort`) and the coordinates in the cells' order."""
    cell_of = np.empty(x.size, dtype=np.int64)
    for i in range(x.size):
        gx = min(np.int64((x[i] - x0) / cell), nx - 1)
        gy = min(np.int64((y[i] - y0) / cell), ny - 1)
        cell_of[i] = gy * nx + gx
    start, order = _bucket_sort(cell_of, nx * ny)
    sx = np.empty(x.size)
    sy = np.empty(x.size)
    for i in range(x.size):
        sx[i], sy[i] = x[order[i]], y[order[i]]
    return start, order, sx, sy, cell_of


@numba.njit(cache=cache_enabled(), nogil=True)
def _bucket_sort(cell, n_cells):
    """Counting sort of `cell` ids: ``start`` (n_cells + 1) and the stable order of the items."""
    start = np.zeros(n_cells + 1, dtype=np.int64)
    for c in cell:
        start[c + 1] += 1
    for k in range(n_cells):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    order = np.empty(cell.size, dtype=np.int64)
    for i in range(cell.size):
        order[fill[cell[i]]] = i
        fill[cell[i]] += 1
    return start, order


@numba.njit(cache=cache_enabled(), nogil=True)
def _visit_cell(cid, x, y, sx, sy, sindex, start, b, bd2):
    """The best of `b` (squared distance `bd2`) and the points of cell `cid` (ties: lower index)."""
    for p in range(start[cid], start[cid + 1]):
        d2 = (x - sx[p]) ** 2 + (y - sy[p]) ** 2
        if d2 < bd2 or (d2 == bd2 and sindex[p] < b):
            b, bd2 = sindex[p], d2
    return b, bd2


@numba.njit(cache=cache_enabled(), nogil=True)
def _grid_query(x, y, sx, sy, sindex, start, x0, y0, cell, nx, ny, rings):
    """:func:`_grid_nearest` for one query ``(x, y)``: ``(index, squared distance, done)``."""
    limit = 2.0**40
    fx = min(max((x - x0) / cell, -limit), limit)
    fy = min(max((y - y0) / cell, -limit), limit)
    ci, cj = np.floor(fx), np.floor(fy)
    # distance from the query to the edges of its own cell, in cells
    margin = min(fx - ci, ci + 1.0 - fx, fy - cj, cj + 1.0 - fy)
    ci, cj = int(ci), int(cj)
    b, bd2 = -1, np.inf
    for k in range(rings + 1):
        for gy in range(max(cj - k, 0), min(cj + k, ny - 1) + 1):
            if gy == cj - k or gy == cj + k:  # top and bottom rows of the ring
                for gx in range(max(ci - k, 0), min(ci + k, nx - 1) + 1):
                    b, bd2 = _visit_cell(gy * nx + gx, x, y, sx, sy, sindex, start, b, bd2)
            else:  # its left and right cells
                if 0 <= ci - k < nx:
                    b, bd2 = _visit_cell(gy * nx + ci - k, x, y, sx, sy, sindex, start, b, bd2)
                if 0 <= ci + k < nx:
                    b, bd2 = _visit_cell(gy * nx + ci + k, x, y, sx, sy, sindex, start, b, bd2)
        reach = (k + margin) * cell
        if b >= 0 and bd2 < reach * reach * (1.0 - 1e-9):
            return b, bd2, True
    return b, bd2, False


@numba.njit(cache=cache_enabled(), nogil=True)
def _grid_nearest(qx, qy, sx, sy, sindex, start, x0, y0, cell, nx, ny, rings):
    """Nearest point of the grid for each query, by rings of cells around the query's cell.

    Returns the index of the nearest point found (−1 if none), its squared distance, and
    whether it is proven nearest: its distance is below the distance from the query to every
    cell beyond the rings searched (ties to the lower index).
    """
    n = qx.size
    best = np.empty(n, dtype=np.int64)
    best_d2 = np.empty(n)
    done = np.empty(n, dtype=np.bool_)
    for i in range(n):
        best[i], best_d2[i], done[i] = _grid_query(qx[i], qy[i], sx, sy, sindex, start, x0, y0,
                                                   cell, nx, ny, rings)
    return best, best_d2, done


@numba.njit(cache=cache_enabled(), nogil=True)
def _grid_nearest_pixels(xp, yp, rows, cols, sx, sy, sindex, start, x0, y0, cell, nx, ny,
                         rings, empty, best, best_d2, done):
    """:func:`_grid_nearest` of the projector coordinates of the pixels ``(rows, cols)`` of the
    images `xp`, `yp` (float32 or float64, read as float64: no gathered copies), into `best`,
    `best_d2`, `done`; each query starts from the previous one's nearest point as a bound
    (:func:`_grid_query_bounded`, `empty`: the cells' distance to an occupied one)."""
    hint = -1
    for i in range(rows.size):
        r, c = rows[i], cols[i]
        best[i], best_d2[i], done[i], hint = _grid_query_bounded(
            np.float64(xp[r, c]), np.float64(yp[r, c]), sx, sy, sindex, start, x0, y0, cell,
            nx, ny, rings, hint, empty)


@numba.njit(cache=cache_enabled(), nogil=True)
def _visit_cell_bounded(cid, x, y, sx, sy, sindex, start, b, bd2, bp):
    """:func:`_visit_cell`, also keeping the best point's position `bp` in the grid's order."""
    for p in range(start[cid], start[cid + 1]):
        d2 = (x - sx[p]) ** 2 + (y - sy[p]) ** 2
        if d2 < bd2 or (d2 == bd2 and sindex[p] < b):
            b, bd2, bp = sindex[p], d2, p
    return b, bd2, bp


@numba.njit(cache=cache_enabled(), nogil=True)
def _grid_query_bounded(x, y, sx, sy, sindex, start, x0, y0, cell, nx, ny, rings, hint,
                        empty):
    """:func:`_grid_query` that skips what cannot hold a nearer point: ``(index, squared
    distance, done, position of the best point in the grid's order)``.

    The point at position `hint` (−1: none; the previous query's nearest, a neighbouring pixel)
    starts as the best; a cell whose distance from the query exceeds the best distance found
    (with a margin for rounding) is not visited, and rings nearer than `empty` (per cell: the
    Chebyshev distance in cells to an occupied cell, at most ``rings + 1``) hold no point. A
    query proven done has the nearest point of the grid, ties to the lower index, the result
    of :func:`_grid_query`: no cell skipped can hold a point as near as the best.
    """
    limit = 2.0**40
    fx = min(max((x - x0) / cell, -limit), limit)
    fy = min(max((y - y0) / cell, -limit), limit)
    ci, cj = np.floor(fx), np.floor(fy)
    margin = min(fx - ci, ci + 1.0 - fx, fy - cj, cj + 1.0 - fy)
    ci, cj = int(ci), int(cj)
    b, bd2, bp = -1, np.inf, -1
    if hint >= 0:
        b, bd2, bp = sindex[hint], (x - sx[hint]) ** 2 + (y - sy[hint]) ** 2, hint
    k0 = 0
    if 0 <= ci < nx and 0 <= cj < ny:
        k0 = empty[cj, ci]
    inv = 1.0 / (cell * cell)
    for k in range(k0, rings + 1):
        for gy in range(max(cj - k, 0), min(cj + k, ny - 1) + 1):
            # distances in cells from the query to the row and to the cells, 0 in its own
            dy = 0.0 if gy == cj else (gy - fy if gy > cj else fy - (gy + 1))
            if gy == cj - k or gy == cj + k:  # top and bottom rows of the ring
                if dy * dy > bd2 * inv * (1.0 + 1e-6) + 1e-9:
                    continue
                for gx in range(max(ci - k, 0), min(ci + k, nx - 1) + 1):
                    dx = 0.0 if gx == ci else (gx - fx if gx > ci else fx - (gx + 1))
                    if dx * dx + dy * dy <= bd2 * inv * (1.0 + 1e-6) + 1e-9:
                        b, bd2, bp = _visit_cell_bounded(gy * nx + gx, x, y, sx, sy, sindex,
                                                         start, b, bd2, bp)
            else:  # its left and right cells
                if 0 <= ci - k < nx:
                    dx = fx - (ci - k + 1)
                    if dx * dx + dy * dy <= bd2 * inv * (1.0 + 1e-6) + 1e-9:
                        b, bd2, bp = _visit_cell_bounded(gy * nx + ci - k, x, y, sx, sy,
                                                         sindex, start, b, bd2, bp)
                if 0 <= ci + k < nx:
                    dx = ci + k - fx
                    if dx * dx + dy * dy <= bd2 * inv * (1.0 + 1e-6) + 1e-9:
                        b, bd2, bp = _visit_cell_bounded(gy * nx + ci + k, x, y, sx, sy,
                                                         sindex, start, b, bd2, bp)
        reach = (k + margin) * cell
        if b >= 0 and bd2 < reach * reach * (1.0 - 1e-9):
            return b, bd2, True, bp
    # rings skipped as empty end the search with the last ring's test
    reach = (rings + margin) * cell
    return b, bd2, b >= 0 and bd2 < reach * reach * (1.0 - 1e-9), bp


# -- sub-pixel refinement --------------------------------------------------------------------
def refine_subpixel(
    xp, yp, target_xp, target_yp, rows, cols, *, iterations: int = _NEWTON_STEPS
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sub-pixel position where the child's projector coordinates equal a target.

    Starting from the nearest pixel ``(rows, cols)``, one step of the local affine model (central
    differences) and `iterations` Newton steps on the bilinear interpolant of ``(xp, yp)`` solve
    ``xp(r, c) = target_xp``, ``yp(r, c) = target_yp``.

    Parameters
    ----------
    xp, yp : (H, W) float
        Child projector coordinates, panel px (NaN invalid).
    target_xp, target_yp : (N,) float
        Parent projector coordinates to reach.
    rows, cols : (N,) int
        Nearest child pixels; must be at least one pixel inside the image.
    iterations : int
        Newton steps on the bilinear model.

    Returns
    -------
    row, col : (N,) float64
        Sub-pixel child position (pixel-centre convention); NaN where the neighbourhood is invalid.
    residual_px : (N,) float64
        ``|(xp, yp)(row, col) − target|`` in panel px; NaN where undefined.

    Examples
    --------
    >>> rr, cc = np.mgrid[0:5, 0:5].astype(float)
    >>> r, c, res = refine_subpixel(2 * cc + 1, 3 * rr, [5.5], [6.3], [2], [2])
    >>> round(float(r[0]), 6), round(float(c[0]), 6), float(res[0]) < 1e-9
    (2.1, 2.25, True)
    """
    xp = np.asarray(xp, dtype=np.float64)
    yp = np.asarray(yp, dtype=np.float64)
    field_ = np.stack([xp, yp], axis=-1)
    target = np.stack([np.asarray(target_xp, np.float64), np.asarray(target_yp, np.float64)], -1)
    rows = np.asarray(rows, dtype=np.intp)
    cols = np.asarray(cols, dtype=np.intp)
    h, w = xp.shape
    if rows.size and (rows.min() < 1 or rows.max() > h - 2 or cols.min() < 1 or cols.max() > w - 2):
        raise ValueError("rows, cols: nearest pixels must lie at least one pixel inside the image")
    # local affine model from central differences
    f = field_[rows, cols]
    d_dc = 0.5 * (field_[rows, cols + 1] - field_[rows, cols - 1])
    d_dr = 0.5 * (field_[rows + 1, cols] - field_[rows - 1, cols])
    r, c = rows.astype(np.float64), cols.astype(np.float64)
    bad = np.zeros(rows.shape, dtype=bool)
    for k in range(iterations + 1):
        if k > 0:
            f, d_dr, d_dc = bilinear(field_, r, c)
        e = target - f
        a, b = d_dc[:, 0], d_dr[:, 0]  # d xp / d(col, row)
        cc_, d = d_dc[:, 1], d_dr[:, 1]  # d yp / d(col, row)
        with np.errstate(divide="ignore", invalid="ignore"):
            det = a * d - b * cc_
            step_c = (d * e[:, 0] - b * e[:, 1]) / det
            step_r = (a * e[:, 1] - cc_ * e[:, 0]) / det
        bad |= ~(np.isfinite(step_r) & np.isfinite(step_c))
        # keep the iterate near the seed; a far solution is reported by the residual
        r = np.where(bad, rows, np.clip(r + step_r, rows - _MAX_SHIFT_PX, rows + _MAX_SHIFT_PX))
        c = np.where(bad, cols, np.clip(c + step_c, cols - _MAX_SHIFT_PX, cols + _MAX_SHIFT_PX))
        r = np.clip(r, 0, h - 1)
        c = np.clip(c, 0, w - 1)
    f, _, _ = bilinear(field_, r, c)
    residual = np.hypot(*(f - target).T)
    bad |= ~np.isfinite(residual)
    residual[bad] = np.nan
    r[bad] = np.nan
    c[bad] = np.nan
    return r, c, residual


@numba.njit(cache=cache_enabled(), nogil=True, error_model="numpy")
def _step_within(r, c, dr, dc, r0, c0, max_shift, h, w):  # pragma: no cover - compiled
    """``(r + dr, c + dc)`` kept within `max_shift` of the nearest pixel ``(r0, c0)`` and inside
    the ``(h, w)`` image: the refinements' moves."""
    r = min(max(r + dr, r0 - max_shift), r0 + max_shift)
    c = min(max(c + dc, c0 - max_shift), c0 + max_shift)
    return min(max(r, 0.0), h - 1.0), min(max(c, 0.0), w - 1.0)


@numba.njit(cache=cache_enabled(), nogil=True, error_model="numpy")
def _refine_one(xp, yp, r0, c0, tx, ty, iterations, max_shift):
    """:func:`refine_subpixel` of one pixel: ``(row, col, residual)``, ``bad`` where the
    refinement failed (residual NaN or infinite then). Every value read as float64."""
    f8 = np.float64
    h, w = xp.shape
    fx, fy = f8(xp[r0, c0]), f8(yp[r0, c0])
    ax = 0.5 * (f8(xp[r0, c0 + 1]) - f8(xp[r0, c0 - 1]))
    ay = 0.5 * (f8(yp[r0, c0 + 1]) - f8(yp[r0, c0 - 1]))
    bx = 0.5 * (f8(xp[r0 + 1, c0]) - f8(xp[r0 - 1, c0]))
    by = 0.5 * (f8(yp[r0 + 1, c0]) - f8(yp[r0 - 1, c0]))
    r, c = float(r0), float(c0)
    for k in range(iterations + 2):
        if k > 0:  # the bilinear model's value and derivatives (b: along rows, a: columns)
            fx, bx, ax = bilinear_gradient(xp, r, c)
            fy, by, ay = bilinear_gradient(yp, r, c)
            if k == iterations + 1:
                break
        ex, ey = tx - fx, ty - fy
        det = ax * by - bx * ay
        step_c = (by * ex - bx * ey) / det
        step_r = (ax * ey - ay * ex) / det
        if not (np.isfinite(step_r) and np.isfinite(step_c)):
            return r, c, np.nan, True
        r, c = _step_within(r, c, step_r, step_c, r0, c0, max_shift, h, w)
    res = np.hypot(fx - tx, fy - ty)
    return r, c, res, not np.isfinite(res)


@numba.njit(cache=cache_enabled(), nogil=True, error_model="numpy")
def _bilinear_xyz(xyz, r, c, out):
    """`out` (3,) ← the bilinear interpolation of `xyz` (H, W, 3) at ``(r, c)``, float64."""
    for j in range(3):
        out[j] = bilinear_value(xyz[:, :, j], r, c)


@numba.njit(cache=cache_enabled(), nogil=True, error_model="numpy")
def _slide_one(p, xyz, r, c, r0, c0, target, point, iterations, max_shift):
    """From ``(r, c)``, the child position on the curve ``p = target`` nearest in the world to
    `point` (3,): ``(row, col, |p − target|, bad)``.

    Each iteration takes one Newton step onto the curve along the gradient of `p`, then one
    Gauss–Newton step along the curve's tangent towards `point` (the child's surface
    linearised there); the position stays within `max_shift` of ``(r0, c0)``.
    """
    h, w = p.shape
    for _ in range(iterations):
        f, gr, gc = bilinear_gradient(p, r, c)
        g2 = gr * gr + gc * gc
        if not (np.isfinite(f) and np.isfinite(g2)) or g2 == 0.0:
            return r, c, np.nan, True
        step = (target - f) / g2
        r, c = _step_within(r, c, step * gr, step * gc, r0, c0, max_shift, h, w)
        norm = np.sqrt(g2)
        tr, tc = -gc / norm, gr / norm  # the curve's direction, (row, col)
        num = den = 0.0
        for j in range(3):
            x, xr, xc = bilinear_gradient(xyz[:, :, j], r, c)
            d = xr * tr + xc * tc
            num += (point[j] - x) * d
            den += d * d
        if not (np.isfinite(num) and np.isfinite(den)) or den == 0.0:
            return r, c, np.nan, True
        s = num / den
        r, c = _step_within(r, c, s * tr, s * tc, r0, c0, max_shift, h, w)
    f, _, _ = bilinear_gradient(p, r, c)
    res = abs(f - target)
    return r, c, res, not np.isfinite(res)


@numba.njit(cache=cache_enabled(), nogil=True, error_model="numpy")
def _pairs_kernel(rows, cols, nr, nc, child_inner, cxp, cyp, cxyz, pxp, pyp, pxyz, iterations,
                  max_shift, max_residual, along, parent_rc, child_nearest, child_rc,
                  xyz_parent, xyz_child, residual, distance, code):
    """The pairs of :func:`correspond` after the nearest-neighbour search, in one pass.

    For each parent pixel ``(rows, cols)`` and its nearest child pixel ``(nr, nc)``: dropped
    (``child_border``) unless the child pixel is in `child_inner` and the refinement
    (:func:`_refine_one`, target the parent's ``xp, yp``) and the interpolated child point are
    finite, dropped (``residual``) when the residual is not within `max_residual`; else a pair.
    `along` 1 (``xp``) or 2 (``yp``): from the refined position, the child position keeping
    that coordinate's value nearest in the world to the parent's point (:func:`_slide_one`),
    the residual that coordinate's alone; 0: both coordinates (the thesis).
    The pairs go, in input order, to the first rows of the outputs (parent and child pixels,
    sub-pixel child position, the two world points, residual, world distance, all as the
    NumPy formulation computes them); returns their number and the two drop counts. `code`
    (one per input pixel) gets 0 for a pair, 1 for ``child_border``, 2 for ``residual``.
    """
    f8 = np.float64
    border = far = 0
    point = np.empty(3)
    k = 0
    for i in range(rows.size):
        r0, c0 = nr[i], nc[i]
        code[i] = 1
        if not child_inner[r0, c0]:
            border += 1
            continue
        pr, pc = rows[i], cols[i]
        r, c, res, bad = _refine_one(cxp, cyp, r0, c0, f8(pxp[pr, pc]), f8(pyp[pr, pc]),
                                     iterations, max_shift)
        if bad:
            border += 1
            continue
        if along != 0:
            for j in range(3):
                point[j] = f8(pxyz[pr, pc, j])
            if along == 1:
                r, c, res, bad = _slide_one(cxp, cxyz, r, c, r0, c0, f8(pxp[pr, pc]), point,
                                            _SLIDE_STEPS, max_shift)
            else:
                r, c, res, bad = _slide_one(cyp, cxyz, r, c, r0, c0, f8(pyp[pr, pc]), point,
                                            _SLIDE_STEPS, max_shift)
            if bad:
                border += 1
                continue
        _bilinear_xyz(cxyz, r, c, point)
        if not (np.isfinite(point[0]) and np.isfinite(point[1]) and np.isfinite(point[2])):
            border += 1
            continue
        if not res <= max_residual:
            code[i] = 2
            far += 1
            continue
        code[i] = 0
        parent_rc[k, 0], parent_rc[k, 1] = pr, pc
        child_nearest[k, 0], child_nearest[k, 1] = r0, c0
        child_rc[k, 0], child_rc[k, 1] = r, c
        residual[k] = res
        s = 0.0
        for j in range(3):
            p = f8(pxyz[pr, pc, j])
            xyz_parent[k, j] = p
            xyz_child[k, j] = point[j]
            d = p - point[j]
            s = s + d * d  # np.linalg.norm's order: (d0² + d1²) + d2²
        distance[k] = np.sqrt(s)
        k += 1
    return k, border, far


def _take_rows(v: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``np.take(v, index, axis=0)`` of a 1-D or C-contiguous 2-D array (compiled)."""
    if v.ndim == 2 and v.flags.c_contiguous:
        return _take_rows_kernel(v, index)
    if v.ndim == 1:
        return _take_rows_kernel(v.reshape(-1, 1), index).reshape(-1)
    return np.take(v, index, axis=0)


@numba.njit(cache=cache_enabled(), nogil=True)
def _take_rows_kernel(v, index):
    out = np.empty((index.size, v.shape[1]), dtype=v.dtype)
    for i in range(index.size):
        for j in range(v.shape[1]):
            out[i, j] = v[index[i], j]
    return out


@numba.njit(cache=cache_enabled(), nogil=True, error_model="numpy")
def _bilinear_at_least(image, rc, threshold, ok):
    """``ok &= value >= threshold``, value the :func:`~nail2nail._interpolate.bilinear_value`
    of `image` at the rows and columns ``rc`` (N, 2) (integer or float, read as float64)."""
    for i in range(rc.shape[0]):
        if not bilinear_value(image, np.float64(rc[i, 0]), np.float64(rc[i, 1])) >= threshold:
            ok[i] = False


# -- the correspondence ----------------------------------------------------------------------
@dataclass
class Correspondence:
    """Corresponding pixels of a parent and a child scan and their world points.

    Attributes
    ----------
    parent_name, child_name : str
    parent_shape, child_shape : (int, int)
        ``(H, W)`` of the two scans.
    parent_rc : (N, 2) intp
        Parent pixel ``(row, col)`` of each kept pair.
    child_nearest : (N, 2) intp
        Nearest child pixel in projector space (the thesis's mapping).
    child_rc : (N, 2) float64
        Refined sub-pixel child position ``(row, col)`` (equal to `child_nearest` unrefined).
    xyz_parent, xyz_child : (N, 3) float64
        World points, mm; the child's interpolated at `child_rc`.
    residual_px : (N,) float64
        Projector-coordinate residual of the pair after refinement, panel px.
    n_sampled : int
        Valid parent pixels on the stride grid that were tried.
    dropped : dict[str, int]
        Pixels dropped per reason (:data:`DROP_REASONS`; the last three count the rejected
        pairs).
    stride : int
    rejected : Correspondence or None
        The pairs found but rejected (:data:`REJECT_REASONS`), with their reason in `reason`;
        None when no rejection test ran.
    reason : (N,) str or None
        For the pairs of a `rejected` correspondence, why each was rejected.
    unpaired_rc, unpaired_nearest : (M, 2) intp or None
        The parent pixels searched but left without a pair (dropped as ``"child_border"`` or
        ``"residual"``) and their nearest child pixel; what :func:`restrict_pairs` needs to
        count the drops of a narrower border. None on a `rejected` correspondence and on one
        that is itself restricted.
    unpaired_reason : (M,) int8 or None
        1 for ``"child_border"``, 2 for ``"residual"``.
    pair_by : {"xpyp", "xp", "yp", "pixel"}
        What paired the pixels: both projector coordinates (the thesis), one of them and the
        child's surface (:func:`correspond`'s `pair_by`), or the same pixel of one camera
        (:func:`same_pixel_pairs`).
    """

    parent_name: str
    child_name: str
    parent_shape: tuple[int, int]
    child_shape: tuple[int, int]
    parent_rc: np.ndarray
    child_nearest: np.ndarray
    child_rc: np.ndarray
    xyz_parent: np.ndarray
    xyz_child: np.ndarray
    residual_px: np.ndarray
    n_sampled: int
    dropped: dict[str, int] = field(default_factory=dict)
    stride: int = 1
    rejected: Correspondence | None = None
    reason: np.ndarray | None = None
    unpaired_rc: np.ndarray | None = None
    unpaired_nearest: np.ndarray | None = None
    unpaired_reason: np.ndarray | None = None
    pair_by: str = "xpyp"

    @property
    def n_pairs(self) -> int:
        """Number of kept pairs."""
        return int(self.parent_rc.shape[0])

    @property
    def distance_mm(self) -> np.ndarray:
        """(N,) float64 Euclidean world distance of each pair, mm (the merge error)."""
        return np.linalg.norm(self.xyz_parent - self.xyz_child, axis=-1)

    @property
    def squared_mm2(self) -> np.ndarray:
        """(N,) float64 the thesis's figure: squared world distance, mm² (``p_world_dist``)."""
        return np.sum((self.xyz_parent - self.xyz_child) ** 2, axis=-1)

    @property
    def mapping(self) -> np.ndarray:
        """(H, W, 2) int32 the thesis's mapping matrix: child ``(row, col)`` per parent pixel.

        −1 where the parent pixel has no kept pair.
        """
        out = np.full((*self.parent_shape, 2), -1, dtype=np.int32)
        out[self.parent_rc[:, 0], self.parent_rc[:, 1]] = self.child_nearest
        return out

    def distance_image(self) -> np.ndarray:
        """(H, W) float32 merge error on the parent's grid, mm; NaN where no pair."""
        out = np.full(self.parent_shape, np.nan, dtype=np.float32)
        out[self.parent_rc[:, 0], self.parent_rc[:, 1]] = self.distance_mm
        return out

    def all_pairs(self) -> Correspondence:
        """The kept and the rejected pairs together (the correspondence before rejection)."""
        if self.rejected is None or self.rejected.n_pairs == 0:
            return self
        r = self.rejected
        return Correspondence(
            parent_name=self.parent_name, child_name=self.child_name,
            parent_shape=self.parent_shape, child_shape=self.child_shape,
            **{k: np.concatenate([getattr(self, k), getattr(r, k)]) for k in (
                "parent_rc", "child_nearest", "child_rc", "xyz_parent", "xyz_child",
                "residual_px")},
            n_sampled=self.n_sampled,
            dropped={k: v for k, v in self.dropped.items() if k not in REJECT_REASONS},
            stride=self.stride, pair_by=self.pair_by,
        )

    def statistics(self) -> dict:
        """Merge-error statistics of the kept pairs, see :func:`merge_statistics`, the pair
        counts, the rejections per reason and the statistics of all pairs before rejection
        (``"before_rejection"``: ``{pairs, distance_mm, squared_mm2}``)."""
        stats = merge_statistics(self.distance_mm)
        before = self.all_pairs()
        return {
            "parent": self.parent_name,
            "child": self.child_name,
            "stride": self.stride,
            "pair_by": self.pair_by,
            "sampled": self.n_sampled,
            "pairs": self.n_pairs,
            "dropped": dict(self.dropped),
            "rejected": {k: int(self.dropped.get(k, 0)) for k in REJECT_REASONS},
            **stats,
            "before_rejection": {"pairs": before.n_pairs,
                                 **merge_statistics(before.distance_mm)},
        }


def check_pair_by(pair_by) -> str:
    """`pair_by` if it is one of :data:`PAIR_BY`; else ``ValueError`` naming it."""
    if pair_by not in PAIR_BY:
        raise ValueError(f"pair_by: expected 'auto', 'xpyp', 'xp' or 'yp', got {pair_by!r}")
    return pair_by


def pairing_coordinates(parent: Scan, child: Scan, pair_by: str = "auto") -> str:
    """The projector coordinates that pair two scans: ``"xpyp"``, ``"xp"`` or ``"yp"``.

    `pair_by` as :func:`correspond` takes it; ``"auto"`` is the coordinate both scans were
    triangulated from (:attr:`~nail2nail.scan.results.Scan.triangulated_from`) when they share
    one, and both coordinates otherwise (either scan's unknown, or triangulated from both).

    The thesis pairs by both projector coordinates (chapter four, "Merging in Projector
    Space": the nearest ``(xp, yp)``, appendix ``closest_proj_point``); pairing by one of them
    and the surface is beyond it, for scans whose points do not use the other
    (``docs/motion.md``, "The merge of scans triangulated from one coordinate").

    Examples
    --------
    >>> one = np.ones((4, 4), np.float32)
    >>> a = Scan("a", np.zeros((4, 4, 3), np.float32), one, one, one, one, one, one > 0,
    ...          triangulated_from="yp")
    >>> pairing_coordinates(a, a), pairing_coordinates(a, a, "xpyp")
    ('yp', 'xpyp')
    """
    if check_pair_by(pair_by) != "auto":
        return pair_by
    used = parent.triangulated_from
    return used if used in ("xp", "yp") and child.triangulated_from == used else "xpyp"


def correspond(
    parent: Scan,
    child: Scan,
    *,
    stride: int = 1,
    max_residual_px: float = 0.5,
    border_px: int = 2,
    max_jump_px: float = 2.0,
    refine: bool = True,
    method: str = "grid",
    workers: int = -1,
    max_view_angle_deg: float | None = 70.0,
    max_incidence_deg: float | None = 65.0,
    min_relative_modulation: float | None = 1 / 3,
    outlier_mm: float | None = 0.025,
    outlier_mad: float = 4.0,
    outlier_block_px: int = 32,
    cache: CorrespondenceCache | None = None,
    pair_by: str = "auto",
) -> Correspondence:
    """Corresponding pixels of two scans in projector space, and their world points.

    For every valid parent pixel on the `stride` grid, the child pixel with the nearest
    ``(xp, yp)``, refined to sub-pixel (:func:`refine_subpixel`) with the child's world point
    interpolated bilinearly there. Pairs are dropped, in this order, when the parent pixel is
    within `border_px` of the edge of the parent's valid region (``"parent_border"``), the child
    position is within `border_px` of the edge of the child's valid region or its neighbourhood
    is invalid (``"child_border"``), or the projector residual exceeds `max_residual_px`
    (``"residual"``; the decoding noise: a pixel the child never saw has a large residual).
    Pixels where the projector coordinates jump (depth discontinuities) count as edges of the
    valid region, so no pair interpolates across one.

    The pairs found are then tested, and the unreliable ones rejected (kept apart in
    :attr:`Correspondence.rejected`): ``"view_angle"``, either camera views the point at more than
    `max_view_angle_deg` from its normal (:func:`view_cosine`, smoothed over 2 px; needs the scans'
    ``camera_center``); ``"incidence"``, the projector's light meets the point at more than
    `max_incidence_deg` from its normal in either scan (:func:`incidence_cosine`, smoothed over 2
    px; needs ``projector_center``; the fringes stretch over the surface as 1 / cos, and with them
    the along-surface error of a point); ``"modulation"``, either camera's fringe modulation there
    is below `min_relative_modulation` × its median over its valid pixels (the phase noise grows as
    1 / modulation); ``"outlier"``, the pair's distance is an outlier among its neighbours'
    (:func:`local_outliers` with `outlier_block_px`, `outlier_mm`, `outlier_mad`). ``None`` skips a
    test.

    Parameters
    ----------
    parent, child : Scan
    stride : int
        Sample every `stride`-th row and column of the parent (the thesis used 5 and 20).
    max_residual_px : float
        Largest projector-coordinate residual of a kept pair, panel px (of the one coordinate
        with `pair_by` ``"xp"`` or ``"yp"``). Without `refine` the residual is the distance to
        the nearest child pixel.
    border_px : int
        Erosion of both valid regions, px (≥ 1: refinement needs the 3 × 3 neighbourhood).
    max_jump_px : float
        Second difference of ``xp`` or ``yp`` between neighbouring pixels above which (and above
        the local slope) a pixel is a discontinuity, panel px.
    refine : bool
        Sub-pixel refinement; ``False`` takes the nearest child pixel as the appendix.
    method : {"grid", "kdtree", "bruteforce"}
        Nearest-neighbour search, all exact: a bucket grid (:func:`nearest_grid`, the fastest),
        a k-d tree built for the call (:func:`nearest_kdtree`), or the appendix's exhaustive
        search (:func:`nearest_bruteforce`, for small inputs only).
    workers : int
        Threads for the nearest-neighbour search and the refinement (``-1``: all cores); the
        results do not depend on it.
    max_view_angle_deg : float or None
        Largest viewing angle (between the normal and the ray to the camera) of a kept pair in
        either camera, degrees.
    max_incidence_deg : float or None
        Largest angle of incidence (between the normal and the ray to the projector) of a kept
        pair in either scan, degrees. The default, 65°, was chosen on two fingers of the
        two-side-projector rigs, where the far side's pairs under 65–80° made the tail of the
        merge (``docs/projectors.md``).
    min_relative_modulation : float or None
        Smallest modulation of a kept pair in either camera, as a fraction of that camera's
        median modulation.
    outlier_mm : float or None
        Smallest excess of a pair's distance over the local median that makes it an outlier,
        mm; None skips the outlier test.
    outlier_mad : float
        The excess must also exceed this many local MADs.
    outlier_block_px : int
        Size of the parent-image blocks over which the local median and MAD are taken, px.
    cache : CorrespondenceCache, optional
        Keeps what is derived from each scan (masks, view cosine, modulation, search grid) for
        the next call with the same scan; matching one scan several times, pass one cache.
    pair_by : {"auto", "xpyp", "xp", "yp"}
        What a pair shares (with `refine`; without it, the nearest pixel in ``(xp, yp)``).
        ``"xpyp"``: both projector coordinates, the thesis's pairing. ``"xp"`` or ``"yp"``:
        that coordinate, and along it the child's point nearest in the world to the parent's
        (the distance from the parent's point to the child's surface curve of equal
        coordinate), for scans triangulated from that one coordinate, whose other coordinate
        is decoded but measures no point: a moving finger's stabilised scans
        (``docs/motion.md``) have it from another time. ``"auto"``
        (:func:`pairing_coordinates`): the coordinate both scans were triangulated from
        (:attr:`~nail2nail.scan.results.Scan.triangulated_from`) when it is one, else both.

    Returns
    -------
    Correspondence

    Raises
    ------
    TypeError
        If a scan is not a :class:`~nail2nail.scan.results.Scan`.
    ValueError
        On inconsistent shapes, a bad option, or a child without valid pixels.

    References
    ----------
    Thesis, chapter four, "Merging in Projector Space", steps i–viii; appendix
    ``closest_proj_point``.

    Examples
    --------
    >>> rr, cc = np.mgrid[0:20, 0:20].astype(np.float32)
    >>> xyz = np.stack([cc, rr, 0 * rr], -1)
    >>> one = np.ones((20, 20), np.float32)
    >>> a = Scan("a", xyz, cc, rr, one, one, one, one > 0)
    >>> b = Scan("b", xyz + [0, 0, 0.01], cc + 0.25, rr, one, one, one, one > 0)
    >>> m = correspond(a, b, stride=4)
    >>> m.n_pairs, round(float(np.median(m.distance_mm)), 4)
    (16, 0.2502)
    """
    return _correspond(
        parent, child, stride=stride, max_residual_px=max_residual_px, border_px=border_px,
        max_jump_px=max_jump_px, refine=refine, method=method, workers=workers,
        max_view_angle_deg=max_view_angle_deg, max_incidence_deg=max_incidence_deg,
        min_relative_modulation=min_relative_modulation,
        outlier_mm=outlier_mm, outlier_mad=outlier_mad, outlier_block_px=outlier_block_px,
        cache=cache, pair_by=pair_by,
    )


def same_pixel_pairs(
    parent: Scan,
    child: Scan,
    *,
    stride: int = 1,
    border_px: int = 2,
    max_jump_px: float = 2.0,
    max_view_angle_deg: float | None = 70.0,
    max_incidence_deg: float | None = 65.0,
    min_relative_modulation: float | None = 1 / 3,
    outlier_mm: float | None = 0.025,
    outlier_mad: float = 4.0,
    outlier_block_px: int = 32,
    cache: CorrespondenceCache | None = None,
    quality: dict | None = None,
) -> Correspondence:
    """Pairs of two scans of one camera under two projectors: the same pixel in both.

    A pixel lit by two projectors is measured twice, once through each projector's
    coordinates; the two world points are one surface point, so their distance is the merge
    error of the pair (and their mean a better point). The pixels are those of the parent's
    inner region (`border_px`, `max_jump_px` as :func:`correspond`) on the `stride` grid that
    are in the child's inner region too (else ``"child_border"``); the pairs are then tested as
    :func:`correspond`'s (:data:`REJECT_REASONS`). ``residual_px`` is 0:
    there is no search.

    Parameters
    ----------
    parent, child : Scan
        Of the same camera (same image size), from two projectors.
    stride, border_px, max_jump_px, max_view_angle_deg, max_incidence_deg,
    min_relative_modulation, outlier_mm, outlier_mad, outlier_block_px, cache
        As :func:`correspond`.
    quality : dict, optional
        As :func:`_correspond`'s (the fusion's cached view cosines).

    Returns
    -------
    Correspondence
        ``child_nearest`` and ``child_rc`` are the parent's pixels; ``residual_px`` 0.

    References
    ----------
    Thesis, chapter four: the merge error is the world distance of two measurements of one
    surface point; there the point is found in the shared projector's coordinates, here in
    the shared camera's pixel (``docs/projectors.md``).

    Examples
    --------
    >>> rr, cc = np.mgrid[0:20, 0:20].astype(np.float32)
    >>> one = np.ones((20, 20), np.float32)
    >>> a = Scan("a", np.stack([cc, rr, 0 * rr], -1), cc, rr, one, one, one, one > 0)
    >>> b = Scan("b", np.stack([cc, rr, 0 * rr + 0.01], -1), 2 * cc, rr, one, one, one,
    ...          one > 0)
    >>> m = same_pixel_pairs(a, b)
    >>> m.n_pairs, round(float(np.median(m.distance_mm)), 4)
    (256, 0.01)
    """
    _check_scan(parent, "parent")
    _check_scan(child, "child")
    if np.shape(parent.mask) != np.shape(child.mask):
        raise ValueError(f"child: {np.shape(child.mask)} pixels, the parent's camera has "
                         f"{np.shape(parent.mask)} (same_pixel_pairs pairs scans of one camera)")
    _check_angles(max_view_angle_deg, max_incidence_deg)
    stride = as_int(stride, "stride", minimum=1)
    border_px = as_int(border_px, "border_px", minimum=1)
    if cache is None:
        cache = CorrespondenceCache()
    parent_images, child_images = cache._entry(parent), cache._entry(child)
    n_sampled, rows, cols = parent_images.inner_pixels(max_jump_px, border_px, stride)
    child_inner = child_images.inner(max_jump_px, border_px)
    dropped = dict.fromkeys(DROP_REASONS, 0)
    dropped["parent_border"] = n_sampled - rows.size
    both = child_inner[rows, cols]
    dropped["child_border"] = int(np.count_nonzero(~both))
    rc = np.stack([rows[both], cols[both]], axis=-1)
    pairs = {
        "parent_rc": rc,
        "child_nearest": rc.copy(),
        "child_rc": rc.astype(np.float64),
        "xyz_parent": np.asarray(parent.xyz)[rc[:, 0], rc[:, 1]].astype(np.float64),
        "xyz_child": np.asarray(child.xyz)[rc[:, 0], rc[:, 1]].astype(np.float64),
        "residual_px": np.zeros(rc.shape[0]),
    }
    lone = np.stack([rows[~both], cols[~both]], axis=-1)
    unpaired = {"unpaired_rc": lone, "unpaired_nearest": lone.copy(),
                "unpaired_reason": np.ones(lone.shape[0], dtype=np.int8)}
    return _tested(parent, child, pairs, None, dropped, unpaired, n_sampled=n_sampled,
                   stride=stride, shapes=(np.shape(parent.mask), np.shape(child.mask)),
                   max_view_angle_deg=max_view_angle_deg, max_incidence_deg=max_incidence_deg,
                   min_relative_modulation=min_relative_modulation, outlier_mm=outlier_mm,
                   outlier_mad=outlier_mad, outlier_block_px=outlier_block_px, quality=quality,
                   cache=cache, pair_by="pixel")


def _tested(parent, child, pairs, distance, dropped, unpaired, *, n_sampled, stride, shapes,
            max_view_angle_deg, max_incidence_deg, min_relative_modulation, outlier_mm,
            outlier_mad, outlier_block_px, quality, cache, pair_by) -> Correspondence:
    """The pairs found (`pairs`: the :class:`Correspondence` arrays; `distance` their world
    distances or None; found by `pair_by`) tested for reliability and split into the kept and
    the rejected ones (:func:`correspond`'s tests); `dropped` gets the rejection counts."""
    # rejection of unreliable pairs, in the order of REJECT_REASONS
    n = pairs["parent_rc"].shape[0]
    reason = np.full(n, -1, dtype=np.int8)
    pr, pc = pairs["parent_rc"].T
    limits = (max_view_angle_deg, max_incidence_deg, min_relative_modulation)
    tests = any(v is not None for v in (*limits, outlier_mm))
    if quality is None:
        quality = {}

    def images(scan, k):
        slot = quality.setdefault(id(scan), [None, None, None])
        if slot[k] is None:
            entry = cache._entry(scan)
            slot[k] = (entry.cosine, entry.incidence, entry.modulation)[k]()
        return slot[k]

    # an angle test skips a scan without the centre it needs (a mat5 set)
    needs = ("camera_center", "projector_center", None)
    for code, limit in enumerate(limits):
        if limit is None or n == 0:
            continue
        threshold = np.cos(np.radians(limit)) if needs[code] is not None else limit
        ok = np.ones(n, dtype=bool)
        key = needs[code]
        for scan, rc in ((parent, pairs["parent_rc"]), (child, pairs["child_rc"])):
            if key is not None and getattr(scan, key) is None:
                continue
            _bilinear_at_least(images(scan, code), rc, float(threshold), ok)
        reason[(reason < 0) & ~ok] = code
    if outlier_mm is not None and n:
        live = reason < 0
        if distance is None:
            distance = np.linalg.norm(pairs["xyz_parent"] - pairs["xyz_child"], axis=-1)
        outliers = local_outliers(pr[live], pc[live], distance[live],
                                  block_px=outlier_block_px, floor_mm=outlier_mm,
                                  k_mad=outlier_mad)
        reason[np.flatnonzero(live)[outliers]] = REJECT_REASONS.index("outlier")
    for code, name in enumerate(REJECT_REASONS):
        dropped[name] = int(np.count_nonzero(reason == code))

    def subset(index, **extra):
        # the pairs' arrays when all are taken (copied when views of the kernel's buffers, which
        # hold a row for every parent pixel searched), else the rows of `index`
        if index.size == n:
            arrays = {k: v.copy() if v.base is not None else v for k, v in pairs.items()}
        else:
            arrays = {k: _take_rows(v, index) for k, v in pairs.items()}
        return Correspondence(
            parent_name=str(parent.name), child_name=str(child.name),
            parent_shape=tuple(shapes[0]), child_shape=tuple(shapes[1]),
            **arrays, n_sampled=int(n_sampled), stride=stride, pair_by=pair_by, **extra)

    rejected = None
    if tests:
        bad = np.flatnonzero(reason >= 0)
        rejected = subset(bad, reason=np.asarray(REJECT_REASONS)[reason[bad]],
                          dropped={k: dropped[k] for k in REJECT_REASONS})
    return subset(np.flatnonzero(reason < 0), dropped=dropped, rejected=rejected, **unpaired)


def restrict_pairs(
    corr: Correspondence,
    parent: Scan,
    child: Scan,
    *,
    border_px: int,
    stride: int = 1,
    parent_valid: np.ndarray | None = None,
    child_valid: np.ndarray | None = None,
    max_jump_px: float = 2.0,
) -> Correspondence:
    """The pairs of a correspondence that a search with a wider border and a stride would find.

    One search serves several readers: the fusion matches every pixel with a 1-pixel border
    (:func:`~nail2nail.merge.fusion.fuse_scans`), and the merge error statistics take the same
    pairs away from the edges of the valid regions (``border_px=2``) instead of searching again.
    The result holds exactly the pairs, the drop counts (``parent_border``, ``child_border``,
    ``residual``) and the view-angle and modulation rejections of
    ``correspond(parent, child, border_px=border_px, stride=stride)`` on the same scans; a
    pair's outlier verdict is the one of `corr`'s search, whose local medians saw the few pairs
    near the edges too.

    Parameters
    ----------
    corr : Correspondence
        From :func:`correspond` of `parent` and `child` with stride 1, a `border_px` no wider
        than this one, and `max_jump_px`.
    parent, child : Scan
        The scans `corr` matched (their ``xp``, ``yp`` give the jumps).
    border_px : int
        Erosion of both valid regions, px (as :func:`correspond`).
    stride : int
        Keep the parent pixels on every `stride`-th row and column.
    parent_valid, child_valid : (H, W) bool, optional
        The valid masks `corr`'s search used, when they are not :func:`valid_mask` of the
        scans (the fusion takes spikes out first).
    max_jump_px : float
        As in :func:`correspond`.

    Returns
    -------
    Correspondence
        With `stride`, its own ``dropped`` counts and its ``rejected`` pairs.

    References
    ----------
    Thesis, chapter four, "Merging in Projector Space": the merge error of sampled pixels
    (the thesis sampled every 5th and 20th), away from the edges of the valid regions.

    Examples
    --------
    >>> rr, cc = np.mgrid[0:20, 0:20].astype(np.float32)
    >>> one = np.ones((20, 20), np.float32)
    >>> a = Scan("a", np.stack([cc, rr, 0 * rr], -1), cc, rr, one, one, one, one > 0)
    >>> b = Scan("b", np.stack([cc, rr, 0 * rr + 0.01], -1), cc + 0.25, rr, one, one, one,
    ...          one > 0)
    >>> wide = correspond(a, b, border_px=1)
    >>> narrow = restrict_pairs(wide, a, b, border_px=3, stride=2)
    >>> narrow.n_pairs == correspond(a, b, border_px=3, stride=2).n_pairs
    True
    """
    border_px = as_int(border_px, "border_px", minimum=1)
    stride = as_int(stride, "stride", minimum=1)
    if corr.stride != 1 or corr.unpaired_rc is None:
        raise ValueError("corr: expected the result of a search with stride 1 (not restricted)")
    for name, scan, shape in (("parent", parent, corr.parent_shape),
                              ("child", child, corr.child_shape)):
        _check_scan(scan, name)
        if tuple(np.shape(scan.mask)) != tuple(shape):
            raise ValueError(f"{name}: shape {np.shape(scan.mask)} is not the correspondence's "
                             f"{tuple(shape)}")
    pv = valid_mask(parent) if parent_valid is None else np.asarray(parent_valid, dtype=bool)
    cv = valid_mask(child) if child_valid is None else np.asarray(child_valid, dtype=bool)
    parent_inner = _eroded(_without_jumps(parent, pv, max_jump_px), border_px)
    child_inner = _eroded(_without_jumps(child, cv, max_jump_px), border_px)
    if stride > 1:
        on_grid = np.zeros_like(parent_inner)
        on_grid[::stride, ::stride] = True
        parent_inner &= on_grid
        n_sampled = int(np.count_nonzero(pv[::stride, ::stride]))
    else:
        n_sampled = int(np.count_nonzero(pv))

    def at(image, rc):
        return image[rc[:, 0], rc[:, 1]] if rc.size else np.zeros(0, dtype=bool)

    dropped = dict.fromkeys(DROP_REASONS, 0)
    dropped["parent_border"] = n_sampled - int(np.count_nonzero(parent_inner))
    searched = at(parent_inner, corr.unpaired_rc)
    child_ok = at(child_inner, corr.unpaired_nearest)
    far = corr.unpaired_reason == 2
    dropped["child_border"] = int(np.count_nonzero(searched & ~(far & child_ok)))
    dropped["residual"] = int(np.count_nonzero(searched & far & child_ok))

    def narrowed(m: Correspondence, **extra) -> Correspondence:
        in_parent = at(parent_inner, m.parent_rc)
        keep = in_parent & at(child_inner, m.child_nearest)
        dropped["child_border"] += int(np.count_nonzero(in_parent & ~keep))
        index = np.flatnonzero(keep)
        arrays: dict[str, Any] = {
            k: _take_rows(np.ascontiguousarray(getattr(m, k)), index) for k in (
                "parent_rc", "child_nearest", "child_rc", "xyz_parent", "xyz_child",
                "residual_px")}
        if m.reason is not None:
            extra["reason"] = m.reason[index]
        return Correspondence(
            parent_name=m.parent_name, child_name=m.child_name, parent_shape=m.parent_shape,
            child_shape=m.child_shape, **arrays, n_sampled=n_sampled, stride=stride,
            pair_by=m.pair_by, **extra)

    rejected = None
    if corr.rejected is not None:
        rejected = narrowed(corr.rejected)
        for name in REJECT_REASONS:
            dropped[name] = int(np.count_nonzero(rejected.reason == name))
        rejected.dropped = {k: dropped[k] for k in REJECT_REASONS}
    return narrowed(corr, dropped=dropped, rejected=rejected)


def _relative_modulation(scan: Scan, valid: np.ndarray | None = None) -> np.ndarray:
    """Modulation over its median on the valid pixels, 0 where invalid (the quality image)."""
    valid = valid_mask(scan) if valid is None else valid
    return _relative_modulation_kernel(_float_image(scan.modulation),
                                       np.ascontiguousarray(valid, dtype=bool))


@numba.njit(cache=cache_enabled(), nogil=True)
def _nan_to_num(v):
    """np.nan_to_num of a float64."""
    if np.isnan(v):
        return 0.0
    if np.isinf(v):
        return 1.7976931348623157e308 if v > 0 else -1.7976931348623157e308
    return v


@numba.njit(cache=cache_enabled(), nogil=True)
def _relative_modulation_kernel(modulation, valid):
    """:func:`_relative_modulation`: ``m / median(m[valid])`` on the valid pixels, 0 elsewhere
    (all 0 unless the median is positive), m the modulation in float64 with NaN as 0."""
    h, w = valid.shape
    values = np.empty(h * w)
    n = 0
    for r in range(h):
        for c in range(w):
            if valid[r, c]:
                values[n] = _nan_to_num(np.float64(modulation[r, c]))
                n += 1
    median = _middle(values[:n]) if n else 0.0
    out = np.zeros((h, w))
    if median > 0:
        for r in range(h):
            for c in range(w):
                if valid[r, c]:
                    out[r, c] = _nan_to_num(np.float64(modulation[r, c])) / median
    return out


def _correspond(parent, child, *, stride, max_residual_px, border_px, max_jump_px, refine,
                method="grid", workers=-1, max_view_angle_deg=70.0, max_incidence_deg=65.0,
                min_relative_modulation=1 / 3, outlier_mm=0.025, outlier_mad=4.0,
                outlier_block_px=32, quality=None, cache=None,
                pair_by="auto") -> Correspondence:
    """:func:`correspond`; `quality` maps ``id(scan)`` to its ``[view cosine, incidence
    cosine, relative modulation]`` images (None: not yet computed; filled here), so a caller
    matching one scan many times computes them once. `cache` (:class:`CorrespondenceCache`)
    keeps those and the rest of what is derived from a scan (masks, search grid) across
    calls."""
    _check_scan(parent, "parent")
    _check_scan(child, "child")
    stride = as_int(stride, "stride", minimum=1)
    border_px = as_int(border_px, "border_px", minimum=1)
    outlier_block_px = as_int(outlier_block_px, "outlier_block_px", minimum=1)
    for value, label in ((max_residual_px, "max_residual_px"), (max_jump_px, "max_jump_px"),
                         (outlier_mad, "outlier_mad")):
        if not np.isfinite(value) or value <= 0:
            raise ValueError(f"{label}: expected a positive number, got {value}")
    for value, label in ((min_relative_modulation, "min_relative_modulation"),
                         (outlier_mm, "outlier_mm")):
        if value is not None and (not np.isfinite(value) or value < 0):
            raise ValueError(f"{label}: expected a non-negative number or None, got {value}")
    _check_angles(max_view_angle_deg, max_incidence_deg)
    if method not in ("grid", "kdtree", "bruteforce"):
        raise ValueError(f"method: expected 'grid', 'kdtree' or 'bruteforce', got {method!r}")
    pair_by = pairing_coordinates(parent, child, pair_by) if refine else "xpyp"
    if cache is None:
        cache = CorrespondenceCache()
    elif not isinstance(cache, CorrespondenceCache):
        raise TypeError(f"cache: expected a CorrespondenceCache, got {type(cache).__name__}")

    parent_images, child_images = cache._entry(parent), cache._entry(child)
    parent_valid, child_valid = parent_images.valid, child_images.valid
    if not child_valid.any():
        raise ValueError(f"child {child.name!r}: no valid pixels")
    # the sampled parent pixels not at the border: the inner region is within the valid one
    n_sampled, rows, cols = parent_images.inner_pixels(max_jump_px, border_px, stride)
    dropped = dict.fromkeys(DROP_REASONS, 0)
    dropped["parent_border"] = n_sampled - rows.size

    if method == "grid":
        grid = child_images.grid
        index, dist2 = grid.nearest_pixels(parent.xp, parent.yp, rows, cols, workers=workers)
        nr, nc = grid.rows[index], grid.cols[index]
    elif method == "kdtree":
        nr, nc, dist2 = nearest_kdtree(parent, child, rows, cols, workers=workers)
    else:
        nr, nc, dist2 = nearest_bruteforce(parent, child, rows, cols)

    child_inner = child_images.inner(max_jump_px, border_px)
    if refine:  # one compiled pass: border test, refinement, residual test, world points
        kernel_images = (child_inner, _float_image(child.xp), _float_image(child.yp),
                         _float_image(child.xyz), _float_image(parent.xp),
                         _float_image(parent.yp), _float_image(parent.xyz))
        n = rows.size
        out = {"parent_rc": np.empty((n, 2), dtype=np.intp),
               "child_nearest": np.empty((n, 2), dtype=np.intp),
               "child_rc": np.empty((n, 2)), "xyz_parent": np.empty((n, 3)),
               "xyz_child": np.empty((n, 3)), "residual_px": np.empty(n),
               "distance": np.empty(n)}
        buffers = tuple(out.values())
        drop_code = np.empty(n, dtype=np.int8)
        counts = _in_chunks(
            lambda a, b: _pairs_kernel(rows[a:b], cols[a:b], nr[a:b], nc[a:b], *kernel_images,
                                       _NEWTON_STEPS, _MAX_SHIFT_PX, float(max_residual_px),
                                       _ALONG[pair_by],
                                       *(v[a:b] for v in (*buffers, drop_code))), n, workers)
        # the chunks' pairs, moved down to follow each other (copies only when threaded)
        bounds = np.linspace(0, n, len(counts) + 1).astype(np.int64)
        k = 0
        for start, (found, _, _) in zip(bounds[:-1], counts, strict=True):
            if start > k:
                for v in buffers:
                    v[k:k + found] = v[start:start + found]
            k += found
        pairs = {name: v[:k] for name, v in out.items()}  # views; copied by `subset` below
        distance = pairs.pop("distance")
        dropped["child_border"] = sum(c[1] for c in counts)
        dropped["residual"] = sum(c[2] for c in counts)
    else:
        residual = np.sqrt(dist2)
        drop_code = np.where(child_inner[nr, nc], np.where(residual <= max_residual_px, 0, 2),
                        1).astype(np.int8)
        good = drop_code == 0
        dropped["child_border"] = int(np.count_nonzero(drop_code == 1))
        dropped["residual"] = int(np.count_nonzero(drop_code == 2))
        xyz_parent = np.asarray(parent.xyz)[rows[good], cols[good]].astype(np.float64)
        xyz_child = np.asarray(child.xyz)[nr[good], nc[good]].astype(np.float64)
        pairs = {
            "parent_rc": np.stack([rows[good], cols[good]], axis=-1),
            "child_nearest": np.stack([nr[good], nc[good]], axis=-1),
            "child_rc": np.stack([nr[good], nc[good]], axis=-1).astype(np.float64),
            "xyz_parent": xyz_parent,
            "xyz_child": xyz_child,
            "residual_px": residual[good],
        }
        distance = None
    # the searched pixels left without a pair, for restrict_pairs: parent pixel, nearest child
    # pixel, and why (1: child_border, 2: residual)
    lone = np.flatnonzero(drop_code)
    unpaired = {"unpaired_rc": np.stack([rows[lone], cols[lone]], axis=-1),
                "unpaired_nearest": np.stack([nr[lone], nc[lone]], axis=-1),
                "unpaired_reason": drop_code[lone]}

    return _tested(parent, child, pairs, distance, dropped, unpaired, n_sampled=n_sampled,
                   stride=stride, shapes=(parent_valid.shape, child_valid.shape),
                   max_view_angle_deg=max_view_angle_deg, max_incidence_deg=max_incidence_deg,
                   min_relative_modulation=min_relative_modulation, outlier_mm=outlier_mm,
                   outlier_mad=outlier_mad, outlier_block_px=outlier_block_px, quality=quality,
                   cache=cache, pair_by=pair_by)
