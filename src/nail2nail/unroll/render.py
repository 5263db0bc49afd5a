"""Rendering the rolled-equivalent print: blend every camera's ridge signal on the print grid.

Print grid (the legacy convention of inked and live-scan rolled prints, ``docs/conventions.md``):
the image is the left-right mirror of the pad seen from outside, fingertip up, at `ppi` pixels
per inch; pixel ``(row, col)`` has its centre at print-plane coordinates

    ``s = s0 − col · pitch``,  ``t = t0 − row · pitch``,  ``pitch = 25.4 / ppi`` mm,

with ``(s, t)`` of :mod:`nail2nail.unroll.flatten`. Each camera's valid pixels are mapped to
``(s, t)`` and splatted bilinearly with their blending weight (fringe modulation × cos² of the
viewing angle × a wide feather at the edge of the camera's valid region), so that cameras fade
into each other across their overlaps and no seam is visible; small gaps are filled by a
normalised Gaussian of ≈ 0.6 px (of a 500-ppi pixel on finer grids, :data:`SUPPORT_PPI`).
"""

from __future__ import annotations

import numpy as np
import scipy.ndimage as ndi

from nail2nail.unroll._kernels import camera_points, rolled_map, splat, tail_percentile
from nail2nail.unroll.flatten import RolledMap
from nail2nail.unroll.ridges import masked_gaussian

__all__ = ["MAX_PRINT_PIXELS", "MM_PER_INCH", "SUPPORT_PPI", "PrintGrid", "binarize",
           "blend_cameras", "gray_levels", "normalized_print", "print_grid", "to_gray",
           "unsharp_mask"]

MM_PER_INCH = 25.4

#: The resolution whose pixel the data region of a print is found on, ppi: at a finer pitch
#: the camera samples no longer cover every print pixel (a full-resolution camera samples the
#: skin every 0.03 mm, 0.05-0.1 mm on the finger's sides: 1–3 samples per 500-ppi pixel), so
#: :func:`blend_cameras`'s gap filling, density threshold and closing keep their size in mm
#: from this pitch, and a 1000- or 2000-ppi print covers the skin a 500-ppi one does
SUPPORT_PPI = 500.0

#: Most pixels of a print grid (:func:`print_grid`): the unroll's peak memory is about 280
#: bytes per pixel of the grid (1.4 GB for a full-resolution finger's 5 M pixels at 2000 ppi),
#: so about 6 GB at this size: a 56 × 56 mm print plane at 2000 ppi, more than a finger's
MAX_PRINT_PIXELS = 20_000_000


class PrintGrid:
    """Geometry of a print image: ``s = s0 − col · pitch``, ``t = t0 − row · pitch``."""

    def __init__(self, s0: float, t0: float, pitch: float, shape: tuple[int, int]):
        self.s0, self.t0, self.pitch = float(s0), float(t0), float(pitch)
        self.shape = (int(shape[0]), int(shape[1]))

    @property
    def ppi(self) -> float:
        """Pixels per inch."""
        return MM_PER_INCH / self.pitch

    def pixel(self, st) -> tuple[np.ndarray, np.ndarray]:
        """``(row, col)`` (float) of print-plane points ``(N, 2)``, mm."""
        st = np.asarray(st, dtype=np.float64)
        return (self.t0 - st[:, 1]) / self.pitch, (self.s0 - st[:, 0]) / self.pitch

    def plane(self, row, col) -> np.ndarray:
        """Print-plane ``(s, t)`` (N, 2), mm, of pixel positions."""
        return np.stack([self.s0 - np.asarray(col) * self.pitch,
                         self.t0 - np.asarray(row) * self.pitch], axis=-1)

    def describe(self) -> dict:
        """JSON-ready geometry."""
        return {"ppi": round(self.ppi, 4), "pitch_mm": self.pitch, "shape": list(self.shape),
                "s_of_col0_mm": round(self.s0, 5), "t_of_row0_mm": round(self.t0, 5),
                "mapping": "s = s_of_col0 - col * pitch; t = t_of_row0 - row * pitch "
                           "(s around the finger towards axis x pad, t towards the tip; "
                           "legacy convention: mirror of the pad view, tip up)"}


def print_grid(st_all, *, ppi: float, margin_mm: float = 1.0) -> PrintGrid:
    """The print grid covering print-plane points with a margin (legacy convention).

    Parameters
    ----------
    st_all : (N, 2) float, or a list of (N_i, 2) float
        Print-plane ``(s, t)`` of every sample, mm (a list: of every camera's samples).
    ppi : float
        Resolution, pixels per inch (``pitch = 25.4 / ppi`` mm).
    margin_mm : float
        Margin around the 0.01–99.99 percentile extent of the points, mm.

    Returns
    -------
    PrintGrid
        ``s0``, ``t0`` snapped to the pitch, so prints of one finger at one ppi share a lattice.

    Raises
    ------
    ValueError
        If `ppi` is not positive, or the grid would exceed :data:`MAX_PRINT_PIXELS`.
    """
    if not (ppi > 0 and np.isfinite(ppi)):
        raise ValueError(f"ppi: expected a positive number, got {ppi}")
    pitch = MM_PER_INCH / ppi
    parts = [np.asarray(p, dtype=np.float64) for p in st_all] \
        if isinstance(st_all, (list, tuple)) else [np.asarray(st_all, dtype=np.float64)]
    # np.percentile(st_all, q, axis=0), found without sorting (nor concatenating)
    lo = np.array([tail_percentile([p[:, k] for p in parts], 0.01) for k in range(2)]) \
        - margin_mm
    hi = np.array([tail_percentile([p[:, k] for p in parts], 99.99) for k in range(2)]) \
        + margin_mm
    # snap s0, t0 to the pitch so that prints of one finger at one ppi share a lattice
    s0 = np.ceil(hi[0] / pitch) * pitch
    t0 = np.ceil(hi[1] / pitch) * pitch
    size = np.array([s0, t0]) - lo
    n = np.ceil(size / pitch) + 1  # (w, h), as float: no overflow
    if not (np.isfinite(n).all() and n[0] * n[1] <= MAX_PRINT_PIXELS):
        raise ValueError(f"st_all: the print plane's points span {size[0]:.4g} x {size[1]:.4g} "
                         f"mm, {n[0]:.4g} x {n[1]:.4g} px at {ppi:g} ppi: more than "
                         f"{MAX_PRINT_PIXELS} px (MAX_PRINT_PIXELS); a lower ppi, or a scan of "
                         "one finger")
    return PrintGrid(s0, t0, pitch, (int(n[1]), int(n[0])))


def _splat(grid: PrintGrid, st, values, weights):
    """Bilinear splat: ``Σ w·k·v``, ``Σ w·k`` and ``Σ k`` (the sample density) per print
    pixel, k the bilinear kernel (:func:`~nail2nail.unroll._kernels.splat`)."""
    return splat(grid, st, values, weights)


def blend_cameras(grid: PrintGrid, samples, *, fill_sigma_px: float = 0.6,
                  min_support: float = 0.3, edge_sigma_px: float = 0.0,
                  min_piece: float = 0.1, support_pitch: float | None = None):
    """Blend per-camera samples ``(st (N, 2), value (N,), weight (N,))`` on the print grid.

    Parameters
    ----------
    grid : PrintGrid
    samples : sequence of (st, value, weight)
        One entry per camera.
    fill_sigma_px : float
        σ of the normalised Gaussian that fills gaps between splatted samples, print px (of
        a pixel of `support_pitch` when the grid is finer).
    min_support : float
        A pixel has data where the smoothed sample density (samples per pixel, per pixel of
        `support_pitch` when the grid is finer) is at least this.
    edge_sigma_px : float
        σ of the Gaussian that smooths the outline of the data region, print px (0: none).
    min_piece : float
        Pieces of the data region smaller than this fraction of the largest are dropped.
    support_pitch : float, optional
        When the grid's pitch is finer than this (mm), `fill_sigma_px`, `min_support` and the
        closing of pinholes keep the size in mm they have at this pitch (the fill's σ with
        the bilinear splat's own spread), so that the data region does not depend on the pitch
        (``unroll_scans`` gives 500 ppi's, :data:`SUPPORT_PPI`): at a pitch finer than the
        samples' spacing, a fill of 0.6 px leaves most pixels without a sample near enough.

    Returns
    -------
    value : (H, W) float32
        Weighted mean of the cameras' values; NaN off `mask`.
    mask : (H, W) bool
        Pixels with data.
    share : (n_cameras, H, W) float32
        Each camera's fraction of the blending weight per pixel.
    """
    h, w = grid.shape
    closing = 2
    if support_pitch is not None and support_pitch > grid.pitch:
        ratio = support_pitch / grid.pitch
        # the same spread in mm, the bilinear splat's own included (variance 1/6 px² per axis)
        fill_sigma_px = float(np.sqrt(ratio * ratio * (fill_sigma_px**2 + 1 / 6) - 1 / 6))
        min_support /= ratio * ratio  # a density: samples per pixel
        closing = round(closing * ratio)
    num = np.zeros((h, w))
    count = np.zeros((h, w))
    per_camera = []
    for st, value, weight in samples:
        n_, d_, c_ = _splat(grid, st, value, weight)
        num += n_
        count += c_
        per_camera.append(d_)

    def g(a):
        return ndi.gaussian_filter(a, fill_sigma_px, truncate=3.0) if fill_sigma_px > 0 else a

    per_camera = [g(d) for d in per_camera]
    num_s, den_s = g(num), sum(per_camera)
    support = g(count)
    mask = support >= min_support
    # close pinholes, drop specks: the print's data region is one solid piece
    mask = ndi.binary_closing(mask, iterations=closing, border_value=0)
    mask = ndi.binary_fill_holes(mask)
    mask &= den_s > 1e-9 * max(float(den_s.max()), 1e-300)
    if edge_sigma_px > 0:
        # a smooth outline: the support's edge is frayed along the ridges (grazing pixels on
        # ridge flanks come and go), and every frayed tip would read as a ridge ending
        mask = ndi.gaussian_filter(mask.astype(np.float32), edge_sigma_px) > 0.5
        mask &= den_s > 1e-9 * max(float(den_s.max()), 1e-300)
    label, n = ndi.label(mask)
    if n > 1:
        # specks go; a large piece stays: a band of skin no camera decoded (a shadow line
        # across a tilted finger) can part the tip's cap from the body, and dropping the cap
        # would cut the print's length from the wrong end
        sizes = np.bincount(label.ravel())
        sizes[0] = 0
        keep = sizes >= min_piece * sizes.max()
        keep[0] = False
        mask = keep[label]
    with np.errstate(invalid="ignore", divide="ignore"):
        value = np.where(mask, num_s / den_s, np.nan).astype(np.float32)
        total = np.maximum(den_s, 1e-300)
        share = np.stack([np.where(mask, d / total, 0) for d in per_camera]).astype(np.float32)
    return value, mask, share


def camera_samples(scan, signal, weight, flat):
    """``(st, value, weight)`` of one camera's pixels with data, for :func:`blend_cameras`.

    `signal` and `weight` are the camera's ridge signal and blending weight
    (:func:`~nail2nail.unroll.ridges.camera_layer`); `flat` maps world points to the print
    plane.
    """
    if isinstance(flat, RolledMap) and np.asarray(scan.xyz).dtype == np.float32:
        # the default map, compiled (the same float64 arithmetic, sample by sample)
        offsets, value, wt = camera_points(scan.xyz, signal, weight, flat.cylinder.center)
        return rolled_map(flat, offsets=offsets), value, wt
    ok = (weight > 0) & np.isfinite(signal)
    xyz = np.asarray(scan.xyz[ok], dtype=np.float64)
    return flat(xyz), signal[ok], weight[ok]


def normalized_print(value, mask, *, sigma_px: float, reduce: int = 1,
                     floor_fraction: float = 0.0) -> np.ndarray:
    """The ridge signal normalised locally: ``z = (v − mean) / rms`` over a Gaussian window.

    Parameters
    ----------
    value : (H, W) float
        Blended ridge signal, positive on ridge crests.
    mask : (H, W) bool
        Pixels with data.
    sigma_px : float
        σ of the normalisation window, print px (1 mm by default in :func:`unroll_scans`).
    reduce : int
        Block size of the reduced grid for the averages.
    floor_fraction : float
        The local RMS is floored at this fraction of its 90th percentile over the mask (the
        ridges' level), so that a faint region stays faint (0: no floor).

    Returns
    -------
    (H, W) float
        About unit local RMS on the mask; 0 off it.
    """
    mask = np.asarray(mask, dtype=bool)
    mean = masked_gaussian(value, mask, sigma_px, reduce=reduce)
    d = np.where(mask, value - mean, 0)
    rms = np.sqrt(masked_gaussian(d * d, mask, sigma_px, reduce=reduce))
    if floor_fraction > 0 and np.any(mask):
        level = rms[mask & np.isfinite(rms)]
        if level.size:
            rms = np.maximum(rms, floor_fraction * float(np.percentile(level, 90)))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(mask, d / np.maximum(rms, 1e-12), 0)


def unsharp_mask(z, mask, *, amount: float, sigma_px: float) -> np.ndarray:
    """``z + amount · (z − G_σ z)``, brought back to the RMS `z` had over `mask`.

    Gives the ridges back the edges that the capture chain blurred (camera and projector
    optics, subsurface scattering, the noise smoothing and the splatting); ``G_σ`` is a
    Gaussian normalised over the mask (:func:`~nail2nail.unroll.ridges.masked_gaussian`), so
    the print's edge is not pulled towards 0. A sinusoid of frequency ``f`` (cycles/px) gains
    ``1 + amount (1 − exp(−2π² σ² f²))`` before the RMS is brought back. Unsharp masking
    (Gonzalez and Woods, *Digital Image Processing*, "unsharp masking and highboost
    filtering"); no thesis equation covers it.

    Parameters
    ----------
    z : (H, W) float
        Normalised print signal (:func:`normalized_print`).
    mask : (H, W) bool
    amount : float
        0 (or `sigma_px` 0, or an empty mask): `z` unchanged.
    sigma_px : float
        σ of the Gaussian, print px.

    Returns
    -------
    (H, W) float
        0 off `mask`.
    """
    mask = np.asarray(mask, dtype=bool)
    if not (amount > 0 and sigma_px > 0 and mask.any()):
        return z
    blurred = np.nan_to_num(masked_gaussian(z, mask, sigma_px))
    sharp = np.where(mask, z + amount * (z - blurred), 0)
    before = float(np.sqrt(np.mean(z[mask] ** 2)))
    after = float(np.sqrt(np.mean(sharp[mask] ** 2)))
    return sharp * (before / after) if after > 0 else z


def gray_levels(z, mask) -> np.ndarray:
    """``I = 127.5 − 90 z``, rounded and clipped to 8 bits; white (255) off `mask`.

    A sinusoid of unit RMS spans ±1.41, i.e. about 0–255; ridges (``z > 0``) dark.

    Returns
    -------
    (H, W) uint8
    """
    gray = np.clip(np.rint(127.5 - 90.0 * z), 0, 255)
    return np.where(mask, gray, 255).astype(np.uint8)


def to_gray(value, mask, *, sigma_px: float, reduce: int = 1,
            floor_fraction: float = 0.0, sharpen: float = 0.0,
            sharpen_sigma_px: float = 0.0) -> np.ndarray:
    """8-bit print: ridges dark on white, contrast normalised locally (σ `sigma_px`).

    :func:`gray_levels` of :func:`normalized_print`, with `sharpen` first given an
    :func:`unsharp_mask` (the print :func:`unroll_scans` delivers).

    Parameters
    ----------
    value, mask, sigma_px, reduce, floor_fraction
        As :func:`normalized_print` (`value` (H, W) float, positive on ridge crests; `mask`
        (H, W) bool).
    sharpen : float
        Amount of the unsharp mask (0: none).
    sharpen_sigma_px : float
        σ of its Gaussian, print px (below the ridge period: 0.075 mm by default in
        :func:`unroll_scans`, where a 0.48 mm period keeps 61 % and its second harmonic
        14 %).

    Returns
    -------
    (H, W) uint8
    """
    z = normalized_print(value, mask, sigma_px=sigma_px, reduce=reduce,
                         floor_fraction=floor_fraction)
    z = unsharp_mask(z, mask, amount=sharpen, sigma_px=sharpen_sigma_px)
    return gray_levels(z, mask)


def binarize(gray, mask, *, period_px: float) -> np.ndarray:
    """Ridges black (0) on white (255), by a local-mean threshold.

    The binarised print of the thesis's Figure 37, by this project's method (the thesis does
    not give one): the image is smoothed (σ = period / 8) against pixel noise and thresholded
    at its local mean over a window of one ridge period (σ = period / 2).

    Parameters
    ----------
    gray : (H, W) uint8 or float
        Print, ridges dark.
    mask : (H, W) bool
        Pixels with data (white elsewhere).
    period_px : float
        Ridge period, print px (0.48 mm at the print's pitch in :func:`unroll_scans`).

    Returns
    -------
    (H, W) uint8
    """
    g = ndi.gaussian_filter(np.asarray(gray, np.float32), period_px / 8)
    local = masked_gaussian(g, mask, period_px / 2)
    ridge = mask & (g < local)
    return np.where(ridge, 0, 255).astype(np.uint8)
