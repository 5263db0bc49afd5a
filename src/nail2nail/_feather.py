"""The blending feather on a camera's pixel grid: the one implementation the stages share.

The merge's fusion (:mod:`nail2nail.merge.fusion`) and the print's blend
(:mod:`nail2nail.unroll.ridges`) weigh each camera's pixels by a ramp that rises from the edge
of its valid region, so that overlapping cameras cross-fade instead of meeting at a seam. The
ramp is positive on every valid pixel: where one camera alone sees the skin (the fingertip's
cap and the finger's sides at grazing view) any weight gives its data, and a zero there would
leave that skin out.
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.ndimage

from nail2nail._numba_cache import cache_enabled

__all__ = ["feather"]

#: Above this ramp width (px) the compiled window, which grows with the ramp, loses to the
#: full distance transform
_COMPILED_MAX_PX = 64


def feather(valid: np.ndarray, feather_px: float) -> np.ndarray:
    """Ramp from the edge of a camera's valid region: ``clip((d − 0.5) / feather_px, 0, 1)``.

    Parameters
    ----------
    valid : (H, W) bool
        The camera's valid pixels.
    feather_px : float
        Width of the ramp, camera px; ``≤ 0``: no ramp (1 everywhere).

    Returns
    -------
    (H, W) float64
        0 off `valid`; on it, with ``d`` the Euclidean distance (px, between pixel centres) to
        the nearest invalid pixel or to the outside of the image, ``(d − 0.5) / feather_px``
        clipped to 1: at least ``0.5 / feather_px`` on every valid pixel.

    Examples
    --------
    >>> valid = np.zeros((7, 9), bool)
    >>> valid[1:6, 1:8] = True
    >>> feather(valid, 2.0)[3].round(2).tolist()  # the middle row
    [0.0, 0.25, 0.75, 1.0, 1.0, 1.0, 0.75, 0.25, 0.0]
    """
    valid = np.ascontiguousarray(valid, dtype=bool)
    if not feather_px > 0:
        return np.ones(valid.shape)
    if feather_px > _COMPILED_MAX_PX:
        distance = scipy.ndimage.distance_transform_edt(np.pad(valid, 1))[1:-1, 1:-1]
        return np.where(valid, np.clip((distance - 0.5) / feather_px, 0, 1), 0.0)
    return _feather_kernel(valid, float(feather_px))


@numba.njit(cache=cache_enabled(), nogil=True, error_model="numpy")
def _feather_kernel(valid, feather_px):  # pragma: no cover - compiled
    """:func:`feather`: the exact Euclidean distance to the nearest invalid pixel (or beyond the
    image edge) where it is below ``reach = ceil(feather_px + 0.5)``, the ramp's end.

    A column sweep gives each pixel's distance along its column, capped at ``reach + 1``; the
    row pass takes the least ``dc² + column²`` over ``|dc| ≤ reach``. Below `reach` the
    nearest invalid pixel lies in that window with an uncapped column distance, so the result is
    the exact distance (as ``scipy.ndimage.distance_transform_edt``); from `reach` on it is at
    least `reach` and the ramp is 1 either way. Pixels whose window holds no column closer than
    `reach` to an invalid pixel skip the row pass.
    """
    h, w = valid.shape
    reach = int(np.ceil(feather_px + 0.5))
    cap = reach + 1
    column = np.empty((h, w), np.int32)
    for c in range(w):  # down: distance to the invalid pixel above (row -1 is invalid)
        column[0, c] = 1 if valid[0, c] else 0
    for r in range(1, h):
        for c in range(w):
            column[r, c] = min(column[r - 1, c] + 1, cap) if valid[r, c] else 0
    below = np.empty(w, np.int32)  # up: row h is invalid
    for c in range(w):
        below[c] = 0
    for r in range(h - 1, -1, -1):
        for c in range(w):
            below[c] = min(below[c] + 1, cap) if valid[r, c] else 0
            column[r, c] = min(column[r, c], below[c])
    out = np.zeros((h, w))
    left = np.empty(w, np.int64)
    for r in range(h):
        # a pixel farther than `reach` from every column closer than `reach` to an invalid
        # pixel (and from the image edge) has none of them in its window: the ramp is 1
        last = -1
        for c in range(w):
            if column[r, c] < reach:
                last = c
            left[c] = c - last
        last = w
        for c in range(w - 1, -1, -1):
            if column[r, c] < reach:
                last = c
            if not valid[r, c]:
                continue
            if left[c] > reach and last - c > reach:
                out[r, c] = 1.0
                continue
            best = cap * cap
            for dc in range(-reach, reach + 1):
                cc = c + dc
                g = column[r, cc] if 0 <= cc < w else 0
                best = min(best, dc * dc + g * g)
            value = (np.sqrt(np.float64(best)) - 0.5) / feather_px
            out[r, c] = min(max(value, 0.0), 1.0)
    return out
