"""Correspondence between cameras in projector space, and the merge error (thesis chapter four).

All cameras of the scanner look at one projector, so a surface point seen by two cameras has the
same projector coordinates ``(xp, yp)`` in both scans. For every (sampled) pixel of a *parent*
scan, :func:`correspond` finds the *child* pixel with the nearest ``(xp, yp)`` (a k-d tree over the
child's valid pixels, instead of the appendix's ``closest_proj_point`` loop over the whole child
frame), refines it to the sub-pixel position where the child's interpolated projector coordinates
equal the parent's, and interpolates the child's world point there. The world distance between
the two points of a pair is the merge error (thesis "Merging in Projector Space", Fig. 32–35).

A nearest neighbour always exists, even where the child never saw the point, so the overlap is
decided, not assumed: a pair is dropped when the parent pixel lies at the border of the parent's
valid region, when the child position lies at the border of the child's valid region, or when
the projector-coordinate residual after refinement exceeds the decoding noise. The counts per
reason are kept in :attr:`Correspondence.dropped`.

A pair that is found may still be wrong: at a grazing view or a shadow border a camera's
projector coordinates are biased (blur spreads a pixel over much surface, and the fringe signal
is weak), which shifts its point along the surface. Such pairs are *rejected* (kept apart in
:attr:`Correspondence.rejected`, with the reason): either camera views the point beyond
`max_view_angle_deg`, either camera's fringe modulation there is below a fraction of its
median, or the pair's distance is an outlier among the pairs around it (above their median by
more than ``max(outlier_mm, outlier_mad × MAD)``). The statistics report the merge error of the
kept pairs and of all pairs before rejection.

:func:`nearest_bruteforce` is the appendix's search (vectorised over the child for each parent
pixel), kept as the reference the k-d tree path is tested against.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np
import scipy.ndimage
import scipy.spatial

from .._interpolate import bilinear
from .._numba_cache import cache_enabled
from .._validation import as_int
from ..reconstruction import Scan
from .statistics import local_outliers, merge_statistics

__all__ = [
    "DROP_REASONS",
    "REJECT_REASONS",
    "Correspondence",
    "correspond",
    "grid_normals",
    "nearest_bruteforce",
    "nearest_kdtree",
    "refine_subpixel",
    "sample_pixels",
    "valid_mask",
    "view_cosine",
]

#: Reasons a pair found in projector space is rejected as unreliable, in the order tested
#: (:func:`correspond`): a grazing view, a weak fringe signal, a distance far above its
#: neighbours'. Rejected pairs are kept apart in :attr:`Correspondence.rejected`.
REJECT_REASONS = ("view_angle", "modulation", "outlier")
#: Reasons a sampled parent pixel gets no (kept) correspondence, in the order they are tested.
DROP_REASONS = ("parent_border", "child_border", "residual", *REJECT_REASONS)

_MAX_SHIFT_PX = 1.5  # a refined position further than this from the nearest pixel is not trusted
_NEWTON_STEPS = 2  # Newton steps on the bilinear model after the affine step


# -- input checks ----------------------------------------------------------------------------
def _check_scan(scan, name: str) -> Scan:
    if not isinstance(scan, Scan):
        raise TypeError(
            f"{name}: expected a nail2nail.reconstruction.Scan, got {type(scan).__name__}"
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
    return (
        np.asarray(scan.mask, dtype=bool)
        & np.isfinite(scan.xyz).all(axis=-1)
        & np.isfinite(scan.xp)
        & np.isfinite(scan.yp)
    )


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
    for f in (scan.xp, scan.yp):
        f = np.asarray(f, dtype=np.float32)
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
            out[tuple(inner)] &= ~jump
    return out


def _eroded(mask: np.ndarray, border_px: int) -> np.ndarray:
    if border_px == 0:
        return mask
    return scipy.ndimage.binary_erosion(
        mask, structure=np.ones((3, 3), bool), iterations=border_px, border_value=0
    )


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

    Examples
    --------
    >>> rr, cc = np.mgrid[0:3, 0:4].astype(float)
    >>> n = grid_normals(np.stack([cc, -rr, 0 * cc], -1))
    >>> np.abs(n[1, 1]).tolist()
    [0.0, 0.0, 1.0]
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.ndim != 3 or xyz.shape[2] != 3:
        raise ValueError(f"xyz: expected shape (H, W, 3), got {xyz.shape}")

    def derivative(axis: int) -> np.ndarray:
        d = np.full_like(xyz, np.nan)
        n = xyz.shape[axis]
        sl = [slice(None)] * 3

        def take(start, stop):
            s = list(sl)
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
        If `scan` has no ``camera_center``.
    """
    _check_scan(scan, "scan")
    if scan.camera_center is None:
        raise ValueError(f"scan {scan.name!r}: camera_center is needed for the viewing angle")
    valid = valid_mask(scan)
    if normals is None:
        normals = grid_normals(scan.xyz, camera_center=scan.camera_center)
    normals = np.asarray(normals, dtype=np.float64)
    view = np.asarray(scan.camera_center, dtype=np.float64) - np.asarray(scan.xyz, np.float64)
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


# cache on disk unless no directory at all can hold numba's cache (nail2nail._numba_cache)
@numba.njit(cache=cache_enabled(), nogil=True, error_model="numpy")
def _refine_kernel(xp, yp, xyz, target_xp, target_yp, rows, cols, iterations, max_shift):
    """Compiled :func:`refine_subpixel` plus bilinear interpolation of ``xyz`` (same arithmetic)."""
    n = rows.size
    h, w = xp.shape
    out_r = np.empty(n)
    out_c = np.empty(n)
    out_res = np.empty(n)
    out_xyz = np.empty((n, 3))
    for i in range(n):
        r0, c0 = rows[i], cols[i]
        tx, ty = target_xp[i], target_yp[i]
        fx, fy = xp[r0, c0], yp[r0, c0]
        ax = 0.5 * (xp[r0, c0 + 1] - xp[r0, c0 - 1])
        ay = 0.5 * (yp[r0, c0 + 1] - yp[r0, c0 - 1])
        bx = 0.5 * (xp[r0 + 1, c0] - xp[r0 - 1, c0])
        by = 0.5 * (yp[r0 + 1, c0] - yp[r0 - 1, c0])
        r, c = float(r0), float(c0)
        bad = False
        for k in range(iterations + 2):
            if k > 0:
                ri = min(max(int(np.floor(r)), 0), h - 2)
                ci = min(max(int(np.floor(c)), 0), w - 2)
                fr, fc = r - ri, c - ci
                x00, x01, x10, x11 = xp[ri, ci], xp[ri, ci + 1], xp[ri + 1, ci], xp[ri + 1, ci + 1]
                y00, y01, y10, y11 = yp[ri, ci], yp[ri, ci + 1], yp[ri + 1, ci], yp[ri + 1, ci + 1]
                xt = x00 + (x01 - x00) * fc
                xb = x10 + (x11 - x10) * fc
                yt = y00 + (y01 - y00) * fc
                yb = y10 + (y11 - y10) * fc
                fx = xt + (xb - xt) * fr
                fy = yt + (yb - yt) * fr
                if k == iterations + 1:
                    break
                ax = (x01 - x00) * (1 - fr) + (x11 - x10) * fr
                ay = (y01 - y00) * (1 - fr) + (y11 - y10) * fr
                bx = xb - xt
                by = yb - yt
            ex, ey = tx - fx, ty - fy
            det = ax * by - bx * ay
            step_c = (by * ex - bx * ey) / det
            step_r = (ax * ey - ay * ex) / det
            if not (np.isfinite(step_r) and np.isfinite(step_c)):
                bad = True
                break
            r = min(max(r + step_r, r0 - max_shift), r0 + max_shift)
            c = min(max(c + step_c, c0 - max_shift), c0 + max_shift)
            r = min(max(r, 0.0), h - 1.0)
            c = min(max(c, 0.0), w - 1.0)
        res = np.hypot(fx - tx, fy - ty)
        if bad or not np.isfinite(res):
            out_r[i] = np.nan
            out_c[i] = np.nan
            out_res[i] = np.nan
            out_xyz[i] = np.nan
            continue
        out_r[i], out_c[i], out_res[i] = r, c, res
        ri = min(max(int(np.floor(r)), 0), h - 2)
        ci = min(max(int(np.floor(c)), 0), w - 2)
        fr, fc = r - ri, c - ci
        for j in range(3):
            top = xyz[ri, ci, j] + (xyz[ri, ci + 1, j] - xyz[ri, ci, j]) * fc
            bottom = xyz[ri + 1, ci, j] + (xyz[ri + 1, ci + 1, j] - xyz[ri + 1, ci, j]) * fc
            out_xyz[i, j] = top + (bottom - top) * fr
    return out_r, out_c, out_res, out_xyz


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
            stride=self.stride,
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
            "sampled": self.n_sampled,
            "pairs": self.n_pairs,
            "dropped": dict(self.dropped),
            "rejected": {k: int(self.dropped.get(k, 0)) for k in REJECT_REASONS},
            **stats,
            "before_rejection": {"pairs": before.n_pairs,
                                 **merge_statistics(before.distance_mm)},
        }


def correspond(
    parent: Scan,
    child: Scan,
    *,
    stride: int = 1,
    max_residual_px: float = 0.5,
    border_px: int = 2,
    max_jump_px: float = 2.0,
    refine: bool = True,
    method: str = "kdtree",
    workers: int = -1,
    max_view_angle_deg: float | None = 70.0,
    min_relative_modulation: float | None = 1 / 3,
    outlier_mm: float | None = 0.025,
    outlier_mad: float = 4.0,
    outlier_block_px: int = 32,
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
    :attr:`Correspondence.rejected`): ``"view_angle"``, either camera views the point at more
    than `max_view_angle_deg` from its normal (:func:`view_cosine`, smoothed over 2 px; needs
    the scans' ``camera_center``); ``"modulation"``, either camera's fringe modulation there is
    below `min_relative_modulation` × its median over its valid pixels (the phase noise grows as
    1 / modulation); ``"outlier"``, the pair's distance is an outlier among its neighbours'
    (:func:`local_outliers` with `outlier_block_px`, `outlier_mm`, `outlier_mad`). ``None``
    skips a test.

    Parameters
    ----------
    parent, child : Scan
    stride : int
        Sample every `stride`-th row and column of the parent (the thesis used 5 and 20).
    max_residual_px : float
        Largest projector-coordinate residual of a kept pair, panel px. Without `refine` the
        residual is the distance to the nearest child pixel.
    border_px : int
        Erosion of both valid regions, px (≥ 1: refinement needs the 3 × 3 neighbourhood).
    max_jump_px : float
        Second difference of ``xp`` or ``yp`` between neighbouring pixels above which (and above
        the local slope) a pixel is a discontinuity, panel px.
    refine : bool
        Sub-pixel refinement; ``False`` takes the nearest child pixel as the appendix.
    method : {"kdtree", "bruteforce"}
        Nearest-neighbour search; ``"bruteforce"`` is the appendix's, for small inputs only.
    workers : int
        Threads for the k-d tree query (``-1``: all cores).
    max_view_angle_deg : float or None
        Largest viewing angle (between the normal and the ray to the camera) of a kept pair in
        either camera, degrees.
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

    Returns
    -------
    Correspondence

    Raises
    ------
    TypeError
        If a scan is not a :class:`~nail2nail.reconstruction.Scan`.
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
        max_view_angle_deg=max_view_angle_deg, min_relative_modulation=min_relative_modulation,
        outlier_mm=outlier_mm, outlier_mad=outlier_mad, outlier_block_px=outlier_block_px,
    )


def _relative_modulation(scan: Scan) -> np.ndarray:
    """Modulation over its median on the valid pixels, 0 where invalid (the quality image)."""
    valid = valid_mask(scan)
    m = np.nan_to_num(np.asarray(scan.modulation, dtype=np.float64))
    median = float(np.median(m[valid])) if valid.any() else 0.0
    return np.where(valid, m / median, 0.0) if median > 0 else np.zeros_like(m)


def _correspond(parent, child, *, stride, max_residual_px, border_px, max_jump_px, refine,
                method, workers, max_view_angle_deg, min_relative_modulation, outlier_mm,
                outlier_mad, outlier_block_px, quality=None) -> Correspondence:
    """:func:`correspond`; `quality` maps ``id(scan)`` to its ``[view cosine, relative
    modulation]`` images, so a caller matching one scan many times computes them once."""
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
    if max_view_angle_deg is not None and not 0 < max_view_angle_deg <= 90:
        raise ValueError(f"max_view_angle_deg: expected a number in (0, 90] or None, "
                         f"got {max_view_angle_deg}")
    if method not in ("kdtree", "bruteforce"):
        raise ValueError(f"method: expected 'kdtree' or 'bruteforce', got {method!r}")

    parent_valid = valid_mask(parent)
    child_valid = valid_mask(child)
    if not child_valid.any():
        raise ValueError(f"child {child.name!r}: no valid pixels")
    rows, cols = sample_pixels(parent_valid, stride=stride)
    n_sampled = rows.size
    dropped = dict.fromkeys(DROP_REASONS, 0)

    keep = _eroded(_without_jumps(parent, parent_valid, max_jump_px), border_px)[rows, cols]
    dropped["parent_border"] = int(np.count_nonzero(~keep))
    rows, cols = rows[keep], cols[keep]

    search = nearest_kdtree if method == "kdtree" else nearest_bruteforce
    kwargs = {"workers": workers} if method == "kdtree" else {}
    nr, nc, dist2 = search(parent, child, rows, cols, **kwargs)

    child_inner = _eroded(_without_jumps(child, child_valid, max_jump_px), border_px)
    keep = child_inner[nr, nc]
    rows, cols, nr, nc, dist2 = rows[keep], cols[keep], nr[keep], nc[keep], dist2[keep]
    if refine:
        sub_r, sub_c, residual, xyz_child = _refine_kernel(
            np.ascontiguousarray(child.xp, dtype=np.float64),
            np.ascontiguousarray(child.yp, dtype=np.float64),
            np.ascontiguousarray(child.xyz, dtype=np.float64),
            parent.xp[rows, cols].astype(np.float64),
            parent.yp[rows, cols].astype(np.float64),
            nr, nc, _NEWTON_STEPS, _MAX_SHIFT_PX,
        )
        finite = np.isfinite(residual) & np.isfinite(xyz_child).all(axis=-1)
    else:
        sub_r, sub_c, residual = nr.astype(np.float64), nc.astype(np.float64), np.sqrt(dist2)
        xyz_child = np.asarray(child.xyz, dtype=np.float64)[nr, nc]
        finite = np.ones(nr.size, dtype=bool)
    dropped["child_border"] = int(np.count_nonzero(~keep) + np.count_nonzero(~finite))

    with np.errstate(invalid="ignore"):
        good = finite & (residual <= max_residual_px)
    dropped["residual"] = int(np.count_nonzero(finite & ~good))
    xyz_parent = np.asarray(parent.xyz, dtype=np.float64)[rows[good], cols[good]]
    pairs = {
        "parent_rc": np.stack([rows[good], cols[good]], axis=-1),
        "child_nearest": np.stack([nr[good], nc[good]], axis=-1),
        "child_rc": np.stack([sub_r[good], sub_c[good]], axis=-1),
        "xyz_parent": xyz_parent,
        "xyz_child": xyz_child[good],
        "residual_px": residual[good],
    }

    # rejection of unreliable pairs, in the order of REJECT_REASONS
    n = pairs["parent_rc"].shape[0]
    reason = np.full(n, -1, dtype=np.int8)
    pr, pc = pairs["parent_rc"].T
    cr, cc = pairs["child_rc"].T
    tests = any(v is not None for v in (max_view_angle_deg, min_relative_modulation, outlier_mm))
    if quality is None:
        quality = {}

    def images(scan, k):
        cache = quality.setdefault(id(scan), [None, None])
        if cache[k] is None:
            cache[k] = view_cosine(scan, smooth_px=2.0) if k == 0 else _relative_modulation(scan)
        return cache[k]

    for code, limit in ((0, max_view_angle_deg), (1, min_relative_modulation)):
        if limit is None or n == 0:
            continue
        threshold = np.cos(np.radians(limit)) if code == 0 else limit
        ok = np.ones(n, dtype=bool)
        for scan, (r, c) in ((parent, (pr, pc)), (child, (cr, cc))):
            if code == 0 and scan.camera_center is None:
                continue
            value = bilinear(images(scan, code), r.astype(np.float64), c.astype(np.float64))[0]
            ok &= value >= threshold
        reason[(reason < 0) & ~ok] = code
    if outlier_mm is not None and n:
        live = reason < 0
        distance = np.linalg.norm(pairs["xyz_parent"] - pairs["xyz_child"], axis=-1)
        out = local_outliers(pr[live], pc[live], distance[live], block_px=outlier_block_px,
                             floor_mm=outlier_mm, k_mad=outlier_mad)
        reason[np.flatnonzero(live)[out]] = 2
    for code, name in enumerate(REJECT_REASONS):
        dropped[name] = int(np.count_nonzero(reason == code))

    def subset(sel, **extra):
        return Correspondence(
            parent_name=str(parent.name), child_name=str(child.name),
            parent_shape=tuple(parent_valid.shape), child_shape=tuple(child_valid.shape),
            **{k: v[sel] for k, v in pairs.items()}, n_sampled=int(n_sampled), stride=stride,
            **extra)

    rejected = None
    if tests:
        bad = reason >= 0
        rejected = subset(bad, reason=np.asarray(REJECT_REASONS)[reason[bad]],
                          dropped={k: dropped[k] for k in REJECT_REASONS})
    return subset(reason < 0, dropped=dropped, rejected=rejected)
