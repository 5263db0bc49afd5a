"""Figures of the unroll stage: the print beside its truth, and each method's distortion map.

Each function draws on its own :class:`matplotlib.figure.Figure` (Agg canvas, no pyplot) and
writes one PNG atomically.
"""

from __future__ import annotations

import os
from pathlib import Path

from matplotlib.figure import Figure

from nail2nail.io._atomic import save_figure

__all__ = ["plot_distortion_maps", "plot_print_and_truth", "save_print_figures"]


def plot_print_and_truth(path: str | os.PathLike, rolled, truth_on_grid=None) -> Path:
    """The print, the true print on the same grid (if given) and the binarised print."""
    panels = [("unrolled print", rolled.image)]
    if truth_on_grid is not None:
        panels.append(("true print (same grid)", truth_on_grid))
    panels.append(("binarised", rolled.binary))
    h, w = rolled.image.shape
    fig = Figure(figsize=(3.2 * len(panels), 3.2 * h / w + 0.5))
    for i, (title, image) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), i + 1)
        ax.imshow(image, cmap="gray", vmin=0, vmax=255, interpolation="nearest")
        ax.set_title(title, fontsize=10)
        ax.set_axis_off()
    fig.suptitle(f"{rolled.method} unroll, {rolled.ppi:g} ppi, legacy convention (tip up)",
                 fontsize=10)
    fig.tight_layout()
    return save_figure(fig, Path(path), dpi=150)


def plot_distortion_maps(path: str | os.PathLike, maps: dict, *, scale_max: float = 0.05,
                         displacement_max_mm: float = 0.3) -> Path:
    """Per method, the local scale error and the residual displacement against the truth.

    Parameters
    ----------
    maps : dict
        ``method -> (scale_error_map, displacement_map)``, each ``(H, W)`` (NaN: no data), as
        :func:`~nail2nail.unroll.accuracy.geometric_accuracy` returns with ``maps=True``.
    """
    names = [m for m, v in maps.items() if v[0] is not None]
    fig = Figure(figsize=(2.6 * len(names) + 1.0, 6.4))
    for i, name in enumerate(names):
        scale, disp = maps[name]
        for row, (image, vmax) in enumerate(((scale, scale_max), (disp, displacement_max_mm))):
            ax = fig.add_subplot(2, len(names), row * len(names) + i + 1)
            im = ax.imshow(100 * image if row == 0 else image, cmap="magma",
                           vmin=0, vmax=100 * vmax if row == 0 else vmax)
            ax.set_axis_off()
            if row == 0:
                ax.set_title(name, fontsize=10)
            if i == len(names) - 1:
                fig.colorbar(im, ax=ax, fraction=0.05,
                             label="scale error %" if row == 0 else "displacement, mm")
    fig.suptitle("unrolling methods against the true skin coordinates (after one similarity)",
                 fontsize=10)
    return save_figure(fig, Path(path), dpi=110)


def save_print_figures(out: str | os.PathLike, prints: dict, maps: dict, *,
                       default: str | None = None) -> list[Path]:
    """Write ``print_vs_truth.png`` (the first method of `prints`) and ``distortion_maps.png``.

    Parameters
    ----------
    prints : dict
        ``method -> (RolledPrint, truth_on_grid or None)``.
    maps : dict
        ``method -> (scale_error_map, displacement_map)``.
    """
    out = Path(out)
    method = default or next(iter(prints))
    rolled, truth_on_grid = prints[method]
    paths = [plot_print_and_truth(out / "print_vs_truth.png", rolled, truth_on_grid)]
    if any(v[0] is not None for v in maps.values()):
        paths.append(plot_distortion_maps(out / "distortion_maps.png", maps))
    return paths
