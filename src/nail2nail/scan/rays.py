"""Triangulation on the camera ray, compiled: the per-pixel float64 solve of the fast path.

A :class:`~nail2nail.scan.triangulation.RayTable` packed into the constants the kernels read
(:func:`_pack_ray`), the projector's panel coordinates taken to ideal pinhole ones
(:func:`_ideal_panel`: the radial model of thesis eq. 3.34 and the lens, inverted by fixed-point
iteration) and the one-dimensional weighted least squares in the ray parameter ``t``
(:func:`_ray_points`, :func:`_ray_points_flat`). Used inside the decoding kernel
(:mod:`~nail2nail.scan.kernels`) and on its own by
:func:`~nail2nail.scan.triangulation.reconstruct_points_ray`.
"""

from __future__ import annotations

import numba
import numpy as np

from nail2nail._numba_cache import cache_enabled

__all__ = [
]


# ------------------------------------------------------------------------------------------------
# Fused fast path
# ------------------------------------------------------------------------------------------------
# cache=True unless no directory at all can hold numba's cache (nail2nail._numba_cache)
_CACHE = cache_enabled()


# Fast-math flags of the decoding arithmetic: fused multiply-adds and signed zeros only. Not
# nnan/ninf (the NaN and finiteness tests must hold), not arcp/reassoc (divisions and sums round
# as the reference's do, so thresholds fall on the same pixels).
_FAST = {"nsz", "contract"}


# Layout of the packed ray-triangulation constants (_pack_ray, _ray_points).
_RAY_INV, _RAY_CENTER, _RAY_G, _RAY_H, _RAY_NORM = 0, 9, 12, 21, 24


_RAY_DIST, _RAY_K, _RAY_KINV, _RAY_LENS, _RAY_SIZE = 29, 32, 38, 44, 49


_USE_CODE = {"xpyp": 0, "xp": 1, "yp": 2}


def _pack_ray(table) -> tuple[np.ndarray, np.ndarray]:
    """A :class:`~nail2nail.scan.triangulation.RayTable`'s constants as the kernel reads them:
    ``(ray_f (49,) float64, ray_i (4,) int64)``."""
    f = np.zeros(_RAY_SIZE)
    f[_RAY_INV:_RAY_INV + 9] = table.camera_inverse.ravel()
    center = table.camera_center
    f[_RAY_CENTER:_RAY_CENTER + 3] = center
    M = table.projector_matrix
    P = M[:, :3]
    f[_RAY_G:_RAY_G + 9] = (P @ table.camera_inverse).ravel()  # q = P d from (x, y, 1)
    f[_RAY_H:_RAY_H + 3] = P @ center + M[:, 3]  # the camera centre seen by the projector
    f[_RAY_NORM:_RAY_NORM + 5] = [P[0] @ P[0], P[1] @ P[1], P[2] @ P[2], P[0] @ P[2],
                                  P[1] @ P[2]]
    has_dist = table.panel_distortion is not None
    if has_dist:
        f[_RAY_DIST:_RAY_DIST + 3] = table.panel_distortion
    has_lens = table.projector_intrinsics is not None
    if has_lens:
        K = table.projector_intrinsics
        f[_RAY_K:_RAY_K + 6] = K[:2].ravel()
        f[_RAY_KINV:_RAY_KINV + 6] = np.linalg.inv(K)[:2].ravel()
        f[_RAY_LENS:_RAY_LENS + 5] = table.projector_dist
    i = np.array([_USE_CODE[table.use], has_dist, has_lens, table.lens_iterations], np.int64)
    return f, i


@numba.njit(fastmath=_FAST, error_model="numpy")
def _ideal_panel(px, py, ray_f, ray_i, xd, yd, ideal_x, ideal_y):  # pragma: no cover
    """Ideal pinhole coordinates ``ideal_x, ideal_y`` (float64) of panel coordinates
    ``px, py`` of a projector with lens distortion: the radial distortion model
    ``r -> r + rho^3 r^3`` (:func:`~nail2nail.calibration.distortion.ideal_from_panel`) if any,
    then the
    OpenCV lens inverted by the fixed-point iteration of
    :meth:`~nail2nail.calibration.camera_models.Pinhole.undistort` (same formula, same iteration
    count).
    `xd`, `yd` are scratch."""
    n = px.shape[0]
    has_dist = ray_i[1]
    cx, cy, k = ray_f[_RAY_DIST], ray_f[_RAY_DIST + 1], ray_f[_RAY_DIST + 2]
    a0, a1, a2 = ray_f[_RAY_KINV], ray_f[_RAY_KINV + 1], ray_f[_RAY_KINV + 2]
    a3, a4, a5 = ray_f[_RAY_KINV + 3], ray_f[_RAY_KINV + 4], ray_f[_RAY_KINV + 5]
    k1, k2, p1 = ray_f[_RAY_LENS], ray_f[_RAY_LENS + 1], ray_f[_RAY_LENS + 2]
    p2, k3 = ray_f[_RAY_LENS + 3], ray_f[_RAY_LENS + 4]
    for i in range(n):
        x = np.float64(px[i])
        y = np.float64(py[i])
        dx = x - cx
        dy = y - cy
        f = 1.0 + k * (dx * dx + dy * dy)
        x = cx + dx * f if has_dist else x
        y = cy + dy * f if has_dist else y
        xd[i] = x * a0 + y * a1 + a2  # normalised, distorted
        yd[i] = x * a3 + y * a4 + a5
        ideal_x[i] = xd[i]
        ideal_y[i] = yd[i]
    for _ in range(ray_i[3]):  # iterations outermost: the column loop vectorises
        for i in range(n):
            x = ideal_x[i]
            y = ideal_y[i]
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            ideal_x[i] = (xd[i] - dx) / radial
            ideal_y[i] = (yd[i] - dy) / radial
    b0, b1, b2 = ray_f[_RAY_K], ray_f[_RAY_K + 1], ray_f[_RAY_K + 2]
    b3, b4, b5 = ray_f[_RAY_K + 3], ray_f[_RAY_K + 4], ray_f[_RAY_K + 5]
    for i in range(n):
        x = ideal_x[i]
        y = ideal_y[i]
        ideal_x[i] = x * b0 + y * b1 + b2
        ideal_y[i] = x * b3 + y * b4 + b5


@numba.njit(fastmath=_FAST, error_model="numpy")
def _ray_points(px, py, x0, x_step, xo, y0, yo, ray_f, use, has_dist, x_out, y_out,
                z_out):  # pragma: no cover - compiled
    """World points (float64, mm) on the rays of the camera pixels ``(x0 + x_step i + xo[i],
    y0 + yo[i])`` from the panel coordinates ``px, py`` (ideal ones, or with the radial
    distortion model `has_dist` removed here,
    :func:`~nail2nail.calibration.distortion.ideal_from_panel`).

    The point ``X = C + t d``: ``t`` solves one projector plane (`use` 1: ``xp``, 2: ``yp``)
    or, `use` 0, both in least squares, each residual divided by its plane normal's norm
    (:func:`~nail2nail.scan.triangulation.reconstruct_points_ray`); in float64.
    """
    m0, m1, m2 = ray_f[_RAY_INV], ray_f[_RAY_INV + 1], ray_f[_RAY_INV + 2]
    m3, m4, m5 = ray_f[_RAY_INV + 3], ray_f[_RAY_INV + 4], ray_f[_RAY_INV + 5]
    m6, m7, m8 = ray_f[_RAY_INV + 6], ray_f[_RAY_INV + 7], ray_f[_RAY_INV + 8]
    g0, g1, g2 = ray_f[_RAY_G], ray_f[_RAY_G + 1], ray_f[_RAY_G + 2]
    g3, g4, g5 = ray_f[_RAY_G + 3], ray_f[_RAY_G + 4], ray_f[_RAY_G + 5]
    g6, g7, g8 = ray_f[_RAY_G + 6], ray_f[_RAY_G + 7], ray_f[_RAY_G + 8]
    h0, h1, h2 = ray_f[_RAY_H], ray_f[_RAY_H + 1], ray_f[_RAY_H + 2]
    n00, n11, n22 = ray_f[_RAY_NORM], ray_f[_RAY_NORM + 1], ray_f[_RAY_NORM + 2]
    n02, n12 = ray_f[_RAY_NORM + 3], ray_f[_RAY_NORM + 4]
    e0, e1, e2 = ray_f[_RAY_CENTER], ray_f[_RAY_CENTER + 1], ray_f[_RAY_CENTER + 2]
    cx, cy, k = ray_f[_RAY_DIST], ray_f[_RAY_DIST + 1], ray_f[_RAY_DIST + 2]
    both = use == 0
    on_x = use == 1
    for i in range(px.shape[0]):
        u = np.float64(px[i])
        v = np.float64(py[i])
        du = u - cx
        dv = v - cy
        f = 1.0 + k * (du * du + dv * dv)
        u = cx + du * f if has_dist else u
        v = cy + dv * f if has_dist else v
        x = x0 + x_step * i + np.float64(xo[i])
        y = y0 + np.float64(yo[i])
        # projector coordinate p of row k of the projector matrix (P | p4): its plane's
        # residual at C + t d is (a t - b) / |r| with r = P_k - p P_2, a = q_k - p q_2 for
        # q = P d, b = p h_2 - h_k for h = P C + p4; t for one division
        q2 = g6 * x + g7 * y + g8
        ax = g0 * x + g1 * y + g2 - q2 * u
        bx = h2 * u - h0
        ay = g3 * x + g4 * y + g5 - q2 * v
        by = h2 * v - h1
        nx = n00 + u * (n22 * u - 2.0 * n02)  # |r|^2
        ny = n11 + v * (n22 * v - 2.0 * n12)
        num = (ax * bx * ny + ay * by * nx) if both else (bx if on_x else by)
        den = (ax * ax * ny + ay * ay * nx) if both else (ax if on_x else ay)
        t = num / den
        x_out[i] = e0 + t * (m0 * x + m1 * y + m2)
        y_out[i] = e1 + t * (m3 * x + m4 * y + m5)
        z_out[i] = e2 + t * (m6 * x + m7 * y + m8)


@numba.njit(fastmath=_FAST, error_model="numpy", cache=_CACHE)
def _ray_points_flat(xc, yc, px, py, ray_f, ray_i):  # pragma: no cover - compiled
    """:func:`_ray_points` (and :func:`_ideal_panel`) on 1-D float64 arrays:
    ``(n, 3)`` float64."""
    n = xc.shape[0]
    out = np.empty((3, n))
    if ray_i[2]:
        ideal = np.empty((2, n))
        _ideal_panel(px, py, ray_f, ray_i, out[0], out[1], ideal[0], ideal[1])
        _ray_points(ideal[0], ideal[1], 0.0, 0.0, xc, 0.0, yc, ray_f, ray_i[0], False, out[0],
                    out[1], out[2])
    else:
        _ray_points(px, py, 0.0, 0.0, xc, 0.0, yc, ray_f, ray_i[0], ray_i[1] != 0, out[0],
                    out[1], out[2])
    return out.T.copy()

