"""Bilinear interpolation on pixel grids: the one implementation the stages share.

:func:`bilinear` is the NumPy form (values and derivatives at many positions);
:func:`bilinear_value` and :func:`bilinear_gradient` are the same arithmetic for one position
inside compiled kernels.
"""

from __future__ import annotations

import numba
import numpy as np

from nail2nail._numba_cache import cache_enabled

__all__ = ["bilinear", "bilinear_gradient", "bilinear_value"]


def bilinear(image: np.ndarray, r: np.ndarray, c: np.ndarray):
    """Bilinear value and derivatives of `image` at float pixel positions.

    Parameters
    ----------
    image : (H, W) or (H, W, k) array
        Values on the pixel grid (pixel centres at integer ``(r, c)``).
    r, c : (N,) float
        Row and column positions; positions outside ``[0, H − 1] × [0, W − 1]`` are
        extrapolated from the nearest border cell (callers mask them).

    Returns
    -------
    value, d_dr, d_dc : (N,) or (N, k)
        The interpolated value and its derivatives along rows and columns. NaN in any of the
        four neighbours makes them NaN.
    """
    h, w = image.shape[:2]
    r0 = np.clip(np.floor(r).astype(np.intp), 0, h - 2)
    c0 = np.clip(np.floor(c).astype(np.intp), 0, w - 2)
    fr, fc = r - r0, c - c0
    if image.ndim == 3:
        fr, fc = fr[:, None], fc[:, None]
    f00, f01 = image[r0, c0], image[r0, c0 + 1]
    f10, f11 = image[r0 + 1, c0], image[r0 + 1, c0 + 1]
    top = f00 + (f01 - f00) * fc
    bottom = f10 + (f11 - f10) * fc
    value = top + (bottom - top) * fr
    d_dc = (f01 - f00) * (1 - fr) + (f11 - f10) * fr
    d_dr = bottom - top
    return value, d_dr, d_dc


@numba.njit(cache=cache_enabled(), nogil=True, error_model="numpy")
def _cell(image, r, c):  # pragma: no cover - compiled
    """The four values (float64) of the cell of `image` that holds ``(r, c)``, clamped into the
    image, and the position's fractions ``fr, fc`` in it: :func:`bilinear`'s neighbours."""
    h, w = image.shape
    r0 = min(max(int(np.floor(r)), 0), h - 2)
    c0 = min(max(int(np.floor(c)), 0), w - 2)
    return (np.float64(image[r0, c0]), np.float64(image[r0, c0 + 1]),
            np.float64(image[r0 + 1, c0]), np.float64(image[r0 + 1, c0 + 1]), r - r0, c - c0)


@numba.njit(cache=cache_enabled(), nogil=True, error_model="numpy")
def bilinear_value(image, r, c):  # pragma: no cover - compiled
    """:func:`bilinear`'s value of a 2-D `image` at one position ``(r, c)``, compiled.

    Every value is read as float64 (a float32 image gives the result of its float64 copy);
    positions outside the image are extrapolated from the nearest border cell, as
    :func:`bilinear` does.
    """
    f00, f01, f10, f11, fr, fc = _cell(image, r, c)
    top = f00 + (f01 - f00) * fc
    bottom = f10 + (f11 - f10) * fc
    return top + (bottom - top) * fr


@numba.njit(cache=cache_enabled(), nogil=True, error_model="numpy")
def bilinear_gradient(image, r, c):  # pragma: no cover - compiled
    """:func:`bilinear`'s value and derivatives ``(value, d_dr, d_dc)`` of a 2-D `image` at one
    position ``(r, c)``, compiled; float64, extrapolated beyond the image as
    :func:`bilinear_value` is."""
    f00, f01, f10, f11, fr, fc = _cell(image, r, c)
    top = f00 + (f01 - f00) * fc
    bottom = f10 + (f11 - f10) * fc
    return top + (bottom - top) * fr, bottom - top, (f01 - f00) * (1 - fr) + (f11 - f10) * fr
