"""Projector radial distortion: the thesis's model (eq. 3.34), its look-up-table correction
(appendix ``distortion2dlut`` / ``distortionradial``) and its estimation (eq. 3.17–3.42).

Model (``docs/conventions.md``): a panel pixel at radius ``r`` from the optical centre ``c``
appears where an ideal pinhole projector puts radius ``r + ρ³ r³``.

Two ways to correct it:

* **Pre-distorted patterns** (the thesis's way): :func:`distortion_lut` + :func:`apply_lut`
  (nearest neighbour, exactly the appendix C++) or :func:`predistort_pattern` (bilinear). Panel
  pixel ``p`` then shows the original pattern's value at ``ideal_from_panel(p)``, so the decoded
  projector coordinates are ideal coordinates.
* **Compensation in the model**: project plain patterns, decode panel coordinates and convert
  them with :func:`ideal_from_decoded` before reconstruction.

Estimation: :func:`estimate_distortion_thesis` (eq. 3.17–3.42, as written) and
:func:`estimate_distortion` (joint non-linear least squares of centre, ρ and a plane homography).
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage, optimize

from nail2nail._uncertainty import gauss_newton_std
from nail2nail._validation import as_float_array, as_points
from nail2nail.io._json import read_json

__all__ = [
    "PLANE_RMS_LIMIT_PX",
    "THESIS_CENTER",
    "THESIS_RHO",
    "CameraDistortionEstimate",
    "DistortionFit",
    "DistortionReport",
    "ProjectorDistortion",
    "ThesisDistortionEstimate",
    "apply_lut",
    "as_projector_distortion",
    "check_plane",
    "distortion_lut",
    "estimate_distortion",
    "estimate_distortion_thesis",
    "estimate_from_decoded",
    "grid_from_decoded",
    "ideal_from_decoded",
    "ideal_from_panel",
    "load_projector_distortion",
    "panel_from_ideal",
    "points_from_decoded",
    "predistort_pattern",
]

#: Optical centre of the thesis's projector, panel px (chapter three).
THESIS_CENTER = (640.0, 1000.0)
#: Radial distortion parameter of the thesis's projector (chapter three).
THESIS_RHO = -0.004


def ideal_from_panel(xy_panel, center=THESIS_CENTER, rho: float = THESIS_RHO) -> np.ndarray:
    """Ideal (pinhole) coordinates of panel coordinates: ``r ↦ r + ρ³ r³`` (eq. 3.34).

    Parameters
    ----------
    xy_panel : (..., 2) float
        Panel coordinates, projector px.
    center : (2,) float
        Optical centre ``(x, y)``, projector px.
    rho : float
        Distortion parameter ρ; negative is barrel.

    Returns
    -------
    (..., 2) float64
        Ideal coordinates, projector px.

    Examples
    --------
    >>> ideal_from_panel([[640.0, 0.0]]).round(3).tolist()
    [[640.0, 64.0]]
    """
    xy = as_float_array(xy_panel, "xy_panel")
    c = np.asarray(center, dtype=float)
    d = xy - c
    r2 = np.sum(d * d, axis=-1, keepdims=True)
    return c + d * (1.0 + rho**3 * r2)


def panel_from_ideal(xy_ideal, center=THESIS_CENTER, rho: float = THESIS_RHO) -> np.ndarray:
    """Inverse of :func:`ideal_from_panel`: solve ``r + ρ³ r³ = s`` for ``r`` (Newton).

    The cubic is monotonic for ``r < 1 / (√3 |ρ|^{3/2})`` (about 2280 px for the thesis's ρ),
    which covers the panel; radii beyond the turning point have no inverse and give NaN.

    Examples
    --------
    >>> xy = np.array([[100.0, 20.0], [1200.0, 900.0]])
    >>> bool(np.allclose(ideal_from_panel(panel_from_ideal(xy)), xy, atol=1e-9))
    True
    """
    xy = as_float_array(xy_ideal, "xy_ideal")
    c = np.asarray(center, dtype=float)
    d = xy - c
    s = np.sqrt(np.sum(d * d, axis=-1))
    k = rho**3
    if k == 0:
        return xy.astype(float, copy=True)
    r = s.copy()
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        for _ in range(30):
            f = r + k * r**3 - s
            r = r - f / (1 + 3 * k * r**2)
        if k < 0:
            r_max = 1.0 / np.sqrt(-3 * k)
            # r_max + k r_max³ = (2/3) r_max, written so that it cannot overflow
            r = np.where((r > r_max) | (s > 2.0 * r_max / 3.0), np.nan, r)
        scale = np.where(s > 0, r / np.where(s > 0, s, 1), 1.0)
    return c + d * scale[..., None]


def ideal_from_decoded(xp, yp, center=THESIS_CENTER, rho: float = THESIS_RHO):
    """Convert decoded panel coordinate maps to ideal coordinates (model compensation).

    This is :func:`ideal_from_panel` on the stacked maps: the alternative to pre-distorted
    patterns, for reconstruction with the distortion inside the model. Use it only on
    coordinates decoded from *plain* (not LUT-corrected) patterns: those from pre-distorted
    patterns are already ideal (``docs/conventions.md``).

    Parameters
    ----------
    xp, yp : (...) float
        Decoded panel coordinates, projector px, same shape; ``NaN`` (no value) passes through.
    center : (2,) float
        Optical centre ``(x, y)``, panel px.
    rho : float
        Distortion parameter ρ (eq. 3.34).

    Returns
    -------
    xp_ideal, yp_ideal : (...) float
        Ideal coordinates, in the input's float dtype (float64 for integer input).

    Raises
    ------
    ValueError
        If `xp` and `yp` differ in shape.

    Examples
    --------
    >>> xi, yi = ideal_from_decoded(np.array([640.0, np.nan]), np.array([0.0, 5.0]))
    >>> xi.tolist(), yi.round(3).tolist()
    ([640.0, nan], [64.0, nan])
    """
    xp_arr = as_float_array(xp, "xp", dtype=None)
    yp_arr = as_float_array(yp, "yp", dtype=None)
    if xp_arr.shape != yp_arr.shape:
        raise ValueError(f"xp, yp: shapes differ, {xp_arr.shape} and {yp_arr.shape}")
    dtype = np.result_type(xp_arr.dtype, yp_arr.dtype)
    ideal = ideal_from_panel(np.stack([xp_arr, yp_arr], axis=-1), center, rho)
    return ideal[..., 0].astype(dtype), ideal[..., 1].astype(dtype)


# --------------------------------------------------------------------------------------------
# Look-up-table correction (appendix: distortion2dlut, distortionradial,
# bmpvolumedistortioncorrect)
# --------------------------------------------------------------------------------------------


def _check_size(size) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in size)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"size: expected (width, height) integers, got {size!r}") from exc
    if width < 1 or height < 1 or (width, height) != tuple(size):
        raise ValueError(f"size: expected positive integers (width, height), got {size!r}")
    return width, height


def _check_params(center, rho) -> tuple[np.ndarray, float]:
    c = as_float_array(center, "center")
    if c.shape != (2,) or not np.all(np.isfinite(c)):
        raise ValueError(f"center: expected finite (x, y), got shape {c.shape}")
    if not isinstance(rho, int | float | np.floating | np.integer) or not math.isfinite(rho):
        raise TypeError(f"rho: expected a finite real number, got {rho!r}")
    return c, float(rho)


def distortion_lut(size=(1280, 1040), center=THESIS_CENTER, rho: float = THESIS_RHO) -> np.ndarray:
    """Nearest-neighbour pre-distortion look-up table, exactly as the appendix ``distortion2dlut``.

    For output panel pixel ``(n, m)`` at radius ``r₂`` and angle ``θ`` from the centre, the
    source pixel is at radius ``r₁ = r₂ + β r₂³`` (``β = ρ³``, the main program's
    ``beta = -0.004; beta = beta*beta*beta``), rounded like the C++ ``(long)(y + ycenter + 0.5)``
    (truncation towards zero, so ``-0.9`` rounds to ``0``); ``-1`` marks a source outside the
    panel. Since ``r₂ + β r₂³`` is :func:`ideal_from_panel`, the corrected pattern shows every
    ideal coordinate the original pattern's value there, within half a pixel (plus the
    float32 rounding of the C++ ``float xcenter`` and ``(float)(r2*r2*r2)``, which are kept).

    Parameters
    ----------
    size : (2,) int
        Panel ``(width, height)``, px.
    center : (2,) float
        Optical centre ``(x, y)``, panel px (the C++ passes it both as double and as float).
    rho : float
        Distortion parameter ρ (eq. 3.34); the table uses ``β = ρ³``.

    Returns
    -------
    lut : (height, width, 2) int64
        Source pixel ``(x, y) = (column, row)`` for every output pixel, ``-1`` outside.

    Examples
    --------
    >>> lut = distortion_lut((1280, 1040))
    >>> lut.shape, lut[0, 640].tolist(), lut[1000, 640].tolist()
    ((1040, 1280, 2), [640, 64], [640, 1000])
    """
    width, height = _check_size(size)
    c, rho = _check_params(center, rho)
    beta = rho * rho * rho  # the main program: beta = -beta; beta = beta*beta*beta
    xc2, yc2 = float(c[0]), float(c[1])  # double xc2center, yc2center
    xcf, ycf = float(np.float32(c[0])), float(np.float32(c[1]))  # float xcenter, ycenter
    n = np.arange(width, dtype=np.float64)[None, :]
    m = np.arange(height, dtype=np.float64)[:, None]
    dx = n - xc2
    dy = m - yc2
    r2 = np.sqrt(dx * dx + dy * dy)
    theta2 = np.arctan2(dy, dx)
    ftemp = (r2 * r2 * r2).astype(np.float32).astype(np.float64)  # ftemp = (float)(r2*r2*r2)
    r1 = r2 + beta * ftemp
    x = r1 * np.cos(theta2)
    y = r1 * np.sin(theta2)
    m1 = np.trunc(y + ycf + 0.5)  # (long) truncates towards zero
    n1 = np.trunc(x + xcf + 0.5)
    inside = (m1 >= 0) & (m1 < height) & (n1 >= 0) & (n1 < width)
    lut = np.full((height, width, 2), -1, dtype=np.int64)
    lut[..., 0] = np.where(inside, n1, -1)
    lut[..., 1] = np.where(inside, m1, -1)
    return lut


def apply_lut(image_or_stack, lut, *, fill=0) -> np.ndarray:
    """Apply a look-up table to an image or a stack, as the appendix ``distortionradial``.

    ``out[..., m, n] = in[..., lut[m, n, 1], lut[m, n, 0]]``; pixels whose entry is ``-1`` get
    `fill` (the C++ writes black).

    Parameters
    ----------
    image_or_stack : (..., H, W) array
        Pattern(s), any dtype; the dtype is kept.
    lut : (H, W, 2) int
        From :func:`distortion_lut`.
    fill : scalar
        Value for pixels with no source.

    Returns
    -------
    (..., H, W) array
        Corrected pattern(s).

    Raises
    ------
    ValueError
        If the image shape does not match the table, or the table holds out-of-range indices.

    Examples
    --------
    >>> lut = distortion_lut((8, 6), center=(4, 3), rho=0.0)
    >>> img = np.arange(48).reshape(6, 8)
    >>> bool(np.array_equal(apply_lut(img, lut), img))
    True
    """
    images = np.asarray(image_or_stack)
    table = np.asarray(lut)
    if table.ndim != 3 or table.shape[2] != 2 or not np.issubdtype(table.dtype, np.integer):
        raise ValueError(
            f"lut: expected an (H, W, 2) integer array, got {table.dtype} {table.shape}"
        )
    if images.ndim < 2 or images.shape[-2:] != table.shape[:2]:
        raise ValueError(
            f"image_or_stack: expected shape (..., {table.shape[0]}, {table.shape[1]}) "
            f"to match lut, got {images.shape}"
        )
    height, width = table.shape[:2]
    xs, ys = table[..., 0], table[..., 1]
    valid = (xs >= 0) & (ys >= 0)
    if np.any(valid & ((xs >= width) | (ys >= height))):
        raise ValueError("lut: holds source indices outside the image")
    out = images[..., np.where(valid, ys, 0), np.where(valid, xs, 0)]
    out[..., ~valid] = fill
    return out


def predistort_pattern(pattern, center=THESIS_CENTER, rho: float = THESIS_RHO, *, order: int = 1,
                       fill=0) -> np.ndarray:
    """Pre-distort pattern(s) so that each ideal coordinate shows the pattern's value there.

    Panel pixel ``p`` takes the pattern interpolated at ``ideal_from_panel(p)`` (bilinear for
    ``order=1``, cubic spline for ``order=3``); ``order=0`` is the appendix's nearest-neighbour
    table (:func:`distortion_lut` + :func:`apply_lut`). Sources outside the panel's extent
    ``[-½, W-½] × [-½, H-½]`` get `fill`; within half a pixel of the border, the edge pixel's
    value is used (no extrapolation).

    Parameters
    ----------
    pattern : (..., H, W) array
        Pattern(s) on a ``W × H`` panel. Integer patterns are rounded and clipped to their dtype.
    center : (2,) float
        Optical centre, panel px.
    rho : float
        Distortion parameter ρ (eq. 3.34).
    order : {0, 1, 3}
        Interpolation order.
    fill : scalar
        Value where the source falls outside the panel.

    Returns
    -------
    (..., H, W) array, same dtype as `pattern`.

    Examples
    --------
    >>> ramp = np.tile(np.arange(64, dtype=float), (48, 1))
    >>> out = predistort_pattern(ramp, center=(32, 40), rho=-0.02)
    >>> float(out[40, 32]), round(float(out[40, 10]), 2)
    (32.0, 10.09)
    """
    images = np.asarray(pattern)
    if images.ndim < 2:
        raise ValueError(f"pattern: expected shape (..., H, W), got {images.shape}")
    if order not in (0, 1, 3):
        raise ValueError(f"order: expected 0, 1 or 3, got {order!r}")
    height, width = images.shape[-2:]
    if order == 0:
        return apply_lut(images, distortion_lut((width, height), center, rho), fill=fill)
    c, rho = _check_params(center, rho)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
    ideal = ideal_from_panel(np.stack([xx, yy], axis=-1), c, rho)
    coords = np.stack([ideal[..., 1], ideal[..., 0]])
    inside = (
        (ideal[..., 0] >= -0.5) & (ideal[..., 0] <= width - 0.5)
        & (ideal[..., 1] >= -0.5) & (ideal[..., 1] <= height - 0.5)
    )
    flat = images.reshape(-1, height, width)
    out = np.empty(flat.shape, dtype=images.dtype)
    for i, frame in enumerate(flat):  # a loop over frames, not pixels
        values = ndimage.map_coordinates(frame.astype(np.float64), coords, order=order,
                                         mode="nearest")
        if np.issubdtype(images.dtype, np.integer):
            info = np.iinfo(images.dtype)
            values = np.clip(np.rint(values), info.min, info.max)
        values[~inside] = fill
        out[i] = values
    return out.reshape(images.shape)


# --------------------------------------------------------------------------------------------
# Estimation, as the thesis writes it (eq. 3.17–3.42)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ThesisDistortionEstimate:
    """Result of :func:`estimate_distortion_thesis`.

    Attributes
    ----------
    center : (2,) tuple of float
        Optical centre in distorted (panel) coordinates ``(x_cc, y_cc)``, eq. 3.32–3.33.
    rho : float
        Distortion parameter ρ, eq. 3.42 (``ρ = ∛(ρ³)``).
    plane_center : (2,) tuple of float
        Optical centre in undistorted (plane) coordinates ``(x_wc, y_wc)``, eq. 3.30–3.31.
    coeffs_x, coeffs_y : (6,) ndarray
        ``A_x``, ``A_y`` of eq. 3.19–3.22.
    coeffs_r : (2,) ndarray
        ``A_r`` of eq. 3.36–3.37.
    """

    center: tuple[float, float]
    rho: float
    plane_center: tuple[float, float]
    coeffs_x: np.ndarray = field(repr=False)
    coeffs_y: np.ndarray = field(repr=False)
    coeffs_r: np.ndarray = field(repr=False)


def _lstsq(design: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Least-squares solution of ``design @ a ≈ target`` with column equilibration.

    Same solution as the normal equations of eq. 3.21–3.22 (``A = x Yᵀ (Y Yᵀ)⁻¹``), computed
    stably: the monomials ``x y²`` of coordinates in the hundreds are badly scaled.
    """
    norms = np.linalg.norm(design, axis=0)
    norms[norms == 0] = 1.0
    sol, *_ = np.linalg.lstsq(design / norms, target, rcond=None)
    return sol / norms


def estimate_distortion_thesis(xy_distorted, xy_undistorted) -> ThesisDistortionEstimate:
    """Optical centre and ρ exactly as the thesis (eq. 3.17–3.42).

    1. Least-squares quadratic fits (eq. 3.17–3.25) of the distorted coordinates against the
       undistorted ones: ``x_d = a_x0 x y² + a_x1 x y + a_x2 x + a_x3 y² + a_x4 y + a_x5`` and
       ``y_d = a_y0 x² y + a_y1 x y + a_y2 y + a_y3 x² + a_y4 x + a_y5``.
    2. Optical centre in the undistorted frame (eq. 3.30–3.31, the mean of the two ratios)
       and in the distorted frame (eq. 3.32–3.33).
    3. Least-squares line ``r_c ≈ a_r0 r_w + a_r1`` (eq. 3.35–3.41) between the distorted radii
       ``r_c`` and the undistorted radii ``r_w``, then ``ρ³`` from ``r₂ = r_c + ρ³ r_c³``
       (eq. 3.42).

    For the projector, the distorted coordinates are the panel coordinates of grid points and
    the undistorted ones their positions on a flat surface (world mm on the plane, or
    rectified camera px). The method assumes the plane maps to ideal projector coordinates by
    a similarity (eq. 3.35 is a scale and an offset); perspective and the missing ``x³``/``y³``
    terms of eq. 3.17–3.18 bias it, and eq. 3.35's free scale absorbs part of the distortion.

    Parameters
    ----------
    xy_distorted : (N, 2) float
        Distorted (panel) coordinates, projector px.
    xy_undistorted : (N, 2) float
        Undistorted coordinates of the same points, any planar unit.

    Returns
    -------
    ThesisDistortionEstimate

    Raises
    ------
    ValueError
        On bad shapes, fewer than 12 points, or a degenerate fit (a zero denominator).

    Examples
    --------
    >>> yy, xx = np.mgrid[0:1040:40, 0:1280:40].reshape(2, -1).astype(float)
    >>> panel = np.column_stack([xx, yy])
    >>> est = estimate_distortion_thesis(panel, ideal_from_panel(panel) * 0.05)
    >>> est.rho < 0
    True
    """
    dist = as_points(xy_distorted, "xy_distorted", 2, min_points=12)
    und = as_points(xy_undistorted, "xy_undistorted", 2, min_points=12)
    if dist.shape != und.shape:
        raise ValueError(
            f"xy_distorted, xy_undistorted: shapes differ, {dist.shape} and {und.shape}"
        )
    xw, yw = und[:, 0], und[:, 1]
    one = np.ones_like(xw)
    y_x = np.column_stack([xw * yw**2, xw * yw, xw, yw**2, yw, one])  # eq. 3.23 (transposed)
    x_y = np.column_stack([xw**2 * yw, xw * yw, yw, xw**2, xw, one])  # eq. 3.24 (transposed)
    ax = _lstsq(y_x, dist[:, 0])  # eq. 3.21
    ay = _lstsq(x_y, dist[:, 1])  # eq. 3.22
    extent = float(np.ptp(dist))
    curvature = min(abs(ax[0]) * np.max(np.abs(y_x[:, 0])), abs(ay[0]) * np.max(np.abs(x_y[:, 0])))
    if not curvature > 1e-9 * extent:
        raise ValueError(
            "xy_distorted: quadratic fit is degenerate (no curvature): cannot locate the centre"
        )
    with np.errstate(divide="ignore", invalid="ignore"):
        xwc = -0.5 * (ax[3] / ax[0] + ax[4] / ax[1])  # eq. 3.30
        ywc = -0.5 * (ay[3] / ay[0] + ay[4] / ay[1])  # eq. 3.31
    if not (np.isfinite(xwc) and np.isfinite(ywc)):
        raise ValueError(
            "xy_distorted: quadratic fit is degenerate (no curvature): cannot locate the centre"
        )
    xcc = ax[2] * xwc + ax[5]  # eq. 3.32
    ycc = ay[2] * ywc + ay[5]  # eq. 3.33
    r_w = np.hypot(xw - xwc, yw - ywc)  # eq. 3.35
    r_c = np.hypot(dist[:, 0] - xcc, dist[:, 1] - ycc)  # eq. 3.38
    r_mat = np.column_stack([r_w, one])  # eq. 3.39
    a_r = _lstsq(r_mat, r_c)  # eq. 3.36, 3.40
    r2 = r_mat @ a_r  # eq. 3.41
    rc3 = r_c**3
    rho3 = float(rc3 @ (r2 - r_c) / (rc3 @ rc3))  # eq. 3.42
    return ThesisDistortionEstimate(
        center=(float(xcc), float(ycc)),
        rho=float(np.cbrt(rho3)),
        plane_center=(float(xwc), float(ywc)),
        coeffs_x=ax,
        coeffs_y=ay,
        coeffs_r=a_r,
    )


# --------------------------------------------------------------------------------------------
# Joint non-linear estimation (centre, ρ and a plane homography)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DistortionFit:
    """Result of :func:`estimate_distortion`.

    Attributes
    ----------
    center : (2,) tuple of float
        Optical centre, panel px.
    rho : float
        Distortion parameter ρ (eq. 3.34).
    homography : (3, 3) ndarray
        Maps plane coordinates to ideal projector coordinates (``H[2, 2] = 1``); the first
        view's.
    homographies : tuple of (3, 3) ndarray
        One per view.
    rms_px, median_px : float
        RMS and median of the residual distances, projector px (all points).
    center_std_px : (2,) tuple of float
        One-sigma uncertainty of the centre from the Gauss–Newton covariance, px. Large values
        flag the centre/homography degeneracy of weak distortion.
    rho_std : float
        One-sigma uncertainty of ρ.
    n_points : int
        Number of points used.
    n_outliers : int
        Points with residual above 3 px (down-weighted by the robust loss).
    success : bool
        Whether the optimiser converged.
    """

    center: tuple[float, float]
    rho: float
    homography: np.ndarray = field(repr=False)
    homographies: tuple = field(default=(), repr=False)
    rms_px: float = math.nan
    median_px: float = math.nan
    center_std_px: tuple[float, float] = (math.nan, math.nan)
    rho_std: float = math.nan
    n_points: int = 0
    n_outliers: int = 0
    success: bool = False


_LOSSES = ("cauchy", "soft_l1", "huber", "arctan", "linear")


def _hartley(xy: np.ndarray) -> np.ndarray:
    """3×3 similarity moving the centroid to 0 and the mean distance to √2 (Hartley)."""
    mean = xy.mean(axis=0)
    scale = math.sqrt(2.0) / max(float(np.mean(np.linalg.norm(xy - mean, axis=1))), 1e-12)
    return np.array([[scale, 0, -scale * mean[0]], [0, scale, -scale * mean[1]], [0, 0, 1.0]])


def _apply_h(h: np.ndarray, xy: np.ndarray) -> np.ndarray:
    w = h[2, 0] * xy[:, 0] + h[2, 1] * xy[:, 1] + h[2, 2]
    x = (h[0, 0] * xy[:, 0] + h[0, 1] * xy[:, 1] + h[0, 2]) / w
    y = (h[1, 0] * xy[:, 0] + h[1, 1] * xy[:, 1] + h[1, 2]) / w
    return np.column_stack([x, y])


def _dlt_homography(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Homography ``src → dst`` by the normalised DLT (both already normalised)."""
    n = src.shape[0]
    a = np.zeros((2 * n, 9))
    x, y = src[:, 0], src[:, 1]
    u, v = dst[:, 0], dst[:, 1]
    a[0::2, 0:3] = np.column_stack([x, y, np.ones(n)])
    a[0::2, 6:9] = -u[:, None] * np.column_stack([x, y, np.ones(n)])
    a[1::2, 3:6] = np.column_stack([x, y, np.ones(n)])
    a[1::2, 6:9] = -v[:, None] * np.column_stack([x, y, np.ones(n)])
    _, _, vt = np.linalg.svd(a, full_matrices=False)
    h = vt[-1].reshape(3, 3)
    return h / h[2, 2]


def _as_views(xy_panel, xy_plane, max_points: int, seed: int):
    """Validate one view (two (N, 2) arrays) or several (two lists); shuffle, subsample each."""
    multi = (isinstance(xy_panel, list | tuple) and len(xy_panel) > 0
             and np.ndim(xy_panel[0]) == 2)
    panels = list(xy_panel) if multi else [xy_panel]
    planes = list(xy_plane) if multi else [xy_plane]
    if len(panels) != len(planes):
        raise ValueError(f"xy_panel, xy_plane: {len(panels)} and {len(planes)} views")
    rng = np.random.default_rng(seed)
    views = []
    for i, (pan, pla) in enumerate(zip(panels, planes, strict=True)):
        suffix = f"[{i}]" if multi else ""
        panel = as_points(pan, f"xy_panel{suffix}", 2, min_points=12)
        plane = as_points(pla, f"xy_plane{suffix}", 2, min_points=12)
        if panel.shape != plane.shape:
            raise ValueError(
                f"xy_panel{suffix}, xy_plane{suffix}: shapes differ, {panel.shape} and "
                f"{plane.shape}"
            )
        # A random order (and subsample): any leading block is a fair sample of the view.
        keep = rng.permutation(panel.shape[0])[:max_points]
        views.append((panel[keep], plane[keep]))
    return views, multi


def _distortion_starts(views, ref: np.ndarray, spread: float, center0, rho0) -> list:
    """Starting ``(center, rho)`` of :func:`estimate_distortion`: the given ones; else the
    closed-form thesis estimate of the first view when it is finite and near the points
    (:func:`estimate_distortion_thesis`), and the points' centroid with ``rho = -1 / spread``."""
    starts = []
    if center0 is not None and rho0 is not None:
        starts.append(_check_params(center0, rho0))
        return starts
    thesis: ThesisDistortionEstimate | None = None
    ok = False
    try:
        with np.errstate(all="ignore"):
            thesis = estimate_distortion_thesis(*views[0])
        ok = bool(np.all(np.isfinite(thesis.center)) and math.isfinite(thesis.rho)
                  and thesis.rho != 0
                  and np.all(np.abs(np.asarray(thesis.center) - ref) < 2 * spread))
    except ValueError:
        ok = False
    if ok:
        assert thesis is not None
        starts.append(_check_params(
            thesis.center if center0 is None else center0,
            thesis.rho if rho0 is None else rho0,
        ))
    starts.append(_check_params(
        tuple(ref) if center0 is None else center0, -1.0 / spread if rho0 is None else rho0
    ))
    return starts


def _parameter_std(result) -> np.ndarray:
    """Standard deviations of a least-squares fit's parameters: the Gauss-Newton covariance.
    ``result.jac`` carries the robust loss's weights; the noise scale is robust (MAD) so that
    outliers do not inflate it."""
    sigma2 = (1.4826 * float(np.median(np.abs(result.fun)))) ** 2
    return gauss_newton_std(result.jac, sigma2)


def estimate_distortion(xy_panel, xy_plane, *, center0=None, rho0: float | None = None,
                        loss: str = "cauchy", f_scale_px: float = 0.5,
                        max_points: int = 20000, seed: int = 0) -> DistortionFit:
    """Estimate centre and ρ jointly by non-linear least squares against plane homographies.

    Points on a flat surface (any orientation) seen by an undistorted camera: the map from
    plane coordinates (camera px, or world mm on the plane) to *ideal* projector coordinates
    is a homography ``H``. The fit minimises, over ``c``, ``ρ`` and ``H``,
    ``Σ loss(‖ T_p(ideal_from_panel(p_n; c, ρ)) − H̃(T_w(w_n)) ‖²)`` where ``T_p``, ``T_w`` are
    Hartley normalisations (fixed) and ``H̃`` the normalised homography (8 parameters). Several
    views (cameras, or plane poses) share ``c`` and ``ρ``, each with its own ``H``. The
    distortion is parametrised by ``κ = ρ³ R²`` with ``R`` the panel points' spread, and the
    centre in units of ``R``, so all parameters are of order one.

    Starts: `center0` and `rho0` when both are given; otherwise the thesis estimate
    (:func:`estimate_distortion_thesis`, first view) when it is finite and near the points, and
    the points' centroid with ``ρ = −1/R`` (about 1 px of distortion at ``R``); the fit with
    the lower cost wins (the thesis start alone can end in a local minimum when the points
    cover part of the panel).

    Degeneracy: the centre enters only through ``ρ³``: ``∂ ideal / ∂c = −ρ³ (r² I + 2 d dᵀ)``,
    which vanishes as ``ρ → 0``; and part of a centre shift (its ``x²`` and ``x y`` terms) is a
    projective term of ``H``. With weak distortion or a small field of view the centre is
    poorly determined; ``center_std_px`` reports it.

    Parameters
    ----------
    xy_panel : (N, 2) float, or list of (N_i, 2)
        Decoded panel coordinates (distorted), projector px; a list for several views.
    xy_plane : (N, 2) float, or list of (N_i, 2)
        Coordinates of the same points on the plane: undistorted camera px or plane mm.
    center0 : (2,) float, optional
        Initial centre, panel px.
    rho0 : float, optional
        Initial ρ.
    loss : {"cauchy", "soft_l1", "huber", "arctan", "linear"}
        ``scipy.optimize.least_squares`` loss. The redescending ones (``"cauchy"``,
        ``"arctan"``) start from a ``"soft_l1"`` fit.
    f_scale_px : float
        Inlier scale of the robust loss, projector px.
    max_points : int
        Random subsample size (in all, split evenly between views) above which points are
        dropped (seeded by `seed`).
    seed : int
        Seed of the subsample.

    Returns
    -------
    DistortionFit

    Raises
    ------
    ValueError
        On bad shapes, fewer than 12 points per view, or a non-finite result.

    Examples
    --------
    >>> yy, xx = np.mgrid[0:1040:40, 0:1280:40].reshape(2, -1).astype(float)
    >>> panel = np.column_stack([xx, yy])
    >>> fit = estimate_distortion(panel, ideal_from_panel(panel) * 0.05)
    >>> [round(v, 1) for v in fit.center], round(fit.rho, 5)
    ([640.0, 1000.0], -0.004)
    """
    if max_points < 12:
        raise ValueError(f"max_points: expected at least 12, got {max_points}")
    if loss not in _LOSSES:
        raise ValueError(f"loss: expected one of {', '.join(_LOSSES)}, got {loss!r}")
    n_views = len(xy_panel) if isinstance(xy_panel, list | tuple) else 1
    views, _ = _as_views(xy_panel, xy_plane, max(12, max_points // max(n_views, 1)), seed)
    all_panel = np.concatenate([v[0] for v in views])
    ref = all_panel.mean(axis=0)
    spread = float(np.max(np.linalg.norm(all_panel - ref, axis=1)))
    if spread <= 0:
        raise ValueError("xy_panel: all points coincide")

    starts = _distortion_starts(views, ref, spread, center0, rho0)

    t_ps = [_hartley(panel) for panel, _ in views]
    t_ws = [_hartley(plane) for _, plane in views]
    planes_n = [_apply_h(t_w, plane) for (_, plane), t_w in zip(views, t_ws, strict=True)]
    n_params = 3 + 8 * len(views)

    def unpack(params):
        c = ref + spread * params[0:2]
        k = params[2] / spread**2
        hs = [np.append(params[3 + 8 * i : 11 + 8 * i], 1.0).reshape(3, 3)
              for i in range(len(views))]
        return c, k, hs

    def ideal_of(panel, c, k):
        d = panel - c
        return c + d * (1.0 + k * np.sum(d * d, axis=1, keepdims=True))

    def problem(n_max):
        """Residual and Jacobian functions on the first `n_max` points of every view."""
        data = [(panel[:n_max], t_p, plane_n[:n_max])
                for (panel, _), t_p, plane_n in zip(views, t_ps, planes_n, strict=True)]

        def residuals(params):
            c, k, hs = unpack(params)
            return np.concatenate([
                (_apply_h(t_p, ideal_of(panel, c, k)) - _apply_h(h, plane_n)).ravel()
                for (panel, t_p, plane_n), h in zip(data, hs, strict=True)
            ])

        def jacobian(params):
            """Analytic Jacobian (rows: x, y residuals interleaved per point)."""
            c, k, hs = unpack(params)
            blocks = []
            for i, ((panel, t_p, plane_n), h) in enumerate(zip(data, hs, strict=True)):
                n = panel.shape[0]
                jac = np.zeros((n, 2, n_params))
                s_p = t_p[0, 0]
                d = panel - c
                r2 = np.sum(d * d, axis=1)
                # ∂ideal/∂c = −k (r² I + 2 d dᵀ), c = ref + R c̃; ∂ideal/∂κ = d r² / R².
                jac[:, 0, 0] = -k * (r2 + 2 * d[:, 0] ** 2)
                jac[:, 0, 1] = -k * 2 * d[:, 0] * d[:, 1]
                jac[:, 1, 0] = jac[:, 0, 1]
                jac[:, 1, 1] = -k * (r2 + 2 * d[:, 1] ** 2)
                jac[:, :, 0:2] *= s_p * spread
                jac[:, :, 2] = s_p * d * (r2 / spread**2)[:, None]
                # −∂H(w)/∂h for the 8 free entries of H.
                x, y = plane_n[:, 0], plane_n[:, 1]
                w = h[2, 0] * x + h[2, 1] * y + 1.0
                u = (h[0, 0] * x + h[0, 1] * y + h[0, 2]) / w
                v = (h[1, 0] * x + h[1, 1] * y + h[1, 2]) / w
                o = 3 + 8 * i
                jac[:, 0, o : o + 3] = -np.column_stack([x, y, np.ones(n)]) / w[:, None]
                jac[:, 1, o + 3 : o + 6] = jac[:, 0, o : o + 3]
                jac[:, 0, o + 6 : o + 8] = np.column_stack([u * x, u * y]) / w[:, None]
                jac[:, 1, o + 6 : o + 8] = np.column_stack([v * x, v * y]) / w[:, None]
                blocks.append(jac.reshape(2 * n, n_params))
            return np.concatenate(blocks)

        return residuals, jacobian

    # Residuals are in each view's normalised units; f_scale uses the first view's scale.
    scale_p = t_ps[0][0, 0]
    stages = ["soft_l1", loss] if loss in ("cauchy", "arctan") else [loss]

    def solve(x0, n_max):
        residuals, jacobian = problem(n_max)
        for stage in stages:  # a redescending loss starts from a convex robust fit
            res = optimize.least_squares(residuals, x0, jac=jacobian, loss=stage,
                                         f_scale=f_scale_px * scale_p, method="trf",
                                         x_scale=1.0, max_nfev=2000)
            x0 = res.x
        return res

    # Every start is first solved on a subsample (2000 points per view); the best one is then
    # refined on all the points. A poor start can end in a local minimum.
    best = None
    for c0, r0 in starts:
        x0 = [(c0 - ref) / spread, [r0**3 * spread**2]]
        for (panel, _), t_p, plane_n in zip(views, t_ps, planes_n, strict=True):
            h0 = _dlt_homography(plane_n, _apply_h(t_p, ideal_of(panel, c0, r0**3)))
            x0.append(h0.ravel()[:8])
        trial = solve(np.concatenate(x0), 2000)
        if best is None or trial.cost < best.cost:
            best = trial
    assert best is not None  # at least one start
    result = solve(best.x, None)
    c, k, hs = unpack(result.x)
    if not (np.all(np.isfinite(c)) and math.isfinite(k)):
        raise ValueError("estimate_distortion: the fit diverged (non-finite parameters)")
    h_px = []
    for t_p, t_w, h_n in zip(t_ps, t_ws, hs, strict=True):
        h = np.linalg.inv(t_p) @ h_n @ t_w
        h_px.append(h / h[2, 2])
    sizes = [2 * len(panel) for panel, _ in views]
    fun_px = np.concatenate([
        f / t_p[0, 0] for f, t_p in zip(np.split(result.fun, np.cumsum(sizes)[:-1]), t_ps,
                                        strict=True)
    ])
    dist_px = np.linalg.norm(fun_px.reshape(-1, 2), axis=1)

    std = _parameter_std(result)
    rho = float(np.cbrt(k))
    rho_std = (std[2] / spread**2) / (3 * rho**2) if rho != 0 else math.inf
    return DistortionFit(
        center=(float(c[0]), float(c[1])),
        rho=rho,
        homography=h_px[0],
        homographies=tuple(h_px),
        rms_px=float(np.sqrt(np.mean(dist_px**2))),
        median_px=float(np.median(dist_px)),
        center_std_px=(float(spread * std[0]), float(spread * std[1])),
        rho_std=float(rho_std),
        n_points=int(dist_px.size),
        n_outliers=int(np.sum(dist_px > 3.0)),
        success=bool(result.success),
    )


# --------------------------------------------------------------------------------------------
# From decoded maps
# --------------------------------------------------------------------------------------------


def points_from_decoded(xp, yp, mask=None, *, stride: int = 1):
    """Point pairs (panel, camera px) from decoded projector coordinate maps.

    Parameters
    ----------
    xp, yp : (H, W) float
        Decoded panel coordinates per camera pixel, projector px; ``NaN`` where undecoded.
    mask : (H, W) bool, optional
        Valid pixels (combined with finiteness of `xp`, `yp`).
    stride : int
        Keep every `stride`-th row and column.

    Returns
    -------
    xy_panel : (N, 2) float64
        Panel coordinates ``(xp, yp)``.
    xy_camera : (N, 2) float64
        Camera pixel coordinates ``(x, y) = (column, row)``.

    Examples
    --------
    >>> xp = np.array([[1.0, np.nan], [3.0, 4.0]])
    >>> panel, cam = points_from_decoded(xp, xp + 10)
    >>> panel.tolist(), cam.tolist()
    ([[1.0, 11.0], [3.0, 13.0], [4.0, 14.0]], [[0.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    """
    xp_arr = as_float_array(xp, "xp")
    yp_arr = as_float_array(yp, "yp")
    if xp_arr.ndim != 2 or xp_arr.shape != yp_arr.shape:
        raise ValueError(f"xp, yp: expected two (H, W) maps, got {xp_arr.shape}, {yp_arr.shape}")
    if not isinstance(stride, int | np.integer) or stride < 1:
        raise ValueError(f"stride: expected a positive integer, got {stride!r}")
    valid = np.isfinite(xp_arr) & np.isfinite(yp_arr)
    if mask is not None:
        mask_arr = np.asarray(mask)
        if mask_arr.shape != xp_arr.shape:
            raise ValueError(f"mask: expected shape {xp_arr.shape}, got {mask_arr.shape}")
        valid &= mask_arr.astype(bool)
    sub = np.zeros_like(valid)
    sub[::stride, ::stride] = True
    rows, cols = np.nonzero(valid & sub)
    panel = np.column_stack([xp_arr[rows, cols], yp_arr[rows, cols]])
    return panel, np.column_stack([cols, rows]).astype(np.float64)


def grid_from_decoded(xp, yp, mask=None, *, panel_size=(1280, 1040), spacing: int = 64,
                      width: int | None = None, center=None, rho: float | None = None,
                      background=None) -> np.ndarray:
    """Image of a projected grid as a camera sees it, drawn from decoded coordinates.

    A camera pixel is on a line when the projector coordinate it sees falls on a grid line of
    :func:`nail2nail.scan.patterns.grid_pattern` (``(round(u) − offset) mod spacing < width``,
    offset
    the panel centre). With the panel coordinates this is the plain grid as projected (the
    thesis's Figure 19); with the ideal coordinates (`center` and `rho` given) it is the
    LUT-corrected grid (Figure 20), whose lines are straight on a plane.

    Parameters
    ----------
    xp, yp : (H, W) float
        Decoded panel coordinates, projector px (``NaN`` undecoded).
    mask : (H, W) bool, optional
        Valid pixels.
    panel_size : (2,) int
        Panel ``(W, H)``: the grid's offset is its centre.
    spacing : int
        Grid spacing, panel px.
    width : int, optional
        Line width, panel px; by default about two camera pixels (from the median gradient of
        the decoded coordinates), so that lines do not break up when a camera pixel spans
        several panel pixels.
    center, rho : optional
        Distortion to undo: draw lines of constant *ideal* coordinate.
    background : (H, W) float in [0, 1], optional
        Image to draw on (e.g. the albedo); by default a dark grey on valid pixels.

    Returns
    -------
    (H, W) uint8
        Lines 255, background scaled to ``[0, 160]``, invalid pixels 0.

    Examples
    --------
    >>> xp = np.tile(np.arange(0.0, 8.0), (2, 1))
    >>> grid_from_decoded(xp, xp, panel_size=(8, 8), spacing=4, width=1)[0].tolist()
    [255, 64, 64, 64, 255, 64, 64, 64]
    """
    xp_arr = as_float_array(xp, "xp")
    yp_arr = as_float_array(yp, "yp")
    if xp_arr.ndim != 2 or xp_arr.shape != yp_arr.shape:
        raise ValueError(f"xp, yp: expected two (H, W) maps, got {xp_arr.shape}, {yp_arr.shape}")
    panel_w, panel_h = _check_size(panel_size)
    if width is None:
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN maps
            step = np.nanmedian(np.hypot(*np.gradient(xp_arr)))
            step = max(step, np.nanmedian(np.hypot(*np.gradient(yp_arr))))
        width = int(np.clip(np.ceil(2 * step), 1, spacing // 2)) if np.isfinite(step) else 1
    if width < 1 or spacing <= width:
        raise ValueError(f"spacing, width: expected spacing > width >= 1, got {spacing}, {width}")
    if (center is None) != (rho is None):
        raise ValueError("center, rho: give both or neither")
    if center is not None and rho is not None:
        xp_arr, yp_arr = ideal_from_decoded(xp_arr, yp_arr, center, rho)
    valid = np.isfinite(xp_arr) & np.isfinite(yp_arr)
    if mask is not None:
        valid &= np.asarray(mask, dtype=bool)
    with np.errstate(invalid="ignore"):
        on_x = np.mod(np.floor(xp_arr + 0.5) - panel_w // 2, spacing) < width
        on_y = np.mod(np.floor(yp_arr + 0.5) - panel_h // 2, spacing) < width
    if background is None:
        image = np.where(valid, 64, 0).astype(np.uint8)
    else:
        back = as_float_array(background, "background")
        if back.shape != xp_arr.shape:
            raise ValueError(f"background: expected shape {xp_arr.shape}, got {back.shape}")
        image = np.where(valid, np.rint(160 * np.clip(np.nan_to_num(back), 0, 1)), 0)
        image = image.astype(np.uint8)
    image[valid & (on_x | on_y)] = 255
    return image


@dataclass(frozen=True)
class CameraDistortionEstimate:
    """Estimates from one camera's view of the plane (see :func:`estimate_from_decoded`)."""

    camera: str
    n_points: int
    fit: DistortionFit
    thesis: ThesisDistortionEstimate | None
    thesis_error: str | None = None


@dataclass(frozen=True)
class DistortionReport:
    """Result of :func:`estimate_from_decoded`.

    Attributes
    ----------
    fit : DistortionFit
        Joint non-linear estimate over all cameras (shared centre and ρ).
    thesis : ThesisDistortionEstimate or None
        The thesis method (eq. 3.17–3.42) on the primary camera (the thesis used the centre
        camera); ``None`` if its fit was degenerate.
    primary : str
        Name of that camera.
    cameras : tuple of CameraDistortionEstimate
        Per-camera estimates.
    """

    fit: DistortionFit
    thesis: ThesisDistortionEstimate | None
    primary: str
    cameras: tuple[CameraDistortionEstimate, ...]

    def to_dict(self, truth: ProjectorDistortion | None = None) -> dict:
        """JSON summary: ``center_px`` and ``rho`` (non-linear), ``thesis`` {center_px, rho},
        per-camera estimates and, with `truth`, the errors of both methods."""

        def fit_dict(fit: DistortionFit) -> dict:
            return {
                "center_px": [fit.center[0], fit.center[1]],
                "rho": fit.rho,
                "center_std_px": list(fit.center_std_px),
                "rho_std": fit.rho_std,
                "rms_px": fit.rms_px,
                "median_px": fit.median_px,
                "n_points": fit.n_points,
                "n_outliers": fit.n_outliers,
                "converged": fit.success,
            }

        def thesis_dict(est: ThesisDistortionEstimate | None) -> dict | None:
            if est is None:
                return None
            return {"center_px": list(est.center), "rho": est.rho,
                    "plane_center": list(est.plane_center)}

        out = {"method": "nonlinear-homography", **fit_dict(self.fit),
               "thesis": thesis_dict(self.thesis), "primary_camera": self.primary,
               "cameras": [
                   {"camera": cam.camera, "nonlinear": fit_dict(cam.fit),
                    "thesis": thesis_dict(cam.thesis), "thesis_error": cam.thesis_error}
                   for cam in self.cameras
               ]}
        if truth is not None:
            def errors(center, rho):
                return {"center_error_px": float(np.hypot(center[0] - truth.center[0],
                                                          center[1] - truth.center[1])),
                        "rho_error_percent": float(100 * abs(rho / truth.rho - 1))
                        if truth.rho != 0 else math.nan}
            out["truth"] = {
                **truth.to_dict(),
                "nonlinear": errors(self.fit.center, self.fit.rho),
                "thesis": None if self.thesis is None else errors(self.thesis.center,
                                                                   self.thesis.rho),
            }
        return out


def _rectify_pixels(xy: np.ndarray, camera) -> np.ndarray:
    """Remove a pinhole camera's lens distortion from pixel coordinates ``(N, 2)``."""
    if camera is None or not np.any(camera.dist):
        return xy
    k = np.asarray(camera.K, dtype=float)
    normalized = (xy - k[:2, 2]) @ np.linalg.inv(k[:2, :2]).T
    return camera.undistort(normalized) @ k[:2, :2].T + k[:2, 2]


def estimate_from_decoded(views, *, primary: str | None = None, cameras=None, stride: int = 2,
                          max_points: int = 20000, seed: int = 0) -> DistortionReport:
    """Estimate the projector distortion from decoded captures of a flat plane.

    Parameters
    ----------
    views : mapping of str to (xp, yp, mask)
        Per camera: decoded panel coordinate maps ``(H, W)`` (from plain, not pre-distorted,
        patterns) and the valid mask (or ``None``).
    primary : str, optional
        Camera for the thesis method; by default the middle one (the thesis's centre camera).
    cameras : mapping of str to Pinhole, optional
        Camera models whose lens distortion is removed from the pixel coordinates first (the
        homography criterion needs an undistorted camera).
    stride : int
        Pixel subsampling of the maps before fitting.
    max_points : int
        Random subsample for each non-linear fit (per camera, and in all for the joint fit).
    seed : int
        Seed of the subsample.

    Returns
    -------
    DistortionReport

    Raises
    ------
    ValueError
        If no camera has enough decoded pixels, or `primary` is unknown.
    """
    if not views:
        raise ValueError("views: no camera given")
    names = list(views)
    if primary is None:
        primary = names[len(names) // 2]
    if primary not in views:
        raise ValueError(f"primary: unknown camera {primary!r} (have {', '.join(names)})")
    cameras = cameras or {}
    points = {}
    for name in names:
        xp, yp, mask = views[name]
        panel, cam = points_from_decoded(xp, yp, mask, stride=stride)
        if panel.shape[0] < 100:
            raise ValueError(f"{name}: only {panel.shape[0]} decoded pixels, need at least 100")
        points[name] = (panel, _rectify_pixels(cam, cameras.get(name)))
    per_camera = []
    for name in names:
        panel, cam = points[name]
        try:
            thesis, message = estimate_distortion_thesis(panel, cam), None
        except ValueError as exc:
            thesis, message = None, str(exc)
        fit = estimate_distortion(panel, cam, max_points=max_points, seed=seed)
        per_camera.append(CameraDistortionEstimate(name, int(panel.shape[0]), fit, thesis,
                                                   message))
    if len(names) == 1:
        joint = per_camera[0].fit
    else:
        joint = estimate_distortion([points[n][0] for n in names], [points[n][1] for n in names],
                                    max_points=max_points, seed=seed)
    main = next(c for c in per_camera if c.camera == primary)
    return DistortionReport(fit=joint, thesis=main.thesis, primary=primary,
                            cameras=tuple(per_camera))


# --------------------------------------------------------------------------------------------
# Parameters from files
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ProjectorDistortion:
    """Projector radial distortion (thesis eq. 3.34): optical centre and ρ.

    The one form of the model everywhere in nail2nail (``RigCalibration``, the virtual rig,
    the calibrations fitted); ``{"center": [x, y], "rho": r}`` in JSON.

    Attributes
    ----------
    center : (float, float)
        Optical centre on the panel, panel px ``(x, y)``.
    rho : float
        Distortion parameter: radius ``r`` appears at ``r + ρ³ r³`` (``ρ < 0``: barrel).
    """

    center: tuple[float, float] = THESIS_CENTER
    rho: float = THESIS_RHO

    def ideal_from_panel(self, xy_panel) -> np.ndarray:
        """:func:`ideal_from_panel` with this model."""
        return ideal_from_panel(xy_panel, self.center, self.rho)

    def panel_from_ideal(self, xy_ideal) -> np.ndarray:
        """:func:`panel_from_ideal` with this model."""
        return panel_from_ideal(xy_ideal, self.center, self.rho)

    def to_dict(self) -> dict:
        """JSON-serialisable ``{"center": [x, y], "rho": r}``."""
        return {"center": [float(self.center[0]), float(self.center[1])], "rho": float(self.rho)}

    @classmethod
    def from_dict(cls, data) -> ProjectorDistortion:
        """Parse ``{"center": [x, y], "rho": r}``; raise ValueError on anything else."""
        if not isinstance(data, dict) or "center" not in data or "rho" not in data:
            raise ValueError("projector_distortion: expected {'center': [x, y], 'rho': r}")
        c, rho = _check_params(data["center"], data["rho"])
        return cls(center=(float(c[0]), float(c[1])), rho=rho)


def as_projector_distortion(value) -> ProjectorDistortion | None:
    """`value` as a :class:`ProjectorDistortion`: ``None``, a model, or its JSON dict.

    Functions that take a ``projector_distortion`` accept any of the three (a dict as read
    from a file); data structures hold the model. ``ValueError`` on anything else.
    """
    if value is None or isinstance(value, ProjectorDistortion):
        return value
    return ProjectorDistortion.from_dict(value)


def load_projector_distortion(source) -> ProjectorDistortion | None:
    """Projector distortion from a calibration or rig JSON file (or its parsed dict).

    Looks for ``projector_distortion`` (the calibration file, ``docs/capture-format.md``), then
    for the simulator rig's projector distortion fields (``projector_distortion``,
    ``distortion`` or ``projector`` → ``distortion``, or ``distortion_center`` +
    ``distortion_rho``). A ``null`` value means no distortion and returns ``None``.

    Raises
    ------
    ValueError
        If the file holds none of these keys.
    OSError
        If the file cannot be read.
    """
    if isinstance(source, dict):
        data, name = source, "data"
    else:
        name = os.fspath(source)
        data = read_json(name)
    if not isinstance(data, dict):
        raise ValueError(f"{name}: expected a JSON object")
    candidates: list[dict] = [data, data["rig"]] if isinstance(data.get("rig"), dict) else [data]
    for obj in candidates:
        for key in ("projector_distortion", "distortion"):
            if key in obj:
                return None if obj[key] is None else ProjectorDistortion.from_dict(obj[key])
        proj = obj.get("projector")
        if isinstance(proj, dict) and "distortion" in proj and not isinstance(
            proj["distortion"], list
        ):
            value = proj["distortion"]
            return None if value is None else ProjectorDistortion.from_dict(value)
        for prefix in ("projector_distortion_", "distortion_"):
            if prefix + "center" in obj and prefix + "rho" in obj:
                return ProjectorDistortion.from_dict(
                    {"center": obj[prefix + "center"], "rho": obj[prefix + "rho"]}
                )
    raise ValueError(f"{name}: no 'projector_distortion' {{center, rho}} found")


#: The plane check that comes before the (slow) fit: each camera's decoded projector
#: coordinates, as a smooth function of the camera pixel (a polynomial of degree
#: :data:`PLANE_DEGREE`, fitted twice, the second time without the points 5 times the median
#: residual away), leave on a flat plane only the projector's radial distortion and the noise.
#: Measured, the worst camera, projector px RMS: the virtual flat plane 0.085 with the thesis's
#: distortion and 0.032 (the noise) without (scales 0.125 and 0.25); the virtual finger
#: 1.3-1.5, the cylinder target 0.50, a sphere 0.96, a coin 5.6. The limit leaves a flat plane
#: room for 4 times that distortion or 0.4 px of decoding noise; above it the capture is
#: refused as not a plane (on a finger the fit used to run for more than ten minutes).
PLANE_RMS_LIMIT_PX = 0.4
PLANE_DEGREE = 5
_PLANE_MAX_POINTS = 20000  # a seeded random subsample of each camera's pixels for the check


def _plane_residual_px(xp, yp, mask) -> float | None:
    """RMS (projector px) of a smooth map's fit to the decoded points (:data:`PLANE_DEGREE`);
    ``None`` when too few points to say (the fit itself refuses them)."""
    panel, cam = points_from_decoded(xp, yp, mask, stride=1)
    n_terms = (PLANE_DEGREE + 1) * (PLANE_DEGREE + 2) // 2
    if panel.shape[0] < 10 * n_terms:
        return None
    if panel.shape[0] > _PLANE_MAX_POINTS:
        keep = np.random.default_rng(0).choice(panel.shape[0], _PLANE_MAX_POINTS, replace=False)
        panel, cam = panel[keep], cam[keep]
    c = (cam - cam.mean(axis=0)) / max(float(cam.std(axis=0).max()), 1e-12)
    design = np.stack([c[:, 0] ** i * c[:, 1] ** j for i in range(PLANE_DEGREE + 1)
                       for j in range(PLANE_DEGREE + 1 - i)], axis=1)
    coef = np.linalg.lstsq(design, panel, rcond=None)[0]
    r = np.linalg.norm(design @ coef - panel, axis=1)
    inliers = r <= 5 * np.median(r)  # gross decoding errors do not decide
    if inliers.sum() >= 10 * n_terms:
        coef = np.linalg.lstsq(design[inliers], panel[inliers], rcond=None)[0]
        r = np.linalg.norm(design[inliers] @ coef - panel[inliers], axis=1)
    return float(np.sqrt(np.mean(r**2)))


def check_plane(views, where) -> dict[str, float]:
    """Refuse a capture that is not of a flat plane, before the distortion fit.

    Parameters
    ----------
    views : mapping of str to (xp, yp, mask)
        Per camera: the decoded panel coordinate maps ``(H, W)`` and the valid mask.
    where : path-like
        How the message names the capture.

    Returns
    -------
    dict of str to float
        Each camera's residual, projector px RMS (cameras with too few points left out).

    Raises
    ------
    ValueError
        Naming `where`, the camera and its residual: the worst camera's residual is above
        :data:`PLANE_RMS_LIMIT_PX`.
    """
    residuals = {name: rms for name, (xp, yp, mask) in views.items()
                 if (rms := _plane_residual_px(xp, yp, mask)) is not None}
    if residuals:
        worst = max(residuals, key=residuals.__getitem__)
        if residuals[worst] > PLANE_RMS_LIMIT_PX:
            raise ValueError(
                f"{where}: not a capture of a flat plane: the decoded projector coordinates of "
                f"camera {worst!r} depart from a plane's smooth map by {residuals[worst]:.2f} px "
                f"RMS (a flat plane: under {PLANE_RMS_LIMIT_PX:g} px); `distortion` needs a flat "
                "plane under plain fringe patterns")
    return residuals
