"""Weighted quantiles: the one definition the unroll's statistics share."""

from __future__ import annotations

import numpy as np

__all__ = ["weighted_quantiles"]


def weighted_quantiles(x, w, qs) -> np.ndarray:
    """Quantiles of `x` with weights `w`: per ``q``, the smallest ``x`` whose cumulative
    weight fraction reaches ``q`` (no interpolation).

    Parameters
    ----------
    x, w : (N,) float
        Values and their non-negative weights (e.g. triangle areas, viewing factors).
    qs : sequence of float
        Quantiles in ``[0, 1]``.

    Returns
    -------
    (len(qs),) float64
        Unweighted percentiles (``np.percentile``) when the weights sum to 0.

    Examples
    --------
    >>> weighted_quantiles(np.array([1.0, 2.0, 3.0]), np.array([1.0, 1.0, 2.0]), [0.5, 0.9])
    array([2., 3.])
    """
    x = np.asarray(x, dtype=np.float64)
    w = np.asarray(w, dtype=np.float64)
    qs = np.asarray(qs, dtype=np.float64)
    total = w.sum()
    if not total > 0:
        return np.percentile(x, 100 * qs)
    if x.size <= _SORT_BELOW or not np.isfinite(x).all():
        order = np.argsort(x)
        cw = np.cumsum(w[order]) / total
        return x[order][np.minimum(np.searchsorted(cw, qs), len(x) - 1)]
    # the same answer without sorting everything: the cumulative weight over value bins finds
    # the bin each quantile falls in, and only that bin's values are sorted (O(N))
    lo, hi = float(x.min()), float(x.max())
    if not hi > lo:
        return np.full(qs.shape, lo)
    nbins = _BINS
    which = np.minimum(((x - lo) * (nbins / (hi - lo))).astype(np.intp), nbins - 1)
    cw_bins = np.cumsum(np.bincount(which, w, nbins)) / total
    out = np.empty(qs.shape)
    for i, q in enumerate(qs.ravel()):
        b = min(int(np.searchsorted(cw_bins, q)), nbins - 1)
        while b < nbins - 1 and not (which == b).any():  # an empty last bin: the next one
            b += 1
        sel = which == b
        xs, ws = x[sel], w[sel]
        order = np.argsort(xs)
        cw = (cw_bins[b - 1] if b else 0.0) + np.cumsum(ws[order]) / total
        out.ravel()[i] = xs[order][min(int(np.searchsorted(cw, q)), len(xs) - 1)]
    return out


#: below this many values the weighted quantiles sort them all
_SORT_BELOW = 4096
#: value bins of the sort-free path
_BINS = 4096
