"""Plot helpers shared by the report's sections: figures without pyplot's global state."""

from __future__ import annotations

import numpy as np

#: Resolution of the report's figures (dots per inch): compact PNGs.
DPI = 100


def new_figure(width_in: float, height_in: float):
    """A ``matplotlib.figure.Figure`` of the given size (inches) at :data:`DPI`, no pyplot."""
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in), dpi=DPI, layout="constrained")


def decimation(shape, max_side: int) -> int:
    """Integer stride that brings an image of `shape` ``(H, W)`` to at most `max_side` px."""
    return max(1, int(np.ceil(max(shape[:2]) / max_side)))


def decimate(image: np.ndarray, max_side: int) -> np.ndarray:
    """Every k-th row and column of `image` ``(H, W, ...)`` so that its longest side is at
    most `max_side` (nearest samples: class maps keep their classes)."""
    step = decimation(image.shape, max_side)
    return image[::step, ::step]


def extent(shape) -> tuple[float, float, float, float]:
    """``imshow`` extent of an ``(H, W)`` image in full-resolution pixel coordinates (pixel
    ``(0, 0)`` the centre of the top-left pixel), whatever the decimation shown."""
    height, width = shape[:2]
    return (-0.5, width - 0.5, height - 0.5, -0.5)


def fmt(value, spec: str = ".3f") -> str:
    """A number for a table cell by format `spec` (``"—"`` for None or NaN; ints with
    thousands separators)."""
    if value is None:
        return "—"
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return f"{int(value):,}"
    value = float(value)
    return f"{value:{spec}}" if np.isfinite(value) else "—"


def percent(fraction, spec: str = ".1f") -> str:
    """A fraction (0..1) as a percentage cell by format `spec` (``"—"`` for None or NaN)."""
    return fmt(None if fraction is None else 100 * float(fraction), spec)
