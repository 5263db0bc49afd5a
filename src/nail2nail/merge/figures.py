"""Figures of the merge: error heat map and histogram, corresponding points, super-scan renders.

Every function draws on its own :class:`matplotlib.figure.Figure` (Agg canvas, no pyplot and no
global backend change) and writes one PNG atomically. The figures follow the thesis: the marked
corresponding pixels of two cameras (Fig. 32, 34) and their world points in 3D (Fig. 33, 35).
"""

from __future__ import annotations

import os
from pathlib import Path

import numba
import numpy as np
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
from matplotlib.figure import Figure

from nail2nail._numba_cache import cache_enabled
from nail2nail.io._atomic import atomic_path
from nail2nail.merge.correspondence import Correspondence
from nail2nail.merge.statistics import merge_statistics

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


def _display_factor(shape: tuple[int, int], fig: Figure, ax) -> int:
    """Integer block size that brings an image of `shape` down to about the pixels the axes
    `ax` show it on (at least 1): matplotlib would resample it to those anyway, and resampling
    a full camera frame is most of a figure's time."""
    box = ax.get_position()
    width, height = fig.get_size_inches() * fig.dpi
    return max(1, int(min(shape[0] / (box.height * height), shape[1] / (box.width * width))))


def _block_mean(image: np.ndarray, factor: int) -> np.ndarray:
    """Mean of the finite values of each `factor` × `factor` block, NaN where a block has none.

    Block ``(i, j)`` covers the pixels ``[i f, (i + 1) f) × [j f, (j + 1) f)`` (the last ones
    cut at the image's edge).
    """
    if factor == 1:
        return image
    return _block_mean_kernel(np.ascontiguousarray(image, dtype=np.float64), int(factor))


@numba.njit(cache=cache_enabled(), nogil=True)
def _block_mean_kernel(image, factor):
    h, w = image.shape
    bh, bw = -(-h // factor), -(-w // factor)
    total = np.zeros((bh, bw))
    count = np.zeros((bh, bw), dtype=np.int64)
    for r in range(h):
        for c in range(w):
            if np.isfinite(image[r, c]):
                total[r // factor, c // factor] += image[r, c]
                count[r // factor, c // factor] += 1
    out = np.full((bh, bw), np.nan)
    for i in range(bh):
        for j in range(bw):
            if count[i, j]:
                out[i, j] = total[i, j] / count[i, j]
    return out


def _show_grey(fig: Figure, ax, image) -> None:
    """`image` in grey (0 black, 1 white) on `ax`, pixel ``(r, c)`` at ``(c, r)``, at about
    the resolution it is shown at (blocks averaged) and as RGB bytes: matplotlib then neither
    colour-maps nor resamples a full camera frame."""
    grey = _grey(image)
    h, w = grey.shape
    f = _display_factor(grey.shape, fig, ax)
    grey = _block_mean(grey, f)
    rgb = ScalarMappable(Normalize(0, 1), "gray").to_rgba(grey, bytes=True)[..., :3]
    ax.imshow(rgb, extent=(-0.5, grey.shape[1] * f - 0.5, grey.shape[0] * f - 0.5, -0.5))
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)


def _save(fig: Figure, path: str | os.PathLike) -> Path:
    """Write `fig` as PNG at `path` atomically, at 100 dpi, zlib level 3 (the default 6 takes
    twice as long for files a few per cent smaller)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100, pil_kwargs={"compress_level": 3})
    return path


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
    if vmax is None:
        vmax = float(np.percentile(d, 99)) if d.size else 1.0
    fig = Figure(figsize=(6, 6.5))
    ax = fig.add_subplot()
    if background is not None:
        _show_grey(fig, ax, background)
    # the samples at about the display's resolution: one cell of each block (what the nearest
    # neighbour interpolation of the full grid shows; a mean would smooth the errors away)
    f = _display_factor(small.shape, fig, ax)
    small = small[::f, ::f]
    cell = s * f
    extent = (-s / 2, small.shape[1] * cell - s / 2, small.shape[0] * cell - s / 2, -s / 2)
    errors = ScalarMappable(Normalize(0, max(vmax, 1e-9)), "inferno")
    ax.imshow(errors.to_rgba(np.ma.masked_invalid(small), bytes=True), extent=extent,
              interpolation="nearest")
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    fig.colorbar(errors, ax=ax, label="merge error (mm)")
    stats = merge_statistics(d)["distance_mm"]
    ax.set_title(title or f"{corr.parent_name} → {corr.child_name}: {corr.n_pairs} pairs, "
                 f"median {1e3 * stats['median']:.1f} µm")
    ax.set_xlabel("column (px)")
    ax.set_ylabel("row (px)")
    return _save(fig, path)


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
    if d.size:  # the bars as one outline (ax.hist: a patch per bar, slower to draw)
        counts, edges = np.histogram(1e3 * d, bins=bins)
        ax.stairs(counts, edges, fill=True, color="tab:blue", alpha=0.8)
        for key, style in (("median", "-"), ("p95", "--")):
            ax.axvline(1e3 * stats[key], color="k", linestyle=style,
                       label=f"{key} {1e3 * stats[key]:.1f} µm")
        if d.max() >= 0.05:
            ax.axvline(50.0, color="tab:red", linestyle=":", label="0.05 mm")
        ax.legend()
    ax.set_xlabel("merge error (µm)")
    ax.set_ylabel("pairs")
    ax.set_title(title or f"{d.size} pairs, {100 * stats['frac_below_0_05']:.1f} % below 0.05 mm")
    # what tight_layout gives with counts of up to six digits, without its cost
    fig.subplots_adjust(left=0.15, right=0.975, bottom=0.146, top=0.907)
    return _save(fig, path)


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
    return _save(fig, path)


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
    from PIL import Image, ImageDraw

    # matplotlib's layout of this figure (two image axes side by side, titled, without axis
    # lines, as tight_layout places them), drawn directly: a quarter of the time
    width, height = _MARKED_SIZE
    left, right, bottom, top, wspace = _MARKED_BOX
    box_w = (right - left) * width / (2 + wspace)
    box_h = (top - bottom) * height
    canvas = Image.new("RGB", (width, height), (255, 255, 255))
    draw = ImageDraw.Draw(canvas)
    font = _title_font()
    dots = []
    for k, (img, pts, colour, name) in enumerate((
        (parent_image, corr.parent_rc[sel], (255, 0, 0), corr.parent_name),
        (child_image, corr.child_rc[sel], (0, 0, 255), corr.child_name),
    )):
        grey = _grey(img)
        h, w = grey.shape
        scale = min(box_w / w, box_h / h)  # aspect equal, centred in the axes' box
        x0 = left * width + k * box_w * (1 + wspace) + (box_w - w * scale) / 2
        y0 = (1 - top) * height + (box_h - h * scale) / 2
        size = (max(round(w * scale), 1), max(round(h * scale), 1))
        f = max(1, int(min(h / size[1], w / size[0])))
        level = np.clip(_block_mean(grey, f) * 256, 0, 255).astype(np.uint8)  # the grey map
        canvas.paste(Image.fromarray(level).resize(size, Image.Resampling.BILINEAR).convert(
            "RGB"), (round(x0), round(y0)))
        dots.append((x0 + (pts[:, 1] + 0.5) * scale, y0 + (pts[:, 0] + 0.5) * scale, colour))
        draw.text((x0 + w * scale / 2, y0 - 8), f"{name}: {sel.size} corresponding points",
                  fill=(0, 0, 0), font=font, anchor="md")
    image = np.array(canvas)
    for x, y, colour in dots:  # as matplotlib's markers of s=6 with their edge: 4 px across
        _draw_dots(image, x, y, 2.1, colour)
    return _write_png(image, path)


def _draw_dots(image: np.ndarray, x, y, radius: float, colour) -> None:
    """Antialiased discs of `radius` px centred on ``(x, y)`` (px, pixel centres at integers)
    painted over `image` ``(H, W, 3)`` uint8 in place, in one `colour`."""
    reach = int(np.ceil(radius + 1))
    off = np.arange(-reach, reach + 1)
    ix = np.round(x).astype(np.int64)[:, None, None] + off[None, None, :]
    iy = np.round(y).astype(np.int64)[:, None, None] + off[None, :, None]
    cover = np.clip(radius + 0.5 - np.hypot(ix - np.asarray(x)[:, None, None],
                                             iy - np.asarray(y)[:, None, None]), 0.0, 1.0)
    inside = (ix >= 0) & (ix < image.shape[1]) & (iy >= 0) & (iy < image.shape[0])
    alpha = np.zeros(image.shape[:2])
    np.maximum.at(alpha, (np.broadcast_to(iy, cover.shape)[inside],
                          np.broadcast_to(ix, cover.shape)[inside]), cover[inside])
    hit = np.nonzero(alpha)
    blend = alpha[hit][:, None]
    image[hit] = np.round(image[hit] * (1 - blend) + np.asarray(colour, float) * blend)


_MARKED_SIZE = (1000, 650)  # px, as the 10 × 6.5 in figure at 100 dpi
_MARKED_BOX = (0.015, 0.985, 0.023, 0.977, 0.031)  # left, right, bottom, top, wspace


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
    are stretched so their 99th percentile shows at 230. The image is drawn by a compiled
    z-buffer and written with Pillow (no matplotlib), the title in a 40 px band above it.

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
        `path`: a PNG of ``width × height`` px, ``height + 40`` with a title.

    Raises
    ------
    ValueError
        If `points` is not ``(N, 3)`` or has no finite point.
    """
    image = _render_image(points, normals=normals, colors=colors, elev=elev, azim=azim,
                          size=size, splat=splat)
    return _write_png(_with_title(image, title), path)


def _render_image(points, *, normals=None, colors=None, elev=0.0, azim=0.0, size=(600, 800),
                  splat=2) -> np.ndarray:
    """The picture of :func:`render_points`: ``(height, width, 3)`` uint8, white background."""
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points: expected shape (N, 3), got {pts.shape}")
    pts = _float_rows(pts)
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
    light = eye + 0.5 * up + 0.3 * right
    light /= np.linalg.norm(light)
    mean = (pts if finite.all() else pts[finite]).mean(axis=0, dtype=np.float64)
    if normals is None:
        normals = np.zeros((0, 3))
    if colors is None:
        colors, stretch = np.zeros((0, 3)), 1.0
    else:  # stretch dark albedo so the 99th percentile shows at 230
        colors = _float_rows(np.asarray(colors))
        stretch = 230.0 / max(_percentile_99(colors[finite]), 1.0)
    return _render_kernel(pts, finite, mean, eye, right, up, light, _float_rows(normals),
                          colors, stretch, int(size[0]), int(size[1]), int(splat))


def _float_rows(a: np.ndarray) -> np.ndarray:
    """`a` C-contiguous, as float32, float64 or uint8 (else float64), for the render kernel."""
    if a.dtype not in (np.float32, np.float64, np.uint8):
        a = a.astype(np.float64)
    return np.ascontiguousarray(a)


def _percentile_99(values: np.ndarray) -> float:
    """``np.percentile(values, 99)``; for uint8 values from their histogram, without a sort."""
    if values.dtype != np.uint8 or not values.size:
        return float(np.percentile(values.astype(np.float64), 99))
    cumulative = np.cumsum(np.bincount(values.ravel(), minlength=256))
    position = 0.99 * (values.size - 1)  # NumPy's linear method, its interpolation formula
    lo = int(np.floor(position))
    a, b = (float(np.searchsorted(cumulative, k, side="right")) for k in (lo, lo + 1))
    b = b if lo + 1 < values.size else a
    t = position - lo
    return b - (b - a) * (1 - t) if t >= 0.5 else a + (b - a) * t


@numba.njit(cache=cache_enabled(), nogil=True)
def _render_kernel(pts, finite, mean, eye, right, up, light, normals, colors, stretch, width,
                   height, splat):
    """Project, shade and z-buffer the points (see :func:`render_points`).

    Each point covers ``(2 splat + 1)²`` pixels; the largest depth (nearest the eye) wins, of
    equal depths the later point (and offset, row-major), as a stable sort would.
    """
    n = pts.shape[0]
    u, v, depth = np.empty(n), np.empty(n), np.empty(n)
    u_min = v_min = np.inf
    u_max = v_max = -np.inf
    for i in range(n):
        if not finite[i]:
            continue
        p0, p1, p2 = pts[i, 0] - mean[0], pts[i, 1] - mean[1], pts[i, 2] - mean[2]
        u[i] = p0 * right[0] + p1 * right[1] + p2 * right[2]
        v[i] = p0 * up[0] + p1 * up[1] + p2 * up[2]
        depth[i] = p0 * eye[0] + p1 * eye[1] + p2 * eye[2]
        u_min, u_max = min(u_min, u[i]), max(u_max, u[i])
        v_min, v_max = min(v_min, v[i]), max(v_max, v[i])
    scale = 0.9 * min(width / max(u_max - u_min, 1e-9), height / max(v_max - v_min, 1e-9))
    u_mid, v_mid = (u_max + u_min) / 2, (v_max + v_min) / 2
    image = np.full((height, width, 3), 255, dtype=np.uint8)
    zbuf = np.full((height, width), -np.inf)  # depths are finite: the first point always wins
    rgb = np.empty(3, dtype=np.uint8)
    for i in range(n):
        if not finite[i]:
            continue
        ix = int(np.round(width / 2 + scale * (u[i] - u_mid)))
        iy = int(np.round(height / 2 - scale * (v[i] - v_mid)))
        shade = 1.0
        if normals.shape[0]:
            n0, n1, n2 = (_finite_or_zero(normals[i, 0]), _finite_or_zero(normals[i, 1]),
                          _finite_or_zero(normals[i, 2]))
            if n0 * eye[0] + n1 * eye[1] + n2 * eye[2] < 0:  # face the viewer
                n0, n1, n2 = -n0, -n1, -n2
            shade = 0.2 + 0.8 * min(max(n0 * light[0] + n1 * light[1] + n2 * light[2], 0.0),
                                    1.0)
        for k in range(3):
            c = colors[i, k] * stretch if colors.shape[0] else 200.0
            rgb[k] = np.uint8(min(max(c * shade, 0.0), 255.0))
        for dy in range(-splat, splat + 1):
            y = iy + dy
            if y < 0 or y >= height:
                continue
            for dx in range(-splat, splat + 1):
                x = ix + dx
                if 0 <= x < width and depth[i] >= zbuf[y, x]:
                    zbuf[y, x] = depth[i]
                    image[y, x, 0] = rgb[0]
                    image[y, x, 1] = rgb[1]
                    image[y, x, 2] = rgb[2]
    return image


@numba.njit(cache=cache_enabled(), nogil=True)
def _finite_or_zero(x):
    """``np.nan_to_num`` of one value, as float64."""
    x = np.float64(x)
    if np.isnan(x):
        return 0.0
    if np.isinf(x):
        return 1.7976931348623157e308 if x > 0 else -1.7976931348623157e308
    return x


_TITLE_PX = 40  # height of the title band above a render, px
_TITLE_FONT_PX = 16  # matplotlib's suptitle ("large": 12 pt at 100 dpi) as DejaVu Sans draws it


def _with_title(image: np.ndarray, title: str | None) -> np.ndarray:
    """`image` below a white band with `title` in it (unchanged without a title), placed as
    matplotlib's suptitle: centred, its top at 2 % of the height."""
    if not title:
        return image
    from PIL import Image, ImageDraw

    height, width = image.shape[:2]
    canvas = Image.new("RGB", (width, height + _TITLE_PX), (255, 255, 255))
    canvas.paste(Image.fromarray(image), (0, _TITLE_PX))
    ImageDraw.Draw(canvas).text((width / 2, round(0.02 * (height + _TITLE_PX))), title,
                                fill=(0, 0, 0), font=_title_font(), anchor="mt")
    return np.asarray(canvas)


def _title_font():
    """DejaVu Sans (matplotlib's default font) at the suptitle's size; Pillow's own without it."""
    import matplotlib
    from PIL import ImageFont

    try:
        return ImageFont.truetype(
            str(Path(matplotlib.get_data_path()) / "fonts" / "ttf" / "DejaVuSans.ttf"),
            _TITLE_FONT_PX)
    except OSError:
        return ImageFont.load_default(_TITLE_FONT_PX)


def _write_png(image: np.ndarray, path: str | os.PathLike) -> Path:
    """Write an RGB image as PNG at `path`, atomically (zlib level 3: a render's flat
    background and smooth shading deflate as well as at the default level 6, faster)."""
    from PIL import Image

    path = Path(path)
    with atomic_path(path) as tmp:
        Image.fromarray(image).save(tmp, format="PNG", compress_level=3)
    return path
