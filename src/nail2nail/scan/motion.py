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

from dataclasses import dataclass

import numpy as np
import scipy.ndimage as ndi

from nail2nail.scan.patterns import PatternSet, frame_table

__all__ = ["MOTION_WARN_MM", "MotionEstimate", "dc_groups", "estimate_motion", "mm_per_pixel"]

#: Motion (spread of the groups' shifts) above which a capture is flagged as moving, mm: about
#: the 3D error it causes (a lateral shift of 20 µm moves the finest fringe's phase by 0.15 rad,
#: 20 µm of depth on the thesis rig), five times the still scanner's noise floor.
MOTION_WARN_MM = 0.02
#: Fewest valid pixels of a region for its own registration.
MIN_REGION_PIXELS = 4096


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
        Largest distance between two groups' shifts, whole image, px.
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
        regions = self.region_spread_px[np.isfinite(self.region_spread_px)]
        return float(max(self.spread_px, regions.max() if regions.size else 0.0))

    @property
    def motion_mm(self) -> float | None:
        """:attr:`max_spread_px` in mm (None without the scan's sampling)."""
        if self.mm_per_px is None or not np.isfinite(self.mm_per_px):
            return None
        return self.max_spread_px * self.mm_per_px

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
    """Median distance between horizontally adjacent valid points of a scan, mm."""
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


def _band(image: np.ndarray, sigma_px: tuple[float, float]) -> np.ndarray:
    return (ndi.gaussian_filter(image, sigma_px[0])
            - ndi.gaussian_filter(image, sigma_px[1]))


def _block_mean(image: np.ndarray, f: int) -> np.ndarray:
    if f == 1:
        return image
    h, w = (image.shape[0] // f) * f, (image.shape[1] // f) * f
    return image[:h, :w].reshape(h // f, f, w // f, f).mean(axis=(1, 3))


def _correlate(a: np.ndarray, b: np.ndarray, window: np.ndarray) -> tuple[float, float]:
    """Shift ``(dx, dy)`` of `b` against `a`, px: cross-correlation (not whitened: a whitened
    one weighs the static edge of the window as much as the moving texture) refined by an upsampled
    DFT to 1/20 px (Guizar-Sicairos et al., Opt. Lett. 33(2), 156, 2008; scikit-image)."""
    from skimage.registration import phase_cross_correlation

    shift, _, _ = phase_cross_correlation(a * window, b * window, upsample_factor=20,
                                          normalization=None)
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
                               iterations=max(2, round(0.3 / (scale * f))))
    window = ndi.gaussian_filter(inner.astype(np.float32), sigma[1])
    images = []
    for _, idx in groups:
        dc = np.zeros((r1 - r0, c1 - c0), np.float32)
        for i in idx:
            dc += frames[i][r0:r1, c0:c1]
        images.append(_band(_block_mean(dc, f), sigma))
    n = len(images)
    shift = np.zeros((n, 2))
    for g in range(1, n):
        shift[g] = _correlate(images[0], images[g], window)
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
            for g in range(1, n):
                region[g, i, j] = _correlate(images[0][sl], images[g][sl], window[sl])
    region_spread = np.array([[_spread(region[:, i, j]) for j in range(tiles)]
                              for i in range(tiles)])
    # back to camera pixels
    return MotionEstimate(labels=[g[0] for g in groups],
                          frames=[(min(g[1]), max(g[1])) for g in groups], shift_px=shift * f,
                          region_shift_px=region * f, spread_px=_spread(shift) * f,
                          region_spread_px=region_spread * f, mm_per_px=mm_per_px)
