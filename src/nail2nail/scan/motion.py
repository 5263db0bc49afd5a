"""Did the finger move during the capture? Evidence from the frames alone.

Phase shifting assumes a still object. A finger held in the air trembles (8–12 Hz, tens to
hundreds of µm) and drifts while the projector shows its frames; between the steps of one
frequency that shows as ripple at the fringe frequency, between frequencies as unwrapping
errors, between cameras as merge errors. Nothing in one decoded image says so, but the frames
do: the mean of the frames of one phase-shift group (all ``N`` steps of one frequency in one
direction) is the scene without the fringes (the DC image ``A``, exact for every harmonic
below ``N``), and the groups are shown one after another. On a still finger every group's DC
image is the same picture; on a moving one the skin's texture (ridges in the albedo and the
relief's shading) and the shading move from group to group.

:func:`estimate_motion` registers every group's DC image against the first by
cross-correlation (scikit-image's ``phase_cross_correlation``, not whitened, refined to
1/20 px) after a band-pass that keeps the skin's
texture (difference of Gaussians, σ 1 and 4 px) under a soft window inside the camera's valid
pixels, over the whole image and over a grid of regions; the spread of the groups' shifts
(the largest distance between two of them) is the motion the frames saw, in camera pixels and,
given the scan's sampling of the surface, in mm. Motion along a camera's line of sight is
invisible to that camera but not to the others (the thesis rig's cameras are 45° apart).

Conventions: shifts are ``(dx, dy)`` in camera pixels, ``dx`` along columns, ``dy`` along
rows, of a group's DC image relative to the first group's; a region is a cell of a
``tiles × tiles`` grid over the bounding box of the valid pixels.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import scipy.ndimage as ndi

from nail2nail.scan.patterns import PatternSet, frame_table
from nail2nail.scan.phase_shift import unwrap_hierarchical

__all__ = [
    "MOTION_WARN_MM",
    "MotionEstimate",
    "compensate_phase_steps",
    "dc_groups",
    "estimate_motion",
    "fit_pixel_shifts",
    "mm_per_pixel",
    "register_frequencies",
]

#: Motion (spread of the groups' shifts) above which a capture is flagged as moving, mm: about
#: the 3D error it causes (a lateral shift of 20 µm moves the finest fringe's phase by 0.15 rad,
#: 20 µm of depth on the thesis rig), five times the still scanner's noise floor.
MOTION_WARN_MM = 0.02
#: Fewest valid pixels of a region for its own registration.
MIN_REGION_PIXELS = 4096
#: Smallest normalised correlation of two groups' band-passed DC images at the registration's
#: peak for the shift to count, over the whole image and over a region: below it the images
#: share too little texture (skin without ridges) and the shift is noise. A region's shift is
#: trusted from a higher correlation: on a virtual finger whose ridges cover a 9 × 12 mm patch,
#: still regions of flat skin correlated at 0.72–0.81 and erred by up to 0.3 px, ridged ones at
#: 0.90–0.999 and erred by at most 0.05 px.
MIN_CORRELATION = 0.5
MIN_REGION_CORRELATION = 0.9


@dataclass
class MotionEstimate:
    """Motion of the scene seen by one camera over a capture (:func:`estimate_motion`).

    Attributes
    ----------
    labels : list of str
        The DC groups, in time order: ``"x/64"`` is direction ``x``, 64 periods.
    frames : list of (int, int)
        First and last frame of each group.
    shift_px : (n_groups, 2) float64
        ``(dx, dy)`` of each group's DC image against the first group's, camera px.
    region_shift_px : (n_groups, tiles, tiles, 2) float64
        The same per region (NaN where a region has too few valid pixels).
    spread_px : float
        Largest distance between two groups' shifts, whole image, px (NaN when fewer than two
        groups registered: a group whose correlation with the first is below
        :data:`MIN_CORRELATION` has no shift).
    region_spread_px : (tiles, tiles) float64
        The same per region, px (NaN where not measured).
    mm_per_px : float or None
        The scan's sampling of the surface (median distance between neighbouring points), mm.
    """

    labels: list
    frames: list
    shift_px: np.ndarray
    region_shift_px: np.ndarray
    spread_px: float
    region_spread_px: np.ndarray
    mm_per_px: float | None = None

    @property
    def max_spread_px(self) -> float:
        """The larger of the whole image's spread and every region's, px."""
        values = np.append(self.region_spread_px.ravel(), self.spread_px)
        values = values[np.isfinite(values)]
        return float(values.max()) if values.size else float("nan")

    @property
    def motion_mm(self) -> float | None:
        """:attr:`max_spread_px` in mm (None without the scan's sampling)."""
        if self.mm_per_px is None or not np.isfinite(self.mm_per_px):
            return None
        spread = self.max_spread_px
        return spread * self.mm_per_px if np.isfinite(spread) else None

    def to_dict(self) -> dict:
        """JSON-ready (``scan.json`` → ``cameras[i].motion``)."""
        mm = self.motion_mm

        def r(x, n=4):
            return None if not np.isfinite(x) else round(float(x), n)

        return {
            "groups": [{"label": lab, "frames": list(fr), "shift_px": [r(v) for v in s]}
                       for lab, fr, s in zip(self.labels, self.frames, self.shift_px,
                                             strict=True)],
            "spread_px": r(self.spread_px),
            "region_spread_px": [[r(v) for v in row] for row in self.region_spread_px],
            "max_spread_px": r(self.max_spread_px),
            "mm_per_px": None if self.mm_per_px is None else r(self.mm_per_px, 6),
            "motion_mm": None if mm is None else r(mm, 5),
            "moving": None if mm is None else bool(mm > MOTION_WARN_MM),
            "threshold_mm": MOTION_WARN_MM,
        }


def dc_groups(pattern_set: PatternSet) -> list[tuple[str, list[int]]]:
    """The frames whose mean is a DC image, in time order: ``[(label, frame indices)]``.

    A phase-shift group (all steps of one frequency of one direction, 3 or more steps, equally
    spaced over a period) averages to ``A`` exactly for every harmonic below its step count; a
    Gray-code bit plane and its inverse to ``A`` as well; a white frame is ``A`` itself.
    """
    table = frame_table(pattern_set)
    groups: dict[tuple, list[int]] = {}
    for row in table:
        if row.kind == "phase" and row.steps >= 3:
            groups.setdefault(("phase", row.direction, row.periods), []).append(row.index)
        elif row.kind in ("gray", "gray-inverse", "complementary", "complementary-inverse"):
            groups.setdefault((row.kind.split("-")[0], row.direction, row.bit), []).append(
                row.index)
        elif row.kind == "white":
            groups[("white", None, 0)] = [row.index]
    out = []
    for (kind, direction, key), frames in groups.items():
        if kind == "phase":
            out.append((f"{direction}/{key:g}", frames))
        elif kind == "white":
            out.append(("white", frames))
        elif len(frames) == 2:  # a plane with its inverse
            out.append((f"{direction}/{kind}{key}", frames))
    out.sort(key=lambda g: min(g[1]))
    return out


def mm_per_pixel(xyz, mask) -> float | None:
    """Median distance between horizontally adjacent valid points of a scan: its sampling of
    the surface, mm.

    Parameters
    ----------
    xyz : (H, W, 3) float
        Points, world mm (NaN where invalid).
    mask : (H, W) bool
        Valid pixels; a step counts where both of its pixels are valid.

    Returns
    -------
    float or None
        mm (about 0.033 for the default rig at full resolution); None without two adjacent
        valid pixels. (``nail2nail.unroll.ridges.pixel_spacing_mm`` is its compiled float32
        twin, which raises instead.)
    """
    xyz = np.asarray(xyz)
    both = np.asarray(mask)[:, 1:] & np.asarray(mask)[:, :-1]
    if not both.any():
        return None
    step = np.linalg.norm((xyz[:, 1:] - xyz[:, :-1])[both].astype(np.float64), axis=-1)
    step = step[np.isfinite(step)]
    return float(np.median(step)) if step.size else None


#: Band-pass of the DC images, σ in mm on the skin: keeps ridges (periods 0.4–0.6 mm, 96 % of
#: their amplitude) and leaves out the fringes' harmonics a projector's gamma or pixel grid
#: leave in a 3-step group's mean (periods of 2 mm and more: 14 % or less), which stay with the
#: projector and would read as no motion.
BAND_MM = (0.05, 0.2)
#: Sampling the DC images are registered at, mm per pixel (coarser images are used as they are).
SAMPLING_MM = 0.05
#: How far inside the valid pixels the registration window starts, mm: the band-pass of a
#: static edge (the finger's silhouette, the end of the projector's lit area, a shadow) reaches
#: about three times its wider σ into them (0.1 % of the step at 0.6 mm), and an edge that does
#: not move with the skin pins a region's correlation at no shift across it and leaves the
#: shift along it free: on a still finger wearing a real impression (condition 2505, flat skin
#: below the ridges) a corner region reached a normalised correlation of 0.9 on the end of the
#: lit area alone and read 1.8 px of motion along it with the window 0.3 mm inside.
EDGE_MM = 3 * BAND_MM[1]


def _band(image: np.ndarray, sigma_px: tuple[float, float]) -> np.ndarray:
    return (ndi.gaussian_filter(image, sigma_px[0])
            - ndi.gaussian_filter(image, sigma_px[1]))


def _block_mean(image: np.ndarray, f: int) -> np.ndarray:
    if f == 1:
        return image
    h, w = (image.shape[0] // f) * f, (image.shape[1] // f) * f
    return image[:h, :w].reshape(h // f, f, w // f, f).mean(axis=(1, 3))


def _spectrum(image: np.ndarray, window: np.ndarray) -> np.ndarray:
    """2-D DFT of ``image · window``, zero-padded to sizes the FFT factors fast.

    The windowed image is 0 at its border, so the padding changes no correlation near zero
    shift; a region of, say, 454 x 227 px (a prime factor) would cost several times more."""
    from scipy import fft

    shape = [fft.next_fast_len(n) for n in image.shape]
    return fft.fft2(image * window, s=shape)


def _correlate(a: np.ndarray, b: np.ndarray,
               min_correlation: float = MIN_CORRELATION) -> tuple[float, float]:
    """Shift ``(dx, dy)`` of the image of spectrum `b` against that of `a` (:func:`_spectrum`),
    px: cross-correlation (not whitened: a whitened one weighs the static edge of the window as
    much as the moving texture) refined by an upsampled DFT to 1/20 px (Guizar-Sicairos et al.,
    Opt. Lett. 33(2), 156, 2008; scikit-image)."""
    from skimage.registration import phase_cross_correlation

    shift, error, _ = phase_cross_correlation(a, b, space="fourier", upsample_factor=20,
                                              normalization=None)
    # the normalised correlation at the peak: low where the two images share no texture
    # (skin without ridges, noise alone), whose "shift" is anywhere
    if not 1 - float(error) ** 2 >= min_correlation**2:
        return float("nan"), float("nan")
    return float(-shift[1]), float(-shift[0])


def _spread(shifts: np.ndarray) -> float:
    ok = np.all(np.isfinite(shifts), axis=-1)
    s = shifts[ok]
    if len(s) < 2:
        return float("nan")
    return float(np.max(np.linalg.norm(s[:, None] - s[None, :], axis=-1)))


def estimate_motion(frames, pattern_set: PatternSet, mask, *, mm_per_px: float | None = None,
                    tiles: int = 3) -> MotionEstimate | None:
    """Register the DC images of a capture's frame groups against each other.

    Parameters
    ----------
    frames : (n_frames, H, W) array
        One camera's frames, any numeric dtype (their values as read).
    pattern_set : PatternSet
        The patterns the frames show (:func:`dc_groups`).
    mask : (H, W) bool
        The camera's valid pixels (the decoded skin): the registration looks only there.
    mm_per_px : float, optional
        The scan's sampling of the surface (:func:`mm_per_pixel`), for the motion in mm.
    tiles : int
        Regions per side of the grid over the valid pixels' bounding box.

    Returns
    -------
    MotionEstimate or None
        None when the pattern set has fewer than two DC groups or the mask fewer than
        :data:`MIN_REGION_PIXELS` pixels (nothing to compare).
    """
    groups = dc_groups(pattern_set)
    mask = np.asarray(mask, dtype=bool)
    if len(groups) < 2 or mask.sum() < MIN_REGION_PIXELS:
        return None
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    # register at about SAMPLING_MM per pixel: block means of f × f pixels
    scale = mm_per_px if mm_per_px is not None and np.isfinite(mm_per_px) and mm_per_px > 0 \
        else SAMPLING_MM / 2
    f = max(1, round(SAMPLING_MM / scale))
    sigma = (BAND_MM[0] / (scale * f), BAND_MM[1] / (scale * f))
    inner = ndi.binary_erosion(_block_mean(mask[r0:r1, c0:c1].astype(np.float32), f) > 0.99,
                               iterations=max(2, round(EDGE_MM / (scale * f))))
    window = ndi.gaussian_filter(inner.astype(np.float32), sigma[1])
    images = []
    for _, idx in groups:
        dc = np.zeros((r1 - r0, c1 - c0), np.float32)
        for i in idx:
            dc += frames[i][r0:r1, c0:c1]
        images.append(_band(_block_mean(dc, f), sigma))
    n = len(images)
    shift = np.zeros((n, 2))
    spectra = [_spectrum(image, window) for image in images]  # each image transformed once
    for g in range(1, n):
        shift[g] = _correlate(spectra[0], spectra[g])
    h, w = inner.shape
    region = np.full((n, tiles, tiles, 2), np.nan)
    edges_r = np.linspace(0, h, tiles + 1).astype(int)
    edges_c = np.linspace(0, w, tiles + 1).astype(int)
    for i in range(tiles):
        for j in range(tiles):
            sl = (slice(edges_r[i], edges_r[i + 1]), slice(edges_c[j], edges_c[j + 1]))
            if inner[sl].sum() * f * f < MIN_REGION_PIXELS or min(inner[sl].shape) < 32:
                continue
            region[0, i, j] = 0.0
            spectra = [_spectrum(image[sl], window[sl]) for image in images]
            for g in range(1, n):
                region[g, i, j] = _correlate(spectra[0], spectra[g], MIN_REGION_CORRELATION)
    region_spread = np.array([[_spread(region[:, i, j]) for j in range(tiles)]
                              for i in range(tiles)])
    # back to camera pixels
    return MotionEstimate(labels=[g[0] for g in groups],
                          frames=[(min(g[1]), max(g[1])) for g in groups], shift_px=shift * f,
                          region_shift_px=region * f, spread_px=_spread(shift) * f,
                          region_spread_px=region_spread * f, mm_per_px=mm_per_px)


#: Side of the regions whose frames' phase offsets :func:`compensate_phase_steps` estimates, px.
COMPENSATION_TILE_PX = 48
#: Fewest radians of fringe phase spread (circular standard deviation) a region needs for its
#: offsets to be estimated; flatter regions (a coarse frequency) keep the nominal shifts.
MIN_PHASE_SPREAD = 1.0
#: Gaussian σ of the window over which :func:`register_frequencies` averages the misfit between
#: two frequencies, px: wide enough to average the coarse phase's noise (times the frequency
#: ratio), narrow against the motion field's variation over the finger.
REGISTRATION_SIGMA_PX = 16.0
#: Gaussian σ over which :func:`register_frequencies` averages a coarse frequency's phase, px:
#: the skin's texture moving under a 3-step group's fringes errs its phase at the ridges'
#: frequency (0.4–0.5 mm: 9–18 px on the thesis rig), which the frequency ratio multiplies.
COARSE_SMOOTHING_PX = 6.0
#: Smallest weight of lit pixels in the smoothing window (of 1) for the average to replace a
#: coarse phase (about 2 σ inside the edge of the lit area or the image).
MIN_SMOOTHING_COVER = 0.98


def _tile_shifts(values: np.ndarray, weight: np.ndarray, nominal: np.ndarray) -> np.ndarray:
    """Per-tile phase shifts of an ``N``-step group (``N ≥ 4``) from the frames' subspace.

    In a region, ``I_k(p) = a_p + C_p cos δ_k − S_p sin δ_k``: the ``N × P`` matrix of the
    frames has rank 3 and its column space holds ``1``, ``cos δ`` and ``sin δ``. The three
    leading eigenvectors of its (weighted) ``N × N`` Gram matrix span it; with ``1`` taken out,
    two remain, ``R`` (``N × 2``), and ``(cos δ_k, sin δ_k) = r_k Q`` for some ``Q``: the unit
    length of each row gives ``r_k G r_kᵀ = 1`` with ``G = Q Qᵀ``, linear in ``G``'s three
    entries (least squares over the ``N`` frames), and ``Q = chol(G)``. That fixes the shifts
    up to a common rotation and a reflection: the sense is taken from `nominal` and the
    shifts' mean offset from it removed (the phase at the group's mean time). A closed form of
    the principal-component approach to phase shifting with unknown steps (Vargas, Quiroga and
    Belenguer, Opt. Lett. 36(8), 1326, 2011), here per region. ``values (T, N, P)``,
    ``weight (T, P)``; returns ``(T, N)`` radians (NaN where a region does not solve).
    """
    n_tiles, n, _ = values.shape
    mean = np.sum(weight[:, None, :] * values, axis=-1, keepdims=True) / np.maximum(
        weight.sum(axis=-1), 1)[:, None, None]
    centred = (values - mean) * np.sqrt(weight)[:, None, :]
    gram = centred @ np.swapaxes(centred, 1, 2)  # (T, N, N); the frames' mean taken out
    # the per-frame mean over the region is not 1·a: take the constant vector out explicitly
    ones = np.full(n, 1 / np.sqrt(n))
    proj = np.eye(n) - np.outer(ones, ones)
    gram = proj @ gram @ proj
    _, vectors = np.linalg.eigh(gram)
    r = vectors[:, :, -2:]  # (T, N, 2): the quadrature pair's span
    x, y = r[..., 0], r[..., 1]
    design = np.stack([x * x, 2 * x * y, y * y], axis=-1)  # (T, N, 3)
    g = np.einsum("tij,tj->ti", np.linalg.pinv(design), np.ones((n_tiles, n)))
    out = np.full((n_tiles, n), np.nan)
    G = np.stack([np.stack([g[:, 0], g[:, 1]], -1), np.stack([g[:, 1], g[:, 2]], -1)], -2)
    good = (g[:, 0] > 0) & (g[:, 0] * g[:, 2] - g[:, 1] ** 2 > 0)
    if not good.any():
        return out
    Q = np.linalg.cholesky(G[good])
    e = r[good] @ Q  # (T', N, 2): cos δ, sin δ up to a rotation and a reflection
    delta = np.arctan2(e[..., 1], e[..., 0])
    # the sense of the nominal sequence
    turn = np.angle(np.exp(1j * np.diff(delta, axis=-1)))
    nominal_turn = np.angle(np.exp(1j * np.diff(nominal)))
    flip = np.sum(turn * nominal_turn, axis=-1) < 0
    delta[flip] = -delta[flip]
    offset = np.angle(np.exp(1j * (delta - nominal)))
    # no mean offset (the phase at the group's mean time), wrapped again to (−π, π]
    offset = np.angle(np.exp(1j * offset)
                      * np.conj(np.mean(np.exp(1j * offset), axis=-1, keepdims=True)))
    out[good] = nominal + offset
    return out


def fit_pixel_shifts(values: np.ndarray, shifts: np.ndarray) -> np.ndarray:
    """Per pixel least squares ``a, C, S`` of ``I_k = a + C cos δ_k − S sin δ_k`` with each
    pixel's own phase shifts (the PMP model of :mod:`nail2nail.scan.phase_shift`,
    ``I_k = A + B cos(φ + δ_k)`` with ``φ = atan2(S, C)``, ``B = hypot(C, S)``, solved by its
    3 × 3 normal equations where the shifts are not equally spaced).

    Parameters
    ----------
    values : (N, H, W) float
        One phase-shift group's frames.
    shifts : (N, H, W) or (N, 1, 1) float
        Each frame's shift, rad, per pixel or for all.

    Returns
    -------
    (3, H, W) float64
        ``a, C, S`` (not finite where a pixel's shifts leave the system singular: fewer than
        three distinct shifts modulo 2π).

    Notes
    -----
    The thesis's PMP model (chapter two) with each pixel's own shifts; for the nominal, equally
    spaced shifts of a still finger it is :func:`nail2nail.scan.phase_shift.wrapped_phase`'s
    fit (tested against per-pixel least squares in ``tests/test_simulation_motion.py``).
    """
    shifts = np.broadcast_to(shifts, np.shape(values))
    cos, sin = np.cos(shifts), -np.sin(shifts)
    # the symmetric normal matrix [[n, Σc, Σs], [Σc, Σcc, Σcs], [Σs, Σcs, Σss]] per pixel,
    # inverted by its cofactors (vectorised; np.linalg.solve per pixel is 4 × slower)
    n = float(values.shape[0])
    sc, ss = cos.sum(axis=0), sin.sum(axis=0)
    scc, scs, sss = (cos * cos).sum(axis=0), (cos * sin).sum(axis=0), (sin * sin).sum(axis=0)
    r0, r1, r2 = values.sum(axis=0), (cos * values).sum(axis=0), (sin * values).sum(axis=0)
    k00, k01, k02 = scc * sss - scs * scs, sc * sss - ss * scs, sc * scs - ss * scc
    k11, k12, k22 = n * sss - ss * ss, n * scs - sc * ss, n * scc - sc * sc
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_det = 1.0 / (n * k00 - sc * k01 + ss * k02)
        return np.stack([(k00 * r0 - k01 * r1 + k02 * r2) * inv_det,
                         (-k01 * r0 + k11 * r1 - k12 * r2) * inv_det,
                         (k02 * r0 - k12 * r1 + k22 * r2) * inv_det])


def _phase_design(nominal: np.ndarray) -> np.ndarray:
    """``(N, 3)`` design ``[1, cos δ_k, −sin δ_k]`` of a group's frames ``a + C cos δ − S sin δ``
    (so ``atan2(S, C)`` is the fringe phase up to the pattern set's sign convention, the same
    for every group of a set)."""
    return np.stack([np.ones(len(nominal)), np.cos(nominal), -np.sin(nominal)], axis=-1)


def register_frequencies(frames, pattern_set: PatternSet, mask=None, *,
                         sigma_px: float = REGISTRATION_SIGMA_PX,
                         saturation: float | None = None,
                         regularise_order: bool = True,
                         smooth_px: float = COARSE_SMOOTHING_PX) -> tuple[np.ndarray, dict]:
    """Frames whose coarser frequencies are shifted in phase to agree with the finest's.

    Temporal unwrapping takes the fringe order of frequency ``n_f`` from the next coarser
    ``n_c``: ``r = (n_f / n_c) Φ_c − φ_f`` must be a multiple of ``2π`` up to noise (the
    decoder refuses a misfit over its unwrap tolerance, π/2 by default). The frequencies are
    shown one after another: a finger that moves between them changes its projector coordinate
    by ``Δu`` and adds ``2π n_f Δu / size`` to the misfit, a field as smooth as the motion
    (rigid) and the surface. Per direction, from the finest frequency down, the misfit's
    wrapped value is averaged over a Gaussian window (σ `sigma_px`, a circular mean weighted by
    both fringes' amplitude) and taken out of the coarser phase, ``Φ_c ← Φ_c − δ n_c / n_f``;
    the coarser group's frames are re-synthesised as ``a + b cos(Φ_c + δ_k)``. The finest
    frequency, which sets the geometry, is not changed: only the fringe order the coarser
    ones give it. A misfit of more than half a fine period (about 0.5 / n_f of the panel) is
    beyond reach: it wraps and gives a whole period's error over its region.

    Only for ``"pmp"`` pattern sets whose consecutive frequencies of a direction have an
    integer ratio (the default 1, 8, 64); other sets are returned as they are. Phases follow
    :func:`_phase_design` (the sign convention of every group alike), pixels are ``[row, col]``
    of the camera image, windows in camera pixels.

    References
    ----------
    Hierarchical temporal unwrapping and its noise amplification by the frequency ratio: Zuo,
    Huang, Tao, Feng, Chen and Chen, "Temporal phase unwrapping algorithms for fringe projection
    profilometry: a comparative review", Opt. Lasers Eng. 85, 84–103 (2016),
    doi:10.1016/j.optlaseng.2016.04.022; the fringe order's median-filter correction is the
    practice reviewed there. The thesis unwraps a still finger (its eq. 3.12–3.14 take the
    unwrapped phase as given).

    Parameters
    ----------
    frames : (n_frames, H, W) array
        One camera's frames; not modified.
    pattern_set : PatternSet
    mask : (H, W) bool, optional
        Pixels to average the misfit over; None: those whose fringe amplitude in both groups
        is at least 2 % of the frames' largest value.
    sigma_px : float
    saturation : float, optional
        Frame value at or above which a pixel keeps its frames.

    Returns
    -------
    frames : (n_frames, H, W) array of the input's dtype
    info : dict
        ``{"levels": [{"label", "misfit_rms_rad", "misfit_max_rad"}]}``, the misfit taken out
        of each coarser group (over the weighted pixels).
    """
    frames = np.asarray(frames)
    out = frames.copy()
    info: dict = {"levels": []}
    if pattern_set.scheme != "pmp":
        return out, info
    table = frame_table(pattern_set)
    full = float(frames.max()) if frames.size else 1.0
    integer = np.issubdtype(frames.dtype, np.integer)
    keep = np.zeros(frames.shape[1:], bool)
    if saturation is not None:
        keep |= (frames >= saturation).any(axis=0)
    for direction in pattern_set.directions:
        groups = sorted(
            ((row.periods, [r.index for r in table if r.kind == "phase"
                            and r.direction == direction and r.periods == row.periods])
             for row in table if row.kind == "phase" and row.direction == direction
             and row.step == 0), reverse=True)
        if len(groups) < 2:
            continue
        ratios = [f / c for (f, _), (c, _) in itertools.pairwise(groups)]
        if any(abs(q - round(q)) > 1e-9 for q in ratios):
            continue
        coefficients = []
        for _, idx in groups:
            nominal = np.array([table[i].shift for i in idx])
            values = frames[idx].astype(np.float64)
            coef = np.einsum("ck,khw->chw", np.linalg.pinv(_phase_design(nominal)), values)
            coefficients.append((nominal, coef))
        phases = [np.arctan2(coefficients[0][1][2], coefficients[0][1][1])]
        amplitudes = [np.hypot(coefficients[0][1][1], coefficients[0][1][2])]
        lit = amplitudes[0] >= 0.02 * full
        for level in range(1, len(groups)):
            ratio = ratios[level - 1]
            _, (_, c, s) = coefficients[level]
            amplitudes.append(np.hypot(c, s))
            lit &= amplitudes[-1] >= 0.02 * full
            weight = ((amplitudes[-1] >= 0.02 * full) & (amplitudes[-2] >= 0.02 * full)
                      if mask is None else np.asarray(mask, bool)).astype(float)
            coarse = np.arctan2(s, c)
            if smooth_px > 0:  # the coarse phase only orders: average its noise away
                lit_c = (amplitudes[-1] >= 0.02 * full).astype(float)
                phasor = lit_c * np.exp(1j * coarse)
                cover = ndi.gaussian_filter(lit_c, smooth_px, mode="constant")
                smooth = np.angle(ndi.gaussian_filter(phasor.real, smooth_px, mode="constant")
                                  + 1j * ndi.gaussian_filter(phasor.imag, smooth_px,
                                                             mode="constant"))
                # only where the window is whole: a one-sided mean of a ramp is biased
                coarse = np.where(cover >= MIN_SMOOTHING_COVER, smooth, coarse)
            misfit = np.exp(1j * (ratio * coarse - phases[-1]))
            total = ndi.gaussian_filter(weight, sigma_px)
            with np.errstate(invalid="ignore", divide="ignore"):
                mean = (ndi.gaussian_filter(weight * misfit.real, sigma_px)
                        + 1j * ndi.gaussian_filter(weight * misfit.imag, sigma_px)) / total
            delta = np.where(total > 1e-3, np.angle(mean), 0.0)
            phases.append(coarse - delta / ratio)
            used = weight > 0
            info["levels"].append({
                "label": f"{direction}/{groups[level][0]:g}",
                "misfit_rms_rad": round(float(np.sqrt(np.mean(delta[used] ** 2))), 4)
                if used.any() else None,
                "misfit_max_rad": round(float(np.abs(delta[used]).max()), 4)
                if used.any() else None,
            })
        if regularise_order:
            valid = lit if mask is None else np.asarray(mask, bool)
            phases, changed = _regularised_orders(phases, [g[0] for g in groups], valid)
            info["levels"][-1]["orders_changed"] = int(changed)
        for level in range(1, len(groups)):
            nominal, (a, _, _) = coefficients[level]
            # a + C cos δ − S sin δ with (C, S) = b (cos Φ, sin Φ)
            synthetic = a + amplitudes[level] * np.cos(phases[level][None]
                                                       + nominal[:, None, None])
            if integer:
                synthetic = np.clip(np.rint(synthetic), 0, np.iinfo(frames.dtype).max)
            idx = groups[level][1]
            out[idx] = np.where(keep, frames[idx], synthetic).astype(frames.dtype)
    return out, info


#: Half side of the window whose median fringe order :func:`register_frequencies` gives a pixel
#: (5 × 5: a fine fringe spans 10 or more camera pixels on a finger).
ORDER_RADIUS_PX = 2
#: Smallest share of a neighbourhood (9 × 9) whose own fringe order agrees with its median for
#: the median to be given to a pixel.
MIN_ORDER_AGREEMENT = 0.75


def _regularised_orders(phases: list, periods: list, valid: np.ndarray,
                        radius: int = ORDER_RADIUS_PX) -> tuple[list, int]:
    """Coarser phases that give every pixel the fringe order of its neighbourhood.

    ``phases`` are one direction's wrapped phases from the finest frequency down (already
    registered to one another), ``periods`` theirs. The finest phase is unwrapped through the
    coarser ones (each pixel on its own), and the median of the unwrapped phase over a
    ``(2r + 1)²`` window of `valid` pixels taken as the reference: a pixel whose coarse phase
    noise (times the frequency ratio) gave it a wrong order differs from it by about ``2π``.
    The coarser phases are then replaced by the median scaled to their frequency: the temporal
    unwrapping reads the neighbourhood's order, and its residual is the pixel's distance from
    its neighbourhood's median (a pixel that disagrees with its neighbours is still refused).
    Pixels with fewer than half a window of valid neighbours keep their phases. Returns the
    phases and the number of valid pixels whose order changed.
    """
    ascending = [np.mod(p, 2 * np.pi) for p in phases[::-1]]
    unwrapped, _ = unwrap_hierarchical(ascending, periods[::-1], tolerance=np.inf)
    unwrapped = unwrapped.astype(np.float64)
    side = 2 * radius + 1
    if not valid.any():
        return phases, 0
    # invalid pixels take their nearest valid one's value (the median's window then sees the
    # valid area's edge repeated, as a replicate padding would)
    _, nearest = ndi.distance_transform_edt(~valid, return_indices=True)
    filled = unwrapped[nearest[0], nearest[1]]
    count = ndi.uniform_filter(valid.astype(float), side, mode="constant") * side * side
    enough = valid & (count >= 0.5 * side * side)
    median = np.where(enough, ndi.median_filter(filled, size=side, mode="nearest"), np.nan)
    use = np.isfinite(median)
    # where most pixels' own order disagrees with their median the neighbourhood itself is in
    # doubt (noise or a misfit beyond half a period): leave those to the decoder's check
    agree = use & (np.abs(unwrapped - median) < np.pi)
    near = 4 * radius + 1
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = (ndi.uniform_filter(agree.astype(float), near, mode="constant")
                / ndi.uniform_filter(use.astype(float), near, mode="constant"))
    use &= rate >= MIN_ORDER_AGREEMENT
    fine = np.mod(phases[0], 2 * np.pi)
    before = np.rint((unwrapped - fine) / (2 * np.pi))
    after = np.rint((median - fine) / (2 * np.pi))
    changed = int(np.count_nonzero(use & (before != after)))
    out = [phases[0]]
    for period, phase in zip(periods[1:], phases[1:], strict=True):
        out.append(np.where(use, median * (period / periods[0]), phase))
    return out, changed


def compensate_phase_steps(frames, pattern_set: PatternSet, mask, *,
                           tile_px: int = COMPENSATION_TILE_PX,
                           saturation: float | None = None,
                           between_frequencies: bool = True) -> tuple[np.ndarray, dict]:
    """Frames of a moving finger corrected for the phase offsets motion puts between steps.

    Within one phase-shift group a moving surface adds an unknown offset ``ε_k`` to each step's
    nominal shift ``δ_k``, nearly uniform over a small region (rigid motion is smooth): the
    decoded phase ripples at the fringe frequency. Per region of `tile_px` × `tile_px` pixels
    and per group with 4 or more steps whose fringe phase spreads over the region (at least
    :data:`MIN_PHASE_SPREAD` rad), the actual shifts are estimated from the frames' subspace
    (:func:`_tile_shifts`), interpolated between regions' centres, and each pixel's
    ``a, b, φ`` solved with them; the group's frames are then replaced by
    ``a + b cos(φ + δ_k)`` with the nominal shifts, so that any decoder reads the phase at
    the group's mean time. Three-step groups (a pixel's three unknowns fit any three shifts),
    coarse groups (too little phase in a region) and saturated pixels keep their frames.

    Then, with `between_frequencies`, the coarser frequencies' phases are registered to the
    finest's (:func:`register_frequencies`), so that the motion between groups does not break
    the temporal unwrapping. Not corrected: the two directions, shown at different times, and
    the skin's texture moving under the fringes.

    Parameters
    ----------
    frames : (n_frames, H, W) array
        One camera's frames (integer values or floats); not modified.
    pattern_set : PatternSet
        A PMP pattern set (other schemes are returned as they are).
    mask : (H, W) bool or None
        The pixels to learn the offsets from (e.g. a first decoding's valid pixels); None:
        those whose fringe amplitude in the group is at least 2 % of the frames' largest
        value.
    tile_px : int
    saturation : float, optional
        Frame value at or above which a pixel keeps its frames.
    between_frequencies : bool
        Also register the frequencies to one another (default).

    Returns
    -------
    frames : (n_frames, H, W) array of the input's dtype
    info : dict
        ``"groups"``, per group: its label, the regions estimated, and the RMS and largest
        offset (rad); ``"levels"``: :func:`register_frequencies`'s.
    """
    frames = np.asarray(frames)
    out = frames.copy()
    info: dict = {"groups": []}
    if pattern_set.scheme != "pmp":
        return out, info
    _, height, width = frames.shape
    full = float(frames.max()) if frames.size else 1.0
    ty, tx = max(1, height // tile_px), max(1, width // tile_px)
    h, w = ty * tile_px, tx * tile_px
    table = frame_table(pattern_set)
    integer = np.issubdtype(frames.dtype, np.integer)
    top = np.iinfo(frames.dtype).max if integer else None
    for label, idx in dc_groups(pattern_set):
        n = len(idx)
        if n < 4 or table[idx[0]].kind != "phase":
            continue
        nominal = np.array([table[i].shift for i in idx])
        stack = frames[idx, :h, :w].astype(np.float64)
        tiles = stack.reshape(n, ty, tile_px, tx, tile_px).transpose(1, 3, 0, 2, 4)
        tiles = tiles.reshape(ty * tx, n, tile_px * tile_px)
        # the phase and amplitude of each pixel under the nominal shifts
        coef = np.linalg.pinv(_phase_design(nominal)) @ tiles
        if mask is None:
            weight = np.hypot(coef[:, 1], coef[:, 2]) >= 0.02 * full
        else:
            weight = np.asarray(mask, bool)[:h, :w].reshape(ty, tile_px, tx, tile_px)
            weight = weight.transpose(0, 2, 1, 3).reshape(ty * tx, tile_px * tile_px)
        weight = weight.astype(np.float64)
        phase = np.exp(1j * np.arctan2(coef[:, 2], coef[:, 1]))
        count = weight.sum(axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            resultant = np.abs(np.sum(weight * phase, axis=-1)) / count
        spread = np.sqrt(-2 * np.log(np.clip(resultant, 1e-12, 1)))
        usable = (count >= 0.5 * tile_px * tile_px) & (spread >= MIN_PHASE_SPREAD)
        if not usable.any():
            continue
        delta = np.broadcast_to(nominal, (ty * tx, n)).copy()
        delta[usable] = _tile_shifts(tiles[usable], weight[usable], nominal)
        solved = usable & np.isfinite(delta).all(axis=-1)
        if not solved.any():
            continue
        offset = np.nan_to_num(delta - nominal).reshape(ty, tx, n)
        # unmeasured regions: their nearest measured one's offsets
        have = solved.reshape(ty, tx)
        _, (ri, ci) = ndi.distance_transform_edt(~have, return_indices=True)
        offset = offset[ri, ci]
        # per pixel, bilinear between the regions' centres (ordinates in region units)
        rows = np.clip((np.arange(height) + 0.5) / tile_px - 0.5, 0, ty - 1)
        cols = np.clip((np.arange(width) + 0.5) / tile_px - 0.5, 0, tx - 1)
        rr, cc = np.meshgrid(rows, cols, indexing="ij")
        pixel_delta = np.stack([nominal[k] + ndi.map_coordinates(offset[..., k], [rr, cc],
                                                                 order=1, mode="nearest")
                                for k in range(n)])  # (n, H, W)
        values = frames[idx].astype(np.float64)
        a, c, s = fit_pixel_shifts(values, pixel_delta)
        synthetic = a + c * np.cos(nominal)[:, None, None] - s * np.sin(nominal)[:, None, None]
        keep = np.zeros((height, width), bool)
        if saturation is not None:
            keep |= (values >= saturation).any(axis=0)
        if integer:
            synthetic = np.clip(np.rint(synthetic), 0, top)
        out[idx] = np.where(keep, frames[idx], synthetic).astype(frames.dtype)
        off = offset[have]
        info["groups"].append({
            "label": label, "regions": int(solved.sum()), "of": int(ty * tx),
            "offset_rms_rad": round(float(np.sqrt(np.mean(off**2))), 4) if off.size else None,
            "offset_max_rad": round(float(np.abs(off).max()), 4) if off.size else None,
        })
    if between_frequencies:
        out, registered = register_frequencies(out, pattern_set, None, saturation=saturation)
        info.update(registered)
    return out, info
