"""Statistics of the merge error: the summary figures of a set of pair distances, and the
pairs whose distance stands far above their neighbours' (thesis chapter four)."""

from __future__ import annotations

import numpy as np

from .._validation import as_int

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

    def block_median(values, block):
        # one sort by (block, value); the key orders distances up to 4 m exactly enough
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
    few = counts < _MIN_BLOCK_PAIRS
    g_median = np.median(d)
    median[few], mad[few] = g_median, np.median(np.abs(d - g_median))
    return d - median[block] > np.maximum(floor_mm, k_mad * mad[block])
