"""Synthetic fingerprints: orientation field with core and delta, Gabor ridge growth, minutiae.

After SFinGe (Cappelli, Maio, Maltoni, *Synthetic fingerprint-image generation*, ICPR 2000,
doi:10.1109/ICPR.2000.903586):

1. orientation field of the zero-pole model (Sherlock & Monro 1993,
   doi:10.1016/0031-3203(93)90087-7): ``θ(z) = θ∞ + ½ [arg(z − z_core) − arg(z − z_delta)]``;
2. ridge growth: starting from sparse random seeds, the image is filtered again and again with
   Gabor filters tuned to the local orientation and ridge frequency (``n_orientations`` kernel
   banks, linear interpolation between neighbouring orientations) and clipped, until ridges fill
   the image; minutiae arise where growing fronts meet;
3. ridge field ``r ∈ [−1, 1]`` (+1 on ridge crests) normalised by its local RMS;
4. minutiae: ridges (``r > 0``) thinned (Zhang & Suen 1984, doi:10.1145/357994.358023), crossing
   number 1 (ending) or 3 (bifurcation), spurious close pairs and border hits removed.

Coordinates: the print lives in the finger's rolled-print plane ``(u, v)`` in mm (``u`` across
the finger, ``v`` along it towards the tip); image column ``c`` is ``u = u0 + c · pitch`` and row
``r`` is ``v = v0 − r · pitch`` (the tip is at the top), 500 ppi by default.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.fft
import scipy.ndimage as ndi

__all__ = ["Fingerprint", "find_minutiae", "generate_fingerprint", "orientation_field"]

MM_PER_INCH = 25.4


@dataclass
class Fingerprint:
    """A ridge pattern on the rolled-print plane.

    Attributes
    ----------
    ridges : (H, W) float32
        Ridge field in ``[−1, 1]``, +1 on ridge crests.
    u0, v0 : float
        ``(u, v)`` of the centre of pixel ``[0, 0]``, mm.
    pitch : float
        Pixel size, mm (``25.4 / 500`` at 500 ppi).
    orientation : (H, W) float32
        Ridge orientation in the ``(u, v)`` plane, radians in ``[0, π)``.
    minutiae : (M, 5) float64
        Columns ``u, v`` (mm), ``col, row`` (px), ``kind`` (1 ending, 3 bifurcation); the
        orientation at each is ``orientation[row, col]``.
    core, delta : (2,) float
        Singular points ``(u, v)``, mm.
    seed : int
    """

    ridges: np.ndarray
    u0: float
    v0: float
    pitch: float
    orientation: np.ndarray
    minutiae: np.ndarray
    core: tuple[float, float]
    delta: tuple[float, float]
    seed: int = 0
    _fine: np.ndarray = field(default=None, repr=False)

    def __post_init__(self):
        if self._fine is None:
            # upsample ×2 with cubic splines: bilinear sampling of the fine grid gives a
            # smooth-enough relief for intersections and normals
            h, w = self.ridges.shape
            rows, cols = np.mgrid[0 : h - 0.5 : 0.5, 0 : w - 0.5 : 0.5]
            self._fine = ndi.map_coordinates(
                self.ridges.astype(np.float64), [rows, cols], order=3, mode="nearest"
            ).astype(np.float64)

    @property
    def ppi(self) -> float:
        """Resolution, pixels per inch."""
        return MM_PER_INCH / self.pitch

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)`` of the ridge image."""
        return self.ridges.shape

    def pixel_from_uv(self, u, v) -> tuple[np.ndarray, np.ndarray]:
        """Image ``(col, row)`` of rolled-print coordinates (mm)."""
        return (np.asarray(u) - self.u0) / self.pitch, (self.v0 - np.asarray(v)) / self.pitch

    def sample(self, u, v) -> np.ndarray:
        """Ridge field at ``(u, v)`` (mm), bilinear on the ×2 cubic upsampling; edges clamp."""
        col, row = self.pixel_from_uv(u, v)
        fine = self._fine
        h, w = fine.shape
        x = np.clip(2.0 * col, 0.0, w - 1.000001)
        y = np.clip(2.0 * row, 0.0, h - 1.000001)
        x0 = x.astype(np.intp)
        y0 = y.astype(np.intp)
        fx = x - x0
        fy = y - y0
        i = y0 * w + x0
        flat = fine.ravel()
        top = flat[i] * (1 - fx) + flat[i + 1] * fx
        bottom = flat[i + w] * (1 - fx) + flat[i + w + 1] * fx
        return top * (1 - fy) + bottom * fy

    def describe(self) -> dict:
        """JSON-ready summary (no arrays except the minutiae count)."""
        return {"seed": self.seed, "ppi": self.ppi, "pitch_mm": self.pitch,
                "shape": list(self.shape), "u0": self.u0, "v0": self.v0,
                "core": list(self.core), "delta": list(self.delta),
                "n_minutiae": len(self.minutiae)}


def orientation_field(u, v, *, core, delta, theta_inf: float = 0.0) -> np.ndarray:
    """Zero-pole ridge orientation (radians in ``[0, π)``) at ``(u, v)`` mm.

    Examples
    --------
    >>> float(orientation_field(0.0, -100.0, core=(0, 0), delta=(0, -5)).round(3))
    0.0
    """
    z = np.asarray(u, dtype=float) + 1j * np.asarray(v, dtype=float)
    theta = theta_inf + 0.5 * (np.angle(z - complex(*core)) - np.angle(z - complex(*delta)))
    return np.mod(theta, np.pi)


def _gabor_bank(n_orient: int, period_px: float, shape, sigma_px: float):
    """rFFT spectra of even Gabor kernels for ridge directions ``k π / n`` (pixel frame)."""
    half = int(np.ceil(3 * sigma_px))
    yy, xx = np.mgrid[-half : half + 1, -half : half + 1].astype(float)
    envelope = np.exp(-(xx**2 + yy**2) / (2 * sigma_px**2))
    bank = []
    for k in range(n_orient):
        a = k * np.pi / n_orient  # ridge direction in pixel frame (x right, y down)
        nx, ny = -np.sin(a), np.cos(a)  # normal to the ridges
        g = envelope * np.cos(2 * np.pi * (xx * nx + yy * ny) / period_px)
        g -= envelope * g.sum() / envelope.sum()  # zero mean
        g /= np.abs(g).sum()
        kernel = np.zeros(shape)
        kernel[: 2 * half + 1, : 2 * half + 1] = g
        kernel = np.roll(kernel, (-half, -half), axis=(0, 1))
        bank.append(scipy.fft.rfft2(kernel.astype(np.float32)))
    return bank


def _orientation_weights(theta_pix: np.ndarray, n_orient: int) -> list[tuple[int, np.ndarray]]:
    k = theta_pix / (np.pi / n_orient)
    lower = np.floor(k).astype(int) % n_orient
    frac = (k - np.floor(k)).astype(np.float32)
    weights = []
    for b in range(n_orient):
        w = np.where(lower == b, 1 - frac, 0) + np.where((lower + 1) % n_orient == b, frac, 0)
        weights.append((b, w.astype(np.float32)))
    return weights


def _zhang_suen(binary: np.ndarray) -> np.ndarray:
    """Thin a binary image to 1-px skeletons (Zhang & Suen), vectorised."""
    img = np.pad(binary.astype(np.uint8), 1)
    while True:
        changed = False
        for step in (0, 1):
            p = img
            p2, p3, p4 = p[:-2, 1:-1], p[:-2, 2:], p[1:-1, 2:]
            p5, p6, p7 = p[2:, 2:], p[2:, 1:-1], p[2:, :-2]
            p8, p9 = p[1:-1, :-2], p[:-2, :-2]
            seq = [p2, p3, p4, p5, p6, p7, p8, p9, p2]
            b = sum(s.astype(np.int32) for s in seq[:8])
            a = sum(((seq[i] == 0) & (seq[i + 1] == 1)).astype(np.int32) for i in range(8))
            if step == 0:
                c1 = (p2 * p4 * p6) == 0
                c2 = (p4 * p6 * p8) == 0
            else:
                c1 = (p2 * p4 * p8) == 0
                c2 = (p2 * p6 * p8) == 0
            remove = (p[1:-1, 1:-1] == 1) & (b >= 2) & (b <= 6) & (a == 1) & c1 & c2
            if np.any(remove):
                img[1:-1, 1:-1][remove] = 0
                changed = True
        if not changed:
            return img[1:-1, 1:-1].astype(bool)


def find_minutiae(ridges: np.ndarray, *, border_px: int = 12, min_distance_px: float = 6.0):
    """Ridge endings and bifurcations of a ridge field (crossing number on the skeleton).

    Parameters
    ----------
    ridges : (H, W) float
        Ridge field, ridges where ``> 0``.
    border_px : int
        Minutiae closer to the image border are dropped.
    min_distance_px : float
        Pairs of minutiae closer than this (skeleton spurs and bridges) are both dropped.

    Returns
    -------
    (M, 3) float64
        ``col, row, kind`` (1 ending, 3 bifurcation).
    """
    skel = _zhang_suen(np.asarray(ridges) > 0)
    p = np.pad(skel.astype(np.int32), 1)
    ring = [p[:-2, 1:-1], p[:-2, 2:], p[1:-1, 2:], p[2:, 2:], p[2:, 1:-1], p[2:, :-2],
            p[1:-1, :-2], p[:-2, :-2]]
    cn = sum(np.abs(ring[i] - ring[(i + 1) % 8]) for i in range(8)) // 2
    rows, cols = np.nonzero(skel & ((cn == 1) | (cn == 3)))
    kinds = cn[rows, cols]
    h, w = skel.shape
    inside = ((rows >= border_px) & (rows < h - border_px)
              & (cols >= border_px) & (cols < w - border_px))
    rows, cols, kinds = rows[inside], cols[inside], kinds[inside]
    if len(rows) > 1:
        from scipy.spatial import cKDTree

        pts = np.column_stack([cols, rows]).astype(float)
        pairs = cKDTree(pts).query_pairs(min_distance_px, output_type="ndarray")
        drop = np.zeros(len(pts), dtype=bool)
        drop[pairs.ravel()] = True
        rows, cols, kinds = rows[~drop], cols[~drop], kinds[~drop]
    return np.column_stack([cols, rows, kinds]).astype(float)


def generate_fingerprint(
    *,
    u_range: tuple[float, float] = (-25.0, 25.0),
    v_range: tuple[float, float] = (-30.0, 20.0),
    core: tuple[float, float] = (0.0, 4.0),
    delta: tuple[float, float] = (-7.0, -5.0),
    ridge_period: float = 0.46,
    ppi: float = 500.0,
    seed: int = 0,
    iterations: int = 10,
    n_orientations: int = 12,
) -> Fingerprint:
    """Grow a fingerprint on the rolled-print plane (see the module docstring).

    Parameters
    ----------
    u_range, v_range : (float, float)
        Extent of the print, mm.
    core, delta : (float, float)
        Singular points ``(u, v)``, mm (a loop with the core above the delta).
    ridge_period : float
        Ridge period, mm (0.4–0.5 for adult fingers); varies by ±5 % smoothly over the print.
    ppi : float
        Resolution, pixels per inch.
    seed : int
        Random seed: the same seed gives the same print.
    iterations, n_orientations : int
        Growth iterations and Gabor orientation banks.

    Returns
    -------
    Fingerprint
    """
    if not 0.2 <= ridge_period <= 1.0:
        raise ValueError(f"ridge_period: expected 0.2..1.0 mm, got {ridge_period}")
    if u_range[1] <= u_range[0] or v_range[1] <= v_range[0]:
        raise ValueError("u_range, v_range: expected (min, max) with max > min")
    rng = np.random.default_rng(seed)
    pitch = MM_PER_INCH / ppi
    w = int(np.ceil((u_range[1] - u_range[0]) / pitch)) + 1
    h = int(np.ceil((v_range[1] - v_range[0]) / pitch)) + 1
    u0, v0 = u_range[0], v_range[1]
    uu = u0 + pitch * np.arange(w)[None, :]
    vv = v0 - pitch * np.arange(h)[:, None]
    theta = orientation_field(uu, vv, core=core, delta=delta)
    theta_pix = np.mod(-theta, np.pi)  # rows run down: mirror the angle
    period_px = ridge_period / pitch
    pad = int(np.ceil(3 * 0.55 * period_px)) + 2
    shape = (scipy.fft.next_fast_len(h + 2 * pad, real=True),
             scipy.fft.next_fast_len(w + 2 * pad, real=True))
    bank = _gabor_bank(n_orientations, period_px, shape, sigma_px=0.55 * period_px)
    weights = _orientation_weights(theta_pix, n_orientations)
    # random seeds: SFinGe grows ridges from initial points; here from a field of random
    # impulses, so that growing fronts meet everywhere and leave minutiae where they merge
    image = np.zeros((h, w), dtype=np.float32)
    n_seeds = max(4, int(h * w / (2 * period_px) ** 2))
    image[rng.integers(0, h, n_seeds), rng.integers(0, w, n_seeds)] = rng.choice([-1, 1], n_seeds)
    canvas = np.zeros(shape, dtype=np.float32)
    for it in range(iterations):
        canvas[pad : pad + h, pad : pad + w] = image
        spectrum = scipy.fft.rfft2(canvas, workers=2)
        out = np.zeros((h, w), dtype=np.float32)
        for b, wmap in weights:
            resp = scipy.fft.irfft2(spectrum * bank[b], s=shape, workers=2)
            out += wmap * resp[pad : pad + h, pad : pad + w]
        scale = np.percentile(np.abs(out), 60 if it < iterations - 1 else 95) + 1e-12
        image = np.clip(out / scale, -1, 1).astype(np.float32)
    rms = np.sqrt(ndi.gaussian_filter(image.astype(np.float64) ** 2, period_px)) + 1e-6
    ridges = np.clip(image / (np.sqrt(2) * rms), -1, 1)
    ridges = ndi.gaussian_filter(ridges, 0.08 * period_px).astype(np.float32)
    found = find_minutiae(ridges, border_px=int(period_px * 1.5),
                          min_distance_px=0.7 * period_px)
    col, row, kind = found.T if len(found) else (np.zeros(0),) * 3
    minutiae = np.column_stack([u0 + pitch * col, v0 - pitch * row, col, row, kind])
    return Fingerprint(ridges=ridges, u0=float(u0), v0=float(v0), pitch=pitch,
                       orientation=theta.astype(np.float32), minutiae=minutiae,
                       core=tuple(core), delta=tuple(delta), seed=int(seed))
