"""From per-camera scans to a rolled-equivalent print (the pipeline's last stage).

:func:`unroll_scans` runs, in order: the ridge signal of every camera
(:func:`~nail2nail.unroll.ridges.ridge_signal`), the flattening map fitted to all cameras'
points (:func:`~nail2nail.unroll.flatten.fit_flattening`), the blend of the cameras on the
print grid (:mod:`~nail2nail.unroll.render`), the 8-bit print, its binarised version, and
quality figures (:mod:`~nail2nail.unroll.quality`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nail2nail._timing import StepClock
from nail2nail.io.rolled import ROLLED_FORMAT, ROLLED_LENGTH_MM
from nail2nail.scan.results import Scan
from nail2nail.unroll.flatten import (
    METHODS,
    CylinderMap,
    IsometricMap,
    RolledMap,
    SphereMap,
    fit_flattening,
    map_distortion,
)
from nail2nail.unroll.mixing import clarity_map, gate_mask, mix_layers
from nail2nail.unroll.quality import block_quality
from nail2nail.unroll.render import (
    PrintGrid,
    binarize,
    blend_cameras,
    camera_samples,
    print_grid,
    to_gray,
)
from nail2nail.unroll.ridges import camera_layer, masked_gaussian, scan_valid

__all__ = ["DEFAULT_LENGTH_MM", "DEFAULT_METHOD", "FLOOR_FRACTION", "MIN_CLARITY", "RolledPrint",
           "image_up_direction", "unroll_scans"]

#: The default unrolling method: the one with the least length and area distortion (README).
DEFAULT_METHOD = "rolled"

#: Length of skin kept below the fingertip by default, mm (:data:`~nail2nail.io.rolled.
#: ROLLED_LENGTH_MM`)
DEFAULT_LENGTH_MM = ROLLED_LENGTH_MM

#: RMS floor of the ridge signal's local normalisations, as a fraction of the ridges' level
#: (``unroll.ridges.local_normalize``): skin without ridges stays faint, not blown up
FLOOR_FRACTION = 0.5

#: The grey print's RMS floor, as a fraction of the (already normalised) signal's level: the
#: print equalises the blend's contrast without lifting what the camera layers left faint
GRAY_FLOOR_FRACTION = 0.8

#: σ of the ridge signal's high-pass, mm (``unroll.ridges.camera_layer``): periods of a few mm
#: (the scanner's periodic errors, shading bands) are not ridges
HIGHPASS_MM = 0.35

#: Print pixels whose ridge signal's local RMS (of the normalised signal, 1 mm) is below this
#: are left out: a faint region carries no ridges (the RMS floor keeps such regions faint)
MIN_AMPLITUDE = 0.5

#: Print pixels whose ridge clarity (3.2 mm blocks, ``unroll.mixing.clarity_map``) is below
#: this are left out of the print (masked, white): no ridges there to print
MIN_CLARITY = 0.3


@dataclass
class RolledPrint:
    """A rolled-equivalent print in the legacy convention (mirror of the pad view, tip up).

    Attributes
    ----------
    image : (H, W) uint8
        Ridges dark on white; 255 off `mask`.
    mask : (H, W) bool
        Pixels with data.
    binary : (H, W) uint8
        Ridges 0, everything else 255.
    ridge : (H, W) float32
        The blended ridge signal (positive on crests); NaN off `mask`.
    share : (n_cameras, H, W) float32
        Each camera's fraction of the blend per pixel.
    grid : PrintGrid
        Pixel ↔ print-plane geometry and resolution.
    method : str
    flattening : object
        The flattening map (world points ``(N, 3)`` → print plane ``(N, 2)``, mm).
    cameras : list of str
    distortion : dict
        Length and area distortion of the map over the scanned skin
        (:func:`~nail2nail.unroll.flatten.map_distortion`).
    quality : dict
        Block ridge period and clarity (:func:`~nail2nail.unroll.quality.block_quality`).
    timings : dict
        Seconds per step.
    """

    image: np.ndarray
    mask: np.ndarray
    binary: np.ndarray
    ridge: np.ndarray
    share: np.ndarray
    grid: PrintGrid
    method: str
    flattening: CylinderMap | SphereMap | IsometricMap | RolledMap
    cameras: list[str]
    distortion: dict
    quality: dict
    timings: dict = field(default_factory=dict)

    @property
    def ppi(self) -> float:
        """Pixels per inch."""
        return self.grid.ppi

    def pixel_of(self, xyz) -> tuple[np.ndarray, np.ndarray]:
        """``(row, col)`` (float) in this print of world points ``(N, 3)``, mm."""
        return self.grid.pixel(self.flattening(np.asarray(xyz, dtype=np.float64)))

    def metadata(self) -> dict:
        """JSON-ready description: geometry, method, distortion, coverage and quality."""
        area_px = int(self.mask.sum())
        pitch = self.grid.pitch
        dominant = np.argmax(self.share, axis=0)
        coverage = {}
        for i, name in enumerate(self.cameras):
            contributes = self.mask & (self.share[i] > 0.01)
            coverage[name] = {
                "contributes_fraction": round(float(contributes.sum()) / max(area_px, 1), 4),
                "dominant_fraction": round(
                    float((self.mask & (dominant == i)).sum()) / max(area_px, 1), 4),
            }
        q = self.quality
        clarity = np.asarray(q["clarity"])
        period = np.asarray(q["period_px"])
        return {
            "format": ROLLED_FORMAT,
            "version": 1,
            "convention": "legacy rolled print: mirror of the pad seen from outside, fingertip "
                          "up; ridges dark on white",
            **self.grid.describe(),
            "method": self.method,
            "flattening": self.flattening.describe(),
            "cameras": list(self.cameras),
            "print_area_mm2": round(area_px * pitch * pitch, 2),
            "print_size_mm": _extent_mm(self.mask, pitch),
            "distortion": self.distortion,
            "coverage": coverage,
            "quality": {
                "measure": "ridge clarity per 3.2 mm block (overlapping by half): fraction of "
                           "spectral energy in the ring of the ridge frequency (1 = clean "
                           "ridges, about 0.1 for noise)",
                "blocks": int(clarity.size),
                "clarity_median": _r(np.median(clarity)) if clarity.size else None,
                "clarity_p10": _r(np.percentile(clarity, 10)) if clarity.size else None,
                "ridge_period_mm_median": _r(np.median(period) * pitch) if period.size else None,
                "regions": _region_quality(q, self.share, self.cameras),
                "mixing": q.get("mixing"),
                "gate": q.get("gate"),
            },
            "timings_s": {k: round(v, 4) for k, v in self.timings.items()},
        }


def _r(x) -> float:
    return round(float(x), 4)


def _extent_mm(mask, pitch) -> list[float]:
    rows, cols = np.nonzero(mask)
    if not rows.size:
        return [0.0, 0.0]
    return [round((cols.max() - cols.min() + 1) * pitch, 2),
            round((rows.max() - rows.min() + 1) * pitch, 2)]


def _region_quality(q, share, cameras) -> dict:
    """Median clarity of the blocks where each camera dominates (the print's regions)."""
    if not np.asarray(q["clarity"]).size:
        return {}
    r = np.asarray(q["rows"]).round().astype(int)
    c = np.asarray(q["cols"]).round().astype(int)
    dom = np.argmax(share[:, r, c], axis=0)
    out = {}
    for i, name in enumerate(cameras):
        sel = dom == i
        out[name] = {"blocks": int(sel.sum()),
                     "clarity_median": _r(np.median(q["clarity"][sel])) if sel.any() else None}
    return out


def _cut_length(grid: PrintGrid, value, mask, share, length_mm: float):
    """Drop the rows more than `length_mm` below the print's top row with data; crop."""
    if not length_mm > 0:
        raise ValueError(f"length_mm: expected a positive length, got {length_mm}")
    rows = np.flatnonzero(mask.any(axis=1))
    last = min(mask.shape[0] - 1, rows[0] + int(np.floor(length_mm / grid.pitch)))
    keep = min(mask.shape[0], last + 1 + int(np.ceil(1.0 / grid.pitch)))  # 1 mm margin
    mask = mask[:keep].copy()
    mask[last + 1:] = False
    value = np.where(mask, value[:keep], np.nan).astype(np.float32)
    share = share[:, :keep] * mask
    return PrintGrid(grid.s0, grid.t0, grid.pitch, mask.shape), value, mask, share


def image_up_direction(scans, *, step: int = 4) -> np.ndarray:
    """The world direction that is *up* in the cameras' images, measured on their scans.

    For each scan, the mean world displacement from a valid pixel to the valid pixel above it
    (row ``r`` to ``r - 1``), on every `step`-th row and column, made unit; then the mean of
    the cameras' unit vectors. It depends on no world frame and no calibration: a finger whose
    tip points to the top of the images (the thesis's and the virtual scanner's layout, and
    the legacy print's "fingertip up") has its tip along this direction.

    Parameters
    ----------
    scans : sequence of Scan
        Scans on their camera's pixel grid (``xyz (H, W, 3)``, world mm).
    step : int
        Sampling of rows and columns, camera px.

    Returns
    -------
    (3,) float64
        Unit vector, world frame.

    Raises
    ------
    ValueError
        When no scan has two valid pixels one above the other.
    """
    total = np.zeros(3)
    for s in scans:
        xyz = np.asarray(s.xyz)[::step, ::step].astype(np.float64)
        valid = np.asarray(s.mask)[::step, ::step] & np.all(np.isfinite(xyz), axis=-1)
        both = valid[:-1] & valid[1:]
        if not both.any():
            continue
        up = np.mean((xyz[:-1] - xyz[1:])[both], axis=0)
        norm = np.linalg.norm(up)
        if norm > 0:
            total += up / norm
    norm = np.linalg.norm(total)
    if not norm > 0:
        raise ValueError("scans: cannot tell the images' up direction (no two valid pixels one "
                         "above the other); give tip_direction")
    return total / norm


def unroll_scans(
    scans,
    *,
    method: str = DEFAULT_METHOD,
    ppi: float = 500.0,
    tip_direction=None,
    pad_direction=None,
    ridge_options: dict | None = None,
    feather_px: float = 40.0,
    grid_mm: float = 0.5,
    length_mm: float | None = DEFAULT_LENGTH_MM,
    mix: bool = True,
    min_clarity: float | None = MIN_CLARITY,
) -> RolledPrint:
    """Unroll a finger scanned by one or more cameras into a rolled-equivalent print.

    Parameters
    ----------
    scans : sequence of Scan
        Every camera's scan of one finger with all its valid pixels (the output of
        :func:`nail2nail.scan.capture.scan_capture`), in one world frame; overlaps are blended.
    method : {"cylinder", "sphere", "rolled", "isometric"}
        Flattening (:mod:`nail2nail.unroll.flatten`); ``rolled`` by default, the method with
        the smallest geometric error against the true skin coordinates (``docs/unroll.md``).
    ppi : float
        Resolution of the print, pixels per inch (500 is the FBI's rolled-print standard).
    tip_direction : (3,) float, optional
        Rough direction of the fingertip in the world frame (only its sign along the finger's
        axis matters). Default: up in the cameras' images (:func:`image_up_direction`), i.e.
        the fingertip points to the top of the images, whatever the world frame (world ``+Y``
        on the virtual scanner and the thesis's rig).
    pad_direction : (3,) float, optional
        Direction from the finger's axis to the middle of the pad (``s = 0``), taken as given.
        Default: the symmetry line of the finger's section
        (:func:`~nail2nail.unroll.flatten.section_pad`: the smallest radius of its elliptic
        part) nearest the mean direction from the points to the cameras' centres (else
        ``+Z``); that rough direction itself when the section is round.
    ridge_options : dict, optional
        Keyword arguments of :func:`~nail2nail.unroll.ridges.camera_layer`.
    feather_px : float
        Width of each camera's cross-fade at the edge of its valid region, camera px.
    grid_mm : float
        Cell size of the coarse mesh the flattening is fitted and judged on, mm.
    length_mm : float or None
        Keep only the skin within this distance (print-plane ``t``) below the fingertip, as an
        inked roll does: :data:`DEFAULT_LENGTH_MM` (25 mm reaches the distal crease of an
        adult finger); None keeps everything the cameras saw.
    mix : bool
        Blend relief and albedo apart and average them by their measured ridge clarity, the
        albedo's sign measured (:func:`~nail2nail.unroll.mixing.mix_layers`); normalise with
        an RMS floor (``FLOOR_FRACTION`` of the ridges' level) and take the smooth surface's
        curvature bias back. False: the fixed sum of earlier versions (relief + 0.3 × albedo,
        no floor), for comparison.
    min_clarity : float or None
        Leave out of the print (mask) the pixels whose ridge clarity is below this
        (:func:`~nail2nail.unroll.mixing.clarity_map`, 3.2 mm blocks) or whose signal is faint
        (local RMS of the normalised signal under ``MIN_AMPLITUDE``): skin without a ridge
        signal is not printed as noise or stripes (the faint test with `mix` only). None: keep
        every pixel with data.

    Returns
    -------
    RolledPrint

    Raises
    ------
    ValueError
        No scans, a scan without valid pixels, an unknown method, a bad `ppi`.
    """
    scans = list(scans)
    if not scans:
        raise ValueError("scans: expected at least one Scan")
    for i, s in enumerate(scans):
        if not isinstance(s, Scan):
            raise TypeError(f"scans[{i}]: expected a Scan, got {type(s).__name__}")
    if method not in METHODS:
        raise ValueError(f"method: expected one of {', '.join(METHODS)}, got {method!r}")
    if not (isinstance(ppi, (int, float)) and 100 <= ppi <= 4000):
        raise ValueError(f"ppi: expected a number in 100..4000, got {ppi!r}")
    lap = StepClock()
    timings = lap.seconds

    picked, valids = [], []
    for s in scans:
        v = scan_valid(s)
        if not v.any():
            raise ValueError(f"scans: {s.name!r} has no valid pixels")
        valids.append(v)
        # every fourth valid point (row-major), converted once they are picked
        xyz = np.asarray(s.xyz).reshape(-1, 3)
        picked.append(xyz[np.flatnonzero(v)[::4]].astype(np.float64))
    points = np.concatenate(picked)
    if tip_direction is None:
        tip_direction = image_up_direction(scans)
    pad_from_section = pad_direction is None
    if pad_direction is None:
        centers = [np.asarray(s.camera_center, float) for s in scans if s.camera_center is not None]
        if centers:
            centroid = points.mean(axis=0)
            pad_direction = np.mean([(c - centroid) / np.linalg.norm(c - centroid)
                                     for c in centers], axis=0)
        else:
            pad_direction = (0.0, 0.0, 1.0)
    flat, mesh = fit_flattening(points, method, tip_direction=tip_direction,
                                pad_direction=pad_direction, grid_mm=grid_mm,
                                pad_from_section=pad_from_section)
    lap("flatten")
    options = dict(ridge_options or {})
    if mix:
        options = {"floor_fraction": FLOOR_FRACTION, "curvature": True,
                   "highpass_mm": HIGHPASS_MM, **options}
    layers = [camera_layer(s, feather_px=feather_px, valid=v, separate=mix, **options)
              for s, v in zip(scans, valids, strict=True)]
    lap("ridges")
    samples, albedo_samples = [], []
    for s, layer in zip(scans, layers, strict=True):
        sig, wt = layer[0], layer[-1]
        samples.append(camera_samples(s, sig, wt, flat))
        if mix and layer[1] is not None:
            ok = (wt > 0) & np.isfinite(sig)  # the samples' pixels, row-major
            st, _, w = samples[-1]
            albedo_samples.append((st, np.nan_to_num(layer[1][ok]), w))
    grid = print_grid([st for st, _, _ in samples], ppi=ppi)
    # the outline smoothed over about one ridge period (0.5 mm)
    value, mask, share = blend_cameras(grid, samples, edge_sigma_px=0.25 / grid.pitch)
    albedo = None
    if albedo_samples and len(albedo_samples) == len(samples):
        albedo, _, _ = blend_cameras(grid, albedo_samples, edge_sigma_px=0.25 / grid.pitch)
    lap("blend")
    if not mask.any():
        raise ValueError("scans: the print has no pixel with data")
    if length_mm is not None:
        grid, value, mask, share = _cut_length(grid, value, mask, share, length_mm)
        if albedo is not None:
            albedo = albedo[:mask.shape[0]]
    pitch = grid.pitch
    mixing = None
    if mix:
        value, mixing = mix_layers(value, albedo, mask, pitch)
    lap("mix")
    gray_options: dict[str, Any] = {"sigma_px": 1.0 / pitch, "reduce": max(1, int(0.25 / pitch))}
    if mix:
        gray_options["floor_fraction"] = GRAY_FLOOR_FRACTION
    image = to_gray(value, mask, **gray_options)
    gated = None
    if min_clarity is not None:
        clarity = clarity_map(image, mask, pitch)
        if mix:
            # faint: the RMS floor kept it so (no ridges' worth of signal); counts as unclear
            z = np.where(mask, (127.5 - image.astype(np.float32)) / 90.0, 0.0)
            amplitude = np.sqrt(masked_gaussian(z * z, mask, 1.0 / pitch,
                                                reduce=max(1, int(0.25 / pitch))))
            clarity = np.where(amplitude >= MIN_AMPLITUDE, clarity, 0.0)
        kept = gate_mask(clarity, mask, min_clarity=min_clarity,
                         min_area_px=round(4.0 / pitch**2))  # pieces under 4 mm² dropped
        gated = {"min_clarity": min_clarity,
                 "masked_fraction": round(1 - float(kept.sum()) / max(int(mask.sum()), 1), 4)}
        if kept.any():
            mask = kept
            value = np.where(mask, value, np.nan).astype(np.float32)
            share = share * mask
            image = np.where(mask, image, 255).astype(np.uint8)
    binary = binarize(image, mask, period_px=0.48 / pitch)
    lap("render")
    quality = block_quality(image, mask, block_px=round(3.2 / pitch))
    quality["mixing"] = None if mixing is None else {
        "albedo_share": round(mixing["albedo_share"], 4)}
    quality["gate"] = gated
    distortion = map_distortion(flat, mesh)
    lap("quality")
    return RolledPrint(image=image, mask=mask, binary=binary, ridge=value, share=share,
                       grid=grid, method=method, flattening=flat,
                       cameras=[s.name for s in scans], distortion=distortion,
                       quality=quality, timings=timings)
