"""Shared input checks: one place that turns bad input into a clear error."""

from __future__ import annotations

import numpy as np

__all__ = ["as_float_array", "as_int", "as_matrix", "as_points"]


def as_float_array(value, name: str, *, dtype=np.float64) -> np.ndarray:
    """Return `value` as a floating-point array, or raise a `TypeError` naming `name`."""
    try:
        array = np.asarray(value)
    except (TypeError, ValueError) as exc:  # ragged input
        raise TypeError(f"{name}: expected a numeric array, got {type(value).__name__}") from exc
    if not (np.issubdtype(array.dtype, np.number) or array.dtype == bool):
        raise TypeError(f"{name}: expected a numeric array, got dtype {array.dtype}")
    if np.issubdtype(array.dtype, np.floating) and dtype is None:
        return array
    return array.astype(dtype if dtype is not None else np.float64, copy=False)


def as_points(
    value, name: str, dim: int, *, min_points: int = 0, finite: bool = True
) -> np.ndarray:
    """Return `value` as an ``(N, dim)`` float64 array.

    Raises
    ------
    ValueError
        If the shape is not ``(N, dim)``, there are fewer than `min_points` rows, or
        (with `finite`) any value is NaN or infinite.
    """
    array = as_float_array(value, name)
    if array.ndim != 2 or array.shape[1] != dim:
        raise ValueError(f"{name}: expected shape (N, {dim}), got {array.shape}")
    if array.shape[0] < min_points:
        raise ValueError(f"{name}: need at least {min_points} points, got {array.shape[0]}")
    if finite and not np.all(np.isfinite(array)):
        bad = np.flatnonzero(~np.all(np.isfinite(array), axis=1))
        raise ValueError(
            f"{name}: {bad.size} point(s) contain NaN or infinity (first at index {bad[0]})"
        )
    return array


def as_matrix(value, name: str, shape: tuple[int, int]) -> np.ndarray:
    """Return `value` as a finite float64 array of exactly `shape`."""
    array = as_float_array(value, name)
    if array.shape != shape:
        raise ValueError(f"{name}: expected shape {shape}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name}: contains NaN or infinity")
    return array


def as_int(value, name: str, *, minimum: int) -> int:
    """Return `value` as a Python ``int`` ≥ `minimum` (``bool`` is refused).

    Raises
    ------
    TypeError
        If `value` is not an integer.
    ValueError
        If it is below `minimum`.
    """
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise TypeError(f"{name}: expected an integer, got {type(value).__name__}")
    if value < minimum:
        raise ValueError(f"{name}: expected an integer ≥ {minimum}, got {value}")
    return int(value)
