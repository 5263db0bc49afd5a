"""Synthetic fingerprints, and real print images, on the finger's rolled-print plane.

Synthetic prints follow SFinGe (Cappelli, Maio, Maltoni, *Synthetic fingerprint-image
generation*, ICPR 2000, doi:10.1109/ICPR.2000.903586):

1. a pattern class (arch, tented arch, left loop, right loop, whorl) and its singular points,
   jittered by the seed; the orientation field of the zero-pole model (Sherlock & Monro 1993,
   doi:10.1016/0031-3203(93)90087-7),
   ``θ(z) = θ∞ + ½ [Σ arg(z − z_core) − Σ arg(z − z_delta)]`` with ``z = u + i v``, or for a
   plain arch (no singular points) a smooth bump field, plus a smooth random perturbation
   (a few degrees over several millimetres);
2. a ridge period of 0.45–0.50 mm (by seed) varying smoothly by ±5 % over the print;
3. ridge growth: starting from sparse random impulses, the whole image is filtered again and
   again with Gabor filters tuned to the local orientation and period (FFT convolution of the
   whole image with ``n_orientations × 2`` kernels, weights interpolated linearly between
   neighbouring orientations and periods, so the result has no block seams) and clipped, until
   ridges fill the image; minutiae arise where growing fronts meet;
4. ridge field ``r ∈ [−1, 1]`` (+1 on ridge crests) normalised by its local RMS;
5. minutiae: ridges (``r > 0``) thinned (Zhang & Suen 1984, doi:10.1145/357994.358023),
   crossing number 1 (ending) or 3 (bifurcation), spurious close pairs and border hits removed.

Coordinates (``docs/conventions.md``, "Rolled prints"): the print lives in the finger's
rolled-print plane ``(u, v)`` in mm (``u`` arc length across the finger, positive towards
world ``+X``; ``v`` along it, positive towards the tip). Images are in the **legacy
convention** of inked rolls and live scans, the mirror of the pad seen from outside, tip up:
column ``c`` is ``u = u0 − c · pitch`` and row ``r`` is ``v = v0 − r · pitch``, 500 ppi by
default. In that image frame (``x = c`` right, ``y = r`` down) a ridge orientation ``θ``
measured in the ``(u, v)`` plane from ``+u`` towards ``+v`` has the same angle ``θ`` (mod π).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.fft
import scipy.ndimage as ndi

__all__ = [
    "PATTERNS",
    "PATTERN_FREQUENCIES",
    "Fingerprint",
    "arch_orientation",
    "find_minutiae",
    "generate_fingerprint",
    "legacy_geometry",
    "orientation_field",
    "pattern_for_seed",
]

MM_PER_INCH = 25.4

#: Pattern classes of :func:`generate_fingerprint`.
PATTERNS = ("arch", "tented_arch", "left_loop", "right_loop", "whorl")

#: Natural frequencies of the classes (Wilson, Candela & Watson 1994, NIST, as quoted by Maltoni
#: et al., *Handbook of Fingerprint Recognition*, 2nd ed., §5.1).
PATTERN_FREQUENCIES = {"arch": 0.037, "tented_arch": 0.029, "left_loop": 0.338,
                       "right_loop": 0.317, "whorl": 0.279}

_GOLDEN = 0.6180339887498949
_PATTERN_OFFSET = 0.4427  # puts all five classes among seeds 0..9
_SIGMA_FACTOR = 0.42  # Gabor envelope σ per ridge period
_CONVENTION = "legacy (mirror of the pad view), tip up"


def pattern_for_seed(seed: int) -> str:
    """The pattern class a seed draws: natural frequencies, consecutive seeds spread out.

    The class is the one whose interval of cumulative frequency (order: tented arch, arch,
    left loop, right loop, whorl) holds ``frac(0.4427 + seed · 0.618034)``. This golden-ratio
    sequence is equidistributed, so over many seeds the classes have their natural frequencies
    (:data:`PATTERN_FREQUENCIES`), and seeds 0..9 give all five classes.

    Examples
    --------
    >>> [pattern_for_seed(s) for s in (0, 1, 3, 4, 9)]
    ['right_loop', 'arch', 'left_loop', 'whorl', 'tented_arch']
    """
    x = (_PATTERN_OFFSET + int(seed) * _GOLDEN) % 1.0
    edge = 0.0
    for name in ("tented_arch", "arch", "left_loop", "right_loop", "whorl"):
        edge += PATTERN_FREQUENCIES[name]
        if x < edge:
            return name
    return "whorl"


@dataclass
class Fingerprint:
    """A ridge pattern on the rolled-print plane, as an image in the legacy convention.

    Pixel ``(col, row)`` (pixel centres, ``docs/conventions.md``) is the skin point
    ``u = u0 − col · pitch``, ``v = v0 − row · pitch`` (mm): columns run towards ``−u`` (the
    mirror of the pad view), rows towards ``−v`` (the fingertip at the top).

    Attributes
    ----------
    ridges : (H, W) float32
        Ridge field in ``[−1, 1]``, +1 on ridge crests.
    u0, v0 : float
        ``(u, v)`` of the centre of pixel ``[0, 0]``, mm.
    pitch : float
        Pixel size, mm (``25.4 / 500`` at 500 ppi).
    orientation : (H, W) float32 or None
        Ridge orientation in the ``(u, v)`` plane, radians in ``[0, π)`` (None for an image).
    minutiae : (M, 5) float64
        Columns ``u, v`` (mm), ``col, row`` (legacy pixels), ``kind`` (1 ending,
        3 bifurcation); the orientation at each is ``orientation[row, col]``.
    cores, deltas : (K, 2), (L, 2) float64
        Singular points ``(u, v)``, mm.
    pattern : str
        One of :data:`PATTERNS`, ``"custom"`` (singular points given) or ``"image"``.
    seed : int or None
        Generator seed (None for an image).
    ridge_period : float or None
        Mean ridge period, mm (None for an image).
    image : (H, W) uint8 or None
        The source image of :meth:`from_image` (the print's truth, unchanged).
    outside : {"clamp", "flat"}
        Ridge field beyond the grid: the nearest edge value, or 0 (flat skin).
    """

    ridges: np.ndarray
    u0: float
    v0: float
    pitch: float
    orientation: np.ndarray | None = None
    minutiae: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))
    cores: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    deltas: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    pattern: str = "custom"
    seed: int | None = None
    ridge_period: float | None = None
    image: np.ndarray | None = field(default=None, repr=False)
    outside: str = "clamp"
    _fine: np.ndarray | None = field(default=None, repr=False)
    _pad: int = field(default=0, repr=False)

    def __post_init__(self):
        if self.outside not in ("clamp", "flat"):
            raise ValueError(f"outside: expected 'clamp' or 'flat', got {self.outside!r}")
        self.cores = np.asarray(self.cores, dtype=float).reshape(-1, 2)
        self.deltas = np.asarray(self.deltas, dtype=float).reshape(-1, 2)
        if self._fine is None:
            ridges = self.ridges.astype(np.float64)
            if self.outside == "flat":
                # a border of zeros: sampling clamps onto it, so the skin is flat beyond
                self._pad = 4
                ridges = np.pad(ridges, self._pad)
            # upsample ×2 with cubic splines: bilinear sampling of the fine grid gives a
            # smooth-enough relief for intersections and normals
            h, w = ridges.shape
            rows, cols = np.mgrid[0 : h - 0.5 : 0.5, 0 : w - 0.5 : 0.5]
            self._fine = ndi.map_coordinates(ridges, [rows, cols], order=3, mode="nearest")
            if self.outside == "flat":  # exactly 0 where sampling clamps (spline ringing)
                self._fine[:2], self._fine[-2:], self._fine[:, :2], self._fine[:, -2:] = 0, 0, 0, 0

    @classmethod
    def from_image(
        cls,
        image,
        *,
        ppi: float = 500.0,
        center_uv: tuple[float, float] = (0.0, 0.0),
        normalize: bool = True,
    ) -> Fingerprint:
        """A print from a grayscale image in the legacy convention (ridges dark).

        The image is laid on the rolled-print plane at true scale: its centre (pixel
        ``((W − 1) / 2, (H − 1) / 2)``) at `center_uv`, columns towards ``−u``, rows towards
        ``−v``, ``25.4 / ppi`` mm per pixel. Ridge field ``r = (127.5 − I) / 127.5`` (+1 on
        black ridge crests); with `normalize`, the local mean (Gaussian, σ = 1 mm) is
        subtracted and the result divided by ``max(√2 · local RMS, 0.1)`` and clipped to
        ``[−1, 1]``, so that the relief has about constant amplitude whatever the ink and
        blank paper stays flat. Outside the image ``r = 0``.

        Parameters
        ----------
        image : (H, W) uint8
            The print, ridges dark on light.
        ppi : float
            Resolution, pixels per inch.
        center_uv : (float, float)
            ``(u, v)`` of the image centre, mm.
        normalize : bool
            Local contrast normalisation (above).

        Returns
        -------
        Fingerprint
            With ``pattern = "image"``, the image kept unchanged in ``image``, no minutiae.

        Raises
        ------
        ValueError
            If `image` is not a non-empty 2-D uint8 array or `ppi` is not positive.

        Examples
        --------
        >>> fp = Fingerprint.from_image(np.zeros((3, 5), np.uint8), ppi=500, normalize=False)
        >>> [float(x) for x in fp.pixel_from_uv(0.0, 0.0)]
        [2.0, 1.0]
        >>> [round(float(fp.sample(u, 0.0)), 6) + 0.0 for u in (0.0, 10.0)]
        [1.0, 0.0]
        """
        image = np.asarray(image)
        if image.dtype != np.uint8:
            raise ValueError(f"image: expected an 8-bit (uint8) array, got {image.dtype}")
        if image.ndim != 2 or image.size == 0:
            raise ValueError(f"image: expected a non-empty (H, W) array, got shape {image.shape}")
        if not (np.isfinite(ppi) and ppi > 0):
            raise ValueError(f"ppi: expected a positive number, got {ppi}")
        pitch = MM_PER_INCH / float(ppi)
        h, w = image.shape
        u0 = float(center_uv[0]) + pitch * (w - 1) / 2
        v0 = float(center_uv[1]) + pitch * (h - 1) / 2
        ridges = (127.5 - image.astype(np.float64)) / 127.5
        if normalize:
            sigma = 1.0 / pitch
            detail = ridges - ndi.gaussian_filter(ridges, sigma)
            rms = np.sqrt(ndi.gaussian_filter(detail**2, sigma))
            ridges = np.clip(detail / np.maximum(np.sqrt(2) * rms, 0.1), -1, 1)
        return cls(ridges=ridges.astype(np.float32), u0=u0, v0=v0, pitch=pitch,
                   pattern="image", image=image.copy(), outside="flat")

    @property
    def ppi(self) -> float:
        """Resolution, pixels per inch."""
        return MM_PER_INCH / self.pitch

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)`` of the ridge image."""
        return self.ridges.shape

    def pixel_from_uv(self, u, v) -> tuple[np.ndarray, np.ndarray]:
        """Legacy image ``(col, row)`` of rolled-print coordinates ``(u, v)`` (mm).

        ``col = (u0 − u) / pitch``, ``row = (v0 − v) / pitch`` (pixel centres at integers).
        """
        return (self.u0 - np.asarray(u, dtype=float)) / self.pitch, \
            (self.v0 - np.asarray(v, dtype=float)) / self.pitch

    def uv_from_pixel(self, col, row) -> tuple[np.ndarray, np.ndarray]:
        """Rolled-print coordinates ``(u, v)`` (mm) of legacy image pixels ``(col, row)``."""
        return self.u0 - self.pitch * np.asarray(col, dtype=float), \
            self.v0 - self.pitch * np.asarray(row, dtype=float)

    def sample(self, u, v) -> np.ndarray:
        """Ridge field at ``(u, v)`` (mm), bilinear on the ×2 cubic upsampling.

        Beyond the grid the edge value (``outside = "clamp"``) or 0 (``"flat"``).
        """
        col, row = self.pixel_from_uv(u, v)
        fine = self._fine
        assert fine is not None  # set in __post_init__
        h, w = fine.shape
        x = np.clip(2.0 * (col + self._pad), 0.0, w - 1.000001)
        y = np.clip(2.0 * (row + self._pad), 0.0, h - 1.000001)
        x0 = x.astype(np.intp)
        y0 = y.astype(np.intp)
        fx = x - x0
        fy = y - y0
        i = y0 * w + x0
        flat = fine.ravel()
        top = flat[i] * (1 - fx) + flat[i + 1] * fx
        bottom = flat[i + w] * (1 - fx) + flat[i + w + 1] * fx
        return top * (1 - fy) + bottom * fy

    def geometry(self) -> dict:
        """The legacy image's placement on the rolled-print plane (JSON-ready)."""
        return legacy_geometry(self.u0, self.v0, self.pitch, self.shape)

    def describe(self) -> dict:
        """JSON-ready summary: pattern, geometry, singular points, minutiae count."""
        return {"pattern": self.pattern, "seed": self.seed, **self.geometry(),
                "ridge_period_mm": self.ridge_period,
                "cores": self.cores.round(4).tolist(), "deltas": self.deltas.round(4).tolist(),
                "n_minutiae": len(self.minutiae)}


def legacy_geometry(u0: float, v0: float, pitch: float, shape) -> dict:
    """Placement of a legacy-convention image on the rolled-print plane (JSON-ready).

    Pixel ``(col, row)`` of an image of `shape` ``(H, W)`` is the skin point
    ``u = u0 − col · pitch``, ``v = v0 − row · pitch`` (mm, pixel centres); the keys are those
    of ``truth/fingerprint.json`` (``docs/capture-format.md``).

    Examples
    --------
    >>> g = legacy_geometry(1.0, 2.0, 0.0508, (3, 4))
    >>> g["u_of_col0_mm"], g["shape"], g["col_direction"]
    (1.0, [3, 4], '-u')
    """
    return {"convention": _CONVENTION, "ppi": MM_PER_INCH / float(pitch),
            "pitch_mm": float(pitch), "shape": [int(n) for n in shape],
            "u_of_col0_mm": float(u0), "v_of_row0_mm": float(v0),
            "col_direction": "-u", "row_direction": "-v",
            "mapping": "col = (u_of_col0_mm - u) / pitch_mm; "
                       "row = (v_of_row0_mm - v) / pitch_mm (pixel centres)"}


def _mod_pi(theta):
    """Angles mod π in ``[0, π)`` (``np.mod`` of a tiny negative angle rounds to π)."""
    theta = np.mod(theta, np.pi)
    return np.where(theta >= np.pi, 0.0, theta)


def orientation_field(u, v, *, cores=(), deltas=(), theta_inf: float = 0.0) -> np.ndarray:
    """Zero-pole ridge orientation (radians in ``[0, π)``) at ``(u, v)`` mm.

    ``θ = θ∞ + ½ [Σ arg(z − core) − Σ arg(z − delta)]``, ``z = u + i v`` (Sherlock & Monro
    1993). Around a core the orientation turns by ``+π``, around a delta by ``−π``.

    Parameters
    ----------
    u, v : array_like
        Points, mm (broadcast together).
    cores, deltas : sequence of (float, float)
        Singular points ``(u, v)``, mm.
    theta_inf : float
        Orientation far from all singular points (when there are as many cores as deltas).

    Examples
    --------
    >>> float(orientation_field(0.0, -100.0, cores=[(0, 0)], deltas=[(0, -5)]).round(3))
    0.0
    """
    z = np.asarray(u, dtype=float) + 1j * np.asarray(v, dtype=float)
    theta = np.full(z.shape, float(theta_inf))
    for c in np.asarray(cores, dtype=float).reshape(-1, 2):
        theta = theta + 0.5 * np.angle(z - complex(*c))
    for d in np.asarray(deltas, dtype=float).reshape(-1, 2):
        theta = theta - 0.5 * np.angle(z - complex(*d))
    return _mod_pi(theta)


def arch_orientation(u, v, *, center, amplitude: float = 4.0, width: float = 5.0,
                     theta_inf: float = 0.0) -> np.ndarray:
    """Orientation (radians in ``[0, π)``) of a plain arch: ridges over a bump.

    Ridges follow ``v = const + A(v) exp(−(u − uc)² / 2w²)``: slope
    ``−A (u − uc) / w² · exp(−(u − uc)² / 2w²)`` with ``A(v)`` = `amplitude` above the centre,
    fading out 3 mm below it (over ~2 mm), so the ridges flatten towards the crease.

    Examples
    --------
    >>> float(arch_orientation(0.0, 0.0, center=(0.0, 0.0)))
    0.0
    """
    du = np.asarray(u, dtype=float) - center[0]
    a = amplitude / (1.0 + np.exp(-(np.asarray(v, dtype=float) - center[1] + 3.0) / 2.0))
    slope = -a * du / width**2 * np.exp(-(du**2) / (2 * width**2))
    return _mod_pi(np.arctan(slope) + theta_inf)


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


def _orientation_weights(theta_pix: np.ndarray, n_orient: int) -> list[np.ndarray]:
    """Linear interpolation weights ``(H, W)`` of the `n_orient` banks (periodic in π)."""
    k = theta_pix / (np.pi / n_orient)
    lower = np.floor(k).astype(int) % n_orient
    frac = (k - np.floor(k)).astype(np.float32)
    weights = []
    for b in range(n_orient):
        w = np.where(lower == b, 1 - frac, 0) + np.where((lower + 1) % n_orient == b, frac, 0)
        weights.append(w.astype(np.float32))
    return weights


def _smooth_noise(rng, shape, pitch, correlation_mm):
    """Smooth random field ``(H, W)`` (std 1), Gaussian correlation length in mm."""
    step = max(pitch, correlation_mm / 8)  # coarse grid, then cubic upsampling
    h, w = shape
    ch = int(np.ceil((h - 1) * pitch / step)) + 8
    cw = int(np.ceil((w - 1) * pitch / step)) + 8
    coarse = ndi.gaussian_filter(rng.standard_normal((ch, cw)), correlation_mm / step,
                                 mode="wrap")
    coarse /= coarse.std() + 1e-12
    rows = 4 + np.arange(h)[:, None] * (pitch / step)
    cols = 4 + np.arange(w)[None, :] * (pitch / step)
    rows, cols = np.broadcast_arrays(rows, cols)
    return ndi.map_coordinates(coarse, [rows, cols], order=3, mode="nearest")


def _singular_points(pattern, center, rng):
    """Cores, deltas ``(K, 2)``, ``(L, 2)`` (mm) of a class, jittered about `center`."""
    cu, cv = center
    jitter = np.clip(rng.normal(0.0, 0.8, 2), -1.5, 1.5)
    core = np.array([cu + jitter[0], cv + jitter[1]])
    if pattern == "arch":
        return core[None, :], np.zeros((0, 2))  # the bump's centre, not a singular point
    if pattern == "tented_arch":
        delta = core + np.array([rng.normal(0.0, 0.3), -rng.uniform(2.0, 3.5)])
        return core[None, :], delta[None, :]
    if pattern in ("left_loop", "right_loop"):
        # left loop: opens to the image left (+u side); its delta lies at the image right (−u)
        side = -1.0 if pattern == "left_loop" else 1.0
        delta = core + np.array([side * rng.uniform(5.0, 8.0), -rng.uniform(5.0, 8.0)])
        return core[None, :], delta[None, :]
    if pattern == "whorl":
        half = rng.uniform(0.5, 1.2)
        angle = rng.uniform(0, np.pi)
        offset = half * np.array([np.cos(angle), np.sin(angle)])
        cores = np.array([core + offset, core - offset])
        below = np.column_stack([[-1.0, 1.0] * rng.uniform(6.0, 9.0, 2),
                                 -rng.uniform(5.0, 8.0, 2)])
        deltas = core + below
        return cores, deltas
    raise ValueError(f"pattern: expected one of {', '.join(PATTERNS)}, got {pattern!r}")


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
    center: tuple[float, float] = (0.0, 4.0),
    pattern: str | None = None,
    cores=None,
    deltas=None,
    ridge_period: float | None = None,
    ppi: float = 500.0,
    seed: int = 0,
    perturbation: float = 0.12,
    iterations: int = 8,
    n_orientations: int = 12,
    seed_density: float = 0.35,
    sharpness: float = 3.0,
) -> Fingerprint:
    """Grow a fingerprint on the rolled-print plane (see the module docstring).

    Parameters
    ----------
    u_range, v_range : (float, float)
        Extent of the print, mm.
    center : (float, float)
        ``(u, v)`` of the pad centre, mm: the core (whorl: the cores' midpoint; arch: the
        bump) lies within 1.5 mm of it (jittered by the seed); deltas lie 5–9 mm lower.
    pattern : str, optional
        One of :data:`PATTERNS`; by default :func:`pattern_for_seed` ``(seed)``.
    cores, deltas : sequence of (float, float), optional
        Explicit singular points ``(u, v)`` mm (zero-pole model) instead of the class's; the
        pattern is then recorded as `pattern` or ``"custom"``.
    ridge_period : float, optional
        Mean ridge period, mm; by default drawn from 0.45–0.50 by the seed. The local period
        varies smoothly by ±5 % about it.
    ppi : float
        Resolution, pixels per inch.
    seed : int
        Random seed: the same seed gives the same print.
    perturbation : float
        Standard deviation of the smooth random orientation perturbation, radians
        (correlation length 5 mm).
    iterations, n_orientations : int
        Growth iterations and Gabor orientation banks.
    seed_density : float
        Initial random impulses per square ridge period (more: more minutiae).
    sharpness : float
        Final ridge profile ``tanh(sharpness · x) / tanh(sharpness)`` of the RMS-normalised
        grown image ``x``: crisp ridge ends where growing fronts met.

    Returns
    -------
    Fingerprint
        In the legacy convention: ``u0 = u_range[1]``, ``v0 = v_range[1]``.

    Raises
    ------
    ValueError
        For a bad range, period or pattern name.

    Examples
    --------
    >>> fp = generate_fingerprint(u_range=(-3, 3), v_range=(-3, 3), pattern="whorl", seed=1)
    >>> fp.pattern, fp.shape, len(fp.cores), len(fp.deltas)
    ('whorl', (120, 120), 2, 2)
    """
    if ridge_period is not None and not 0.2 <= ridge_period <= 1.0:
        raise ValueError(f"ridge_period: expected 0.2..1.0 mm, got {ridge_period}")
    if u_range[1] <= u_range[0] or v_range[1] <= v_range[0]:
        raise ValueError("u_range, v_range: expected (min, max) with max > min")
    if pattern is not None and pattern not in PATTERNS:
        raise ValueError(f"pattern: expected one of {', '.join(PATTERNS)}, got {pattern!r}")
    if not (np.isfinite(ppi) and ppi > 0):
        raise ValueError(f"ppi: expected a positive number, got {ppi}")
    rng = np.random.default_rng(seed)
    period0 = float(rng.uniform(0.45, 0.50)) if ridge_period is None else float(ridge_period)
    theta_inf = float(np.clip(rng.normal(0.0, 0.06), -0.15, 0.15))
    if cores is not None or deltas is not None:
        cores = np.zeros((0, 2)) if cores is None else np.asarray(cores, float).reshape(-1, 2)
        deltas = np.zeros((0, 2)) if deltas is None else np.asarray(deltas, float).reshape(-1, 2)
        pattern = pattern or "custom"
    else:
        pattern = pattern or pattern_for_seed(seed)
        cores, deltas = _singular_points(pattern, center, rng)

    pitch = MM_PER_INCH / ppi
    w = int(np.ceil((u_range[1] - u_range[0]) / pitch)) + 1
    h = int(np.ceil((v_range[1] - v_range[0]) / pitch)) + 1
    u0, v0 = float(u_range[1]), float(v_range[1])  # legacy: column 0 at the largest u
    uu = u0 - pitch * np.arange(w)[None, :]
    vv = v0 - pitch * np.arange(h)[:, None]
    if pattern == "arch":
        theta = arch_orientation(uu, vv, center=tuple(cores[0]),
                                 amplitude=rng.uniform(6.0, 10.0), width=rng.uniform(4.0, 6.0),
                                 theta_inf=theta_inf)
        cores = np.zeros((0, 2))
    else:
        theta = orientation_field(uu, vv, cores=cores, deltas=deltas, theta_inf=theta_inf)
    theta = _mod_pi(theta + perturbation * _smooth_noise(rng, (h, w), pitch, 5.0))
    variation = _smooth_noise(rng, (h, w), pitch, 6.0)
    variation /= np.abs(variation).max() + 1e-12
    period_mm = period0 * (1.0 + 0.05 * variation)  # ±5 %, smooth
    # legacy image frame (x = col towards −u, y = row towards −v): the direction (cos θ, sin θ)
    # becomes (−cos θ, −sin θ), the same orientation mod π
    theta_pix = theta
    periods_px = (0.95 * period0 / pitch, 1.05 * period0 / pitch)
    sigma = _SIGMA_FACTOR * period0 / pitch
    pad = int(np.ceil(3 * sigma)) + 2
    shape = (scipy.fft.next_fast_len(h + 2 * pad, real=True),
             scipy.fft.next_fast_len(w + 2 * pad, real=True))
    banks = [_gabor_bank(n_orientations, p, shape, sigma_px=sigma) for p in periods_px]
    frac_hi = ((period_mm / period0 - 0.95) / 0.10).astype(np.float32)
    orient_w = _orientation_weights(theta_pix, n_orientations)
    weights = []  # (period bank, orientation bank, weight map); all-zero maps skipped
    for p, wp in ((0, 1 - frac_hi), (1, frac_hi)):
        for b, wo in enumerate(orient_w):
            wmap = wo * wp
            if np.any(wmap > 0):
                weights.append((p, b, wmap))
    # random seeds: SFinGe grows ridges from initial points; here from a field of random
    # impulses, so that growing fronts meet everywhere and leave minutiae where they merge
    image = np.zeros((h, w), dtype=np.float32)
    n_seeds = max(4, int(seed_density * h * w / (period0 / pitch) ** 2))
    image[rng.integers(0, h, n_seeds), rng.integers(0, w, n_seeds)] = rng.choice([-1, 1], n_seeds)
    canvas = np.zeros(shape, dtype=np.float32)
    for it in range(iterations):
        canvas[pad : pad + h, pad : pad + w] = image
        spectrum = scipy.fft.rfft2(canvas, workers=2)
        out = np.zeros((h, w), dtype=np.float32)
        for p, b, wmap in weights:
            resp = scipy.fft.irfft2(spectrum * banks[p][b], s=shape, workers=2)
            out += wmap * resp[pad : pad + h, pad : pad + w]
        scale = np.percentile(np.abs(out), 60 if it < iterations - 1 else 95) + 1e-12
        image = np.clip(out / scale, -1, 1).astype(np.float32)
    period_px = period0 / pitch
    rms = np.sqrt(ndi.gaussian_filter(image.astype(np.float64) ** 2, period_px)) + 1e-6
    # sharpen: weak responses where growing fronts met become crisp endings and forks
    ridges = np.tanh(sharpness * image / (np.sqrt(2) * rms)) / np.tanh(sharpness)
    ridges = np.clip(ndi.gaussian_filter(ridges, 0.08 * period_px), -1, 1).astype(np.float32)
    found = find_minutiae(ridges, border_px=int(period_px * 1.5),
                          min_distance_px=0.7 * period_px)
    col, row, kind = found.T if len(found) else (np.zeros(0),) * 3
    minutiae = np.column_stack([u0 - pitch * col, v0 - pitch * row, col, row, kind])
    return Fingerprint(ridges=ridges, u0=u0, v0=v0, pitch=pitch,
                       orientation=theta.astype(np.float32), minutiae=minutiae,
                       cores=cores, deltas=deltas, pattern=pattern, seed=int(seed),
                       ridge_period=period0)
