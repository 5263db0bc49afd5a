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
    order = np.argsort(x)
    cw = np.cumsum(w[order]) / total
    return x[order][np.minimum(np.searchsorted(cw, qs), len(x) - 1)]
