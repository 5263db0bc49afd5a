"""Figures of the merge: error heat map and histogram, corresponding points, super-scan renders.

Every function draws on its own :class:`matplotlib.figure.Figure` (Agg canvas, no pyplot and no
global backend change) and writes one PNG atomically. The figures follow the thesis: the marked
corresponding pixels of two cameras (Fig. 32, 34) and their world points in 3D (Fig. 33, 35).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from ..io._atomic import save_figure
from .correspondence import Correspondence
from .statistics import merge_statistics

__all__ = [
    "plot_correspondence_images",
    "plot_correspondences_3d",
    "plot_merge_heatmap",
    "plot_merge_histogram",
    "render_points",
]


def _check_corr(corr) -> Correspondence:
    if not isinstance(corr, Correspondence):
        raise TypeError(f"corr: expected a Correspondence, got {type(corr).__name__}")
    return corr


def _grey(image) -> np.ndarray:
    img = np.nan_to_num(np.asarray(image, dtype=np.float64))
    if img.ndim != 2:
        raise ValueError(f"background: expected a (H, W) image, got shape {img.shape}")
    return img


def plot_merge_heatmap(
    corr: Correspondence,
    path: str | os.PathLike,
    *,
    background=None,
    vmax: float | None = None,
    title: str | None = None,
) -> Path:
    """Merge error over the parent image (mm), each sample drawn as its `stride` cell.

    Parameters
    ----------
    corr : Correspondence
    path : path
        PNG to write.
    background : (H, W) float, optional
        Parent image drawn in grey beneath (its albedo).
    vmax : float, optional
        Top of the colour scale, mm; default the 99th percentile.
    title : str, optional

    Returns
    -------
    Path
        `path`.
    """
    corr = _check_corr(corr)
    s = corr.stride
    h, w = corr.parent_shape
    small = np.full((-(-h // s), -(-w // s)), np.nan)
    d = corr.distance_mm
    small[corr.parent_rc[:, 0] // s, corr.parent_rc[:, 1] // s] = d
    extent = (-s / 2, (small.shape[1] - 1) * s + s / 2, (small.shape[0] - 1) * s + s / 2, -s / 2)
    if vmax is None:
        vmax = float(np.percentile(d, 99)) if d.size else 1.0
    fig = Figure(figsize=(6, 6.5))
    ax = fig.add_subplot()
    if background is not None:
        ax.imshow(_grey(background), cmap="gray", vmin=0, vmax=1,
                  extent=(-0.5, w - 0.5, h - 0.5, -0.5))
    im = ax.imshow(np.ma.masked_invalid(small), cmap="inferno", vmin=0, vmax=max(vmax, 1e-9),
                   extent=extent, interpolation="nearest")
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    fig.colorbar(im, ax=ax, label="merge error (mm)")
    stats = merge_statistics(d)["distance_mm"]
    ax.set_title(title or f"{corr.parent_name} → {corr.child_name}: {corr.n_pairs} pairs, "
                 f"median {1e3 * stats['median']:.1f} µm")
    ax.set_xlabel("column (px)")
    ax.set_ylabel("row (px)")
    return save_figure(fig, path)


def plot_merge_histogram(
    distance_mm, path: str | os.PathLike, *, bins: int = 60, title: str | None = None
) -> Path:
    """Histogram of merge errors (µm) with the median, p95 and the thesis's 0.05 mm marked.

    Parameters
    ----------
    distance_mm : (N,) float
    path : path
    bins : int
    title : str, optional

    Returns
    -------
    Path
    """
    d = np.asarray(distance_mm, dtype=np.float64).ravel()
    stats = merge_statistics(d)["distance_mm"]
    fig = Figure(figsize=(6, 4))
    ax = fig.add_subplot()
    if d.size:
        ax.hist(1e3 * d, bins=bins, color="tab:blue", alpha=0.8)
        for key, style in (("median", "-"), ("p95", "--")):
            ax.axvline(1e3 * stats[key], color="k", linestyle=style,
                       label=f"{key} {1e3 * stats[key]:.1f} µm")
        if d.max() >= 0.05:
            ax.axvline(50.0, color="tab:red", linestyle=":", label="0.05 mm")
        ax.legend()
    ax.set_xlabel("merge error (µm)")
    ax.set_ylabel("pairs")
    ax.set_title(title or f"{d.size} pairs, {100 * stats['frac_below_0_05']:.1f} % below 0.05 mm")
    fig.tight_layout()
    return save_figure(fig, path)


def _every(corr: Correspondence, every: int) -> np.ndarray:
    rc = corr.parent_rc
    return np.flatnonzero((rc[:, 0] % every == 0) & (rc[:, 1] % every == 0))


def plot_correspondences_3d(
    corr: Correspondence,
    path: str | os.PathLike,
    *,
    every: int = 20,
    labels: tuple[str, str] | None = None,
    title: str | None = None,
) -> Path:
    """World points of corresponding pixels in 3D, parent red dots, child blue crosses.

    The thesis's Figures 33 and 35 (appendix: every 20th pixel).

    Parameters
    ----------
    corr : Correspondence
    path : path
    every : int
        Plot the pairs on every `every`-th parent row and column (a multiple of the stride).
    labels : (str, str), optional
        Legend of parent and child; default their names.
    title : str, optional

    Returns
    -------
    Path
    """
    import mpl_toolkits.mplot3d  # noqa: F401  (registers the 3d projection)

    corr = _check_corr(corr)
    if every < 1:
        raise ValueError(f"every: expected a positive integer, got {every}")
    sel = _every(corr, every)
    a, b = corr.xyz_parent[sel], corr.xyz_child[sel]
    labels = labels or (corr.parent_name, corr.child_name)
    fig = Figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    ax.scatter(a[:, 0], a[:, 1], a[:, 2], c="r", marker=".", label=labels[0])
    ax.scatter(b[:, 0], b[:, 1], b[:, 2], c="b", marker="+", label=labels[1])
    ax.set_xlabel("Xw (mm)")
    ax.set_ylabel("Yw (mm)")
    ax.set_zlabel("Zw (mm)")
    ax.legend()
    d = np.linalg.norm(a - b, axis=-1)
    ax.set_title(title or f"{sel.size} corresponding points, median distance "
                 f"{1e3 * np.median(d) if d.size else float('nan'):.1f} µm")
    return save_figure(fig, path)


def plot_correspondence_images(
    corr: Correspondence,
    parent_image,
    child_image,
    path: str | os.PathLike,
    *,
    every: int = 20,
) -> Path:
    """The two camera images with corresponding pixels marked, parent red, child blue.

    The thesis's Figures 24, 32 and 34.

    Parameters
    ----------
    corr : Correspondence
    parent_image, child_image : (H, W) float
        Images (albedo) of the two cameras.
    path : path
    every : int
        Mark the pairs on every `every`-th parent row and column.

    Returns
    -------
    Path
    """
    corr = _check_corr(corr)
    sel = _every(corr, every)
    fig = Figure(figsize=(10, 6.5))
    for k, (img, pts, colour, name) in enumerate((
        (parent_image, corr.parent_rc[sel], "r", corr.parent_name),
        (child_image, corr.child_rc[sel], "b", corr.child_name),
    )):
        ax = fig.add_subplot(1, 2, k + 1)
        ax.imshow(_grey(img), cmap="gray", vmin=0, vmax=1)
        ax.scatter(pts[:, 1], pts[:, 0], s=6, c=colour)
        ax.set_title(f"{name}: {sel.size} corresponding points")
        ax.set_axis_off()
    fig.tight_layout()
    return save_figure(fig, path)


def render_points(
    points,
    path: str | os.PathLike,
    *,
    normals=None,
    colors=None,
    elev: float = 0.0,
    azim: float = 0.0,
    size: tuple[int, int] = (600, 800),
    splat: int = 2,
    title: str | None = None,
) -> Path:
    """Shaded orthographic render of a point cloud (a super scan) with a z-buffer.

    The view looks at the cloud's centre from the direction given by `azim` (degrees about the
    world Y axis, the finger axis; 0 looks from +Z, the centre camera) and `elev` (degrees above
    the X–Z plane). Each point is splatted over ``(2 splat + 1)²`` pixels, the nearest wins, and
    is shaded by ``0.2 + 0.8 max(n · l, 0)`` with the light above and right of the eye; colours
    are stretched so their 99th percentile shows at 230.

    Parameters
    ----------
    points : (N, 3) float
        World mm.
    path : path
    normals : (N, 3) float, optional
        Unit normals (flat shading without).
    colors : (N, 3) uint8, optional
        Vertex colours (grey 200 without).
    elev, azim : float
        Viewing direction, degrees.
    size : (int, int)
        Image ``(width, height)``, px.
    splat : int
        Splat radius, px.
    title : str, optional

    Returns
    -------
    Path
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points: expected shape (N, 3), got {pts.shape}")
    finite = np.isfinite(pts).all(axis=1)
    if not finite.any():
        raise ValueError("points: no finite point to render")
    a, e = np.radians(azim), np.radians(elev)
    eye = np.array([np.sin(a) * np.cos(e), np.sin(e), np.cos(a) * np.cos(e)])
    right = np.cross([0.0, 1.0, 0.0], eye)
    if np.linalg.norm(right) < 1e-9:
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(eye, right)
    p = pts[finite] - pts[finite].mean(axis=0)
    u, v, depth = p @ right, p @ up, p @ eye
    width, height = int(size[0]), int(size[1])
    scale = 0.9 * min(width / max(np.ptp(u), 1e-9), height / max(np.ptp(v), 1e-9))
    ix = np.round(width / 2 + scale * (u - (u.max() + u.min()) / 2)).astype(np.int64)
    iy = np.round(height / 2 - scale * (v - (v.max() + v.min()) / 2)).astype(np.int64)
    if normals is not None:
        n = np.nan_to_num(np.asarray(normals, dtype=np.float64)[finite])
        n *= np.where(n @ eye < 0, -1.0, 1.0)[:, None]  # face the viewer
        light = eye + 0.5 * up + 0.3 * right
        light /= np.linalg.norm(light)
        shade = 0.2 + 0.8 * np.clip(n @ light, 0, 1)
    else:
        shade = np.ones(p.shape[0])
    if colors is None:
        rgb = np.full((p.shape[0], 3), 200.0)
    else:  # stretch dark albedo so the 99th percentile shows at 230
        rgb = np.asarray(colors, dtype=np.float64)[finite]
        rgb *= 230.0 / max(float(np.percentile(rgb, 99)), 1.0)
    rgb = np.clip(rgb * shade[:, None], 0, 255).astype(np.uint8)
    offsets = np.arange(-splat, splat + 1)
    dy, dx = (g.ravel() for g in np.meshgrid(offsets, offsets, indexing="ij"))
    px = (ix[:, None] + dx).ravel()
    py = (iy[:, None] + dy).ravel()
    pd = np.repeat(depth, dx.size)
    pc = np.repeat(np.arange(p.shape[0]), dx.size)
    inside = (px >= 0) & (px < width) & (py >= 0) & (py < height)
    px, py, pd, pc = px[inside], py[inside], pd[inside], pc[inside]
    pixel = py * width + px
    order = np.lexsort((pd, pixel))  # by pixel, then depth: the last of each pixel is nearest
    last = np.r_[pixel[order][1:] != pixel[order][:-1], True]
    image = np.full((height * width, 3), 255, dtype=np.uint8)
    image[pixel[order][last]] = rgb[pc[order][last]]
    fig = Figure(figsize=(width / 100, height / 100 + (0.4 if title else 0)))
    ax = fig.add_axes((0, 0, 1, height / (height + (40 if title else 0))))
    ax.imshow(image.reshape(height, width, 3), interpolation="nearest")
    ax.set_axis_off()
    if title:
        fig.suptitle(title)
    return save_figure(fig, path)
