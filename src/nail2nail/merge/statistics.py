"""Statistics of the merge error: the summary figures of a set of pair distances, and the
pairs whose distance stands far above their neighbours' (thesis chapter four)."""

from __future__ import annotations

import numba
import numpy as np

from nail2nail._numba_cache import cache_enabled
from nail2nail._validation import as_int

__all__ = ["local_outliers", "merge_statistics"]

_MIN_BLOCK_PAIRS = 8  # fewer pairs in a block: the outlier test uses the statistics of all pairs


def merge_statistics(distance_mm) -> dict:
    """Summary of merge errors: Euclidean (mm) and the thesis's squared figure (mm²).

    Parameters
    ----------
    distance_mm : (N,) float
        World distance of corresponding points, mm.

    Returns
    -------
    dict
        ``{"distance_mm": {median, mean, rms, p90, p95, max, frac_below_0_05},
        "squared_mm2": {median, mean, max}}``; values are NaN (fractions 0) for no pairs.

    Examples
    --------
    >>> s = merge_statistics([0.01, 0.02, 0.03, 0.1])
    >>> s["distance_mm"]["median"], s["distance_mm"]["frac_below_0_05"]
    (0.025, 0.75)
    """
    d = np.asarray(distance_mm, dtype=np.float64).ravel()
    if np.any(~np.isfinite(d)) or np.any(d < 0):
        raise ValueError("distance_mm: expected finite, non-negative distances")
    if d.size == 0:
        nan = float("nan")
        return {
            "distance_mm": dict.fromkeys(
                ("median", "mean", "rms", "p90", "p95", "max"), nan
            ) | {"frac_below_0_05": 0.0},
            "squared_mm2": dict.fromkeys(("median", "mean", "max"), nan),
        }
    sq = d * d
    p90, p95 = np.percentile(d, [90, 95])
    return {
        "distance_mm": {
            "median": float(np.median(d)),
            "mean": float(d.mean()),
            "rms": float(np.sqrt(sq.mean())),
            "p90": float(p90),
            "p95": float(p95),
            "max": float(d.max()),
            "frac_below_0_05": float(np.mean(d < 0.05)),
        },
        "squared_mm2": {
            "median": float(np.median(sq)),
            "mean": float(sq.mean()),
            "max": float(sq.max()),
        },
    }


def local_outliers(rows, cols, distance_mm, *, block_px: int = 32, floor_mm: float = 0.025,
                   k_mad: float = 4.0) -> np.ndarray:
    """Pairs whose distance is far above the distances of the pairs around them.

    The parent image is cut into `block_px` × `block_px` blocks; a pair is an outlier when its
    distance exceeds its block's median by more than ``max(floor_mm, k_mad × MAD)`` (MAD: the
    block's median absolute deviation; blocks with fewer than 8 pairs use all pairs). A smooth
    offset between the cameras (a calibration error) moves the median, not the outliers.

    Parameters
    ----------
    rows, cols : (N,) int
        Parent pixels of the pairs.
    distance_mm : (N,) float
        Their merge errors, mm.
    block_px : int
    floor_mm : float
        Smallest excess over the median that counts, mm.
    k_mad : float

    Returns
    -------
    (N,) bool

    Examples
    --------
    >>> d = np.full(100, 0.005); d[7] = 0.2
    >>> np.flatnonzero(local_outliers(np.arange(100) // 10, np.arange(100) % 10, d)).tolist()
    [7]
    """
    block_px = as_int(block_px, "block_px", minimum=1)
    d = np.asarray(distance_mm, dtype=np.float64)
    rows, cols = np.asarray(rows, np.intp), np.asarray(cols, np.intp)
    if d.size == 0:
        return np.zeros(0, dtype=bool)

    n_cols = int(cols.max()) // block_px + 1
    block = (rows // block_px) * n_cols + cols // block_px
    n_blocks = int(block.max()) + 1
    median, mad, counts = _block_median_mad(d, block, n_blocks, _MIN_BLOCK_PAIRS)
    few = counts < _MIN_BLOCK_PAIRS
    if few[block].any():  # only then are the statistics of all pairs needed
        g_median = _middle(d.copy())  # np.median's value, by selection in place
        median[few], mad[few] = g_median, _middle(np.abs(d - g_median))
    return _above(d, block, median, mad, float(floor_mm), float(k_mad))


@numba.njit(cache=cache_enabled(), nogil=True)
def _block_median_mad(d, block, n_blocks, min_pairs):
    """Per block (ids `block`, ``0 ≤ id < n_blocks``): the median of the values `d` and the
    median of their absolute deviations from it (each the mean of the two middle values, an
    odd count's middle value twice), and the count; blocks of fewer than `min_pairs` values
    are left NaN. One counting sort by block, then each block's values sorted alone."""
    counts = np.zeros(n_blocks, dtype=np.int64)
    for b in block:
        counts[b] += 1
    start = np.zeros(n_blocks + 1, dtype=np.int64)
    for k in range(n_blocks):
        start[k + 1] = start[k] + counts[k]
    fill = start[:-1].copy()
    grouped = np.empty(d.size)
    for i in range(d.size):
        grouped[fill[block[i]]] = d[i]
        fill[block[i]] += 1
    median = np.full(n_blocks, np.nan)
    mad = np.full(n_blocks, np.nan)
    for k in range(n_blocks):
        n = counts[k]
        if n < min_pairs:
            continue
        values = grouped[start[k]:start[k + 1]]
        m = _middle(values, True)
        for i in range(n):
            values[i] = np.abs(values[i] - m)
        median[k] = m
        mad[k] = _middle(values, True)
    return median, mad, counts


@numba.njit(cache=cache_enabled(), nogil=True)
def _middle(values, nan_last=False):
    """The median of `values` (reordered in place): the mean of its two middle values in sorted
    order, ``0.5 * (sorted[(n - 1) // 2] + sorted[n // 2])``, by selection. With NaN present:
    NaN as np.median, or with `nan_last` the middle of the values sorted with NaN last (as
    the former sort by a (block, value) key)."""
    n = values.size
    lo, hi = (n - 1) // 2, n // 2
    for v in values:
        if np.isnan(v):
            if not nan_last:
                return np.nan
            values[:] = np.sort(values)
            return 0.5 * (values[lo] + values[hi])
    _select(values, lo)
    second = values[lo]
    if hi != lo:  # the smallest value above position lo
        second = values[hi]
        for i in range(hi + 1, n):
            if values[i] < second:
                second = values[i]
    return 0.5 * (values[lo] + second)


@numba.njit(cache=cache_enabled(), nogil=True)
def _select(a, kth):
    """Reorder `a` (no NaN) so that ``a[kth]`` is the value a sort puts there, with no larger
    value before it and no smaller one after it (quickselect, median-of-three pivots)."""
    left, right = 0, a.size - 1
    while right > left:
        mid = (left + right) // 2
        # median of three to a[mid], then Hoare partition around its value
        if a[mid] < a[left]:
            a[mid], a[left] = a[left], a[mid]
        if a[right] < a[left]:
            a[right], a[left] = a[left], a[right]
        if a[right] < a[mid]:
            a[right], a[mid] = a[mid], a[right]
        pivot = a[mid]
        i, j = left, right
        while i <= j:
            while a[i] < pivot:
                i += 1
            while pivot < a[j]:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if kth <= j:
            right = j
        elif kth >= i:
            left = i
        else:
            return


@numba.njit(cache=cache_enabled(), nogil=True)
def _above(d, block, median, mad, floor_mm, k_mad):
    """``d − median[block] > maximum(floor_mm, k_mad × mad[block])`` (NaN propagated as
    np.maximum)."""
    out = np.empty(d.size, dtype=np.bool_)
    for i in range(d.size):
        limit = k_mad * mad[block[i]]
        if not (np.isnan(limit) or limit > floor_mm):
            limit = floor_mm
        out[i] = d[i] - median[block[i]] > limit
    return out
