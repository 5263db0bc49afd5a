"""Parameter uncertainties of a least-squares fit: the one Gauss–Newton covariance."""

from __future__ import annotations

import warnings

import numpy as np

__all__ = ["gauss_newton_std"]


def gauss_newton_std(jac, variance: float) -> np.ndarray:
    """Standard deviations ``(n,)`` of a fit's parameters: ``sqrt(diag(σ² (JᵀJ)⁺))``.

    Parameters
    ----------
    jac : (m, n) array
        Jacobian of the (weighted) residuals at the solution (``least_squares(...).jac``).
    variance : float
        The residuals' noise variance ``σ²`` in their own units (the caller's estimate: per
        degree of freedom, or robust).

    Returns
    -------
    (n,) float64
        In each parameter's units; the pseudo-inverse leaves an undetermined direction finite
        (its spread is then not meaningful), negative round-off is clipped to 0.

    Examples
    --------
    >>> gauss_newton_std(np.array([[1.0, 0.0], [0.0, 2.0]]), 4.0).tolist()
    [2.0, 1.0]
    """
    jac = np.asarray(jac, dtype=float)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cov = np.linalg.pinv(jac.T @ jac) * variance
    return np.sqrt(np.clip(np.diag(cov), 0, None))
