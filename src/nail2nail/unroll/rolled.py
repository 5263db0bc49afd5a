"""From per-camera scans to a rolled-equivalent print (the pipeline's last stage).

:func:`unroll_scans` runs, in order: the ridge signal of every camera
(:func:`~nail2nail.unroll.ridges.ridge_signal`), the flattening map fitted to all cameras'
points (:func:`~nail2nail.unroll.flatten.fit_flattening`), the blend of the cameras on the
print grid (:mod:`~nail2nail.unroll.render`), the 8-bit print, its binarised version, and
quality figures (:mod:`~nail2nail.unroll.quality`).
"""

from __future__ import annotations

import numbers
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
    bulk_sphere,
    fit_flattening,
    map_distortion,
    within_sphere,
)
from nail2nail.unroll.mixing import (
    CLARITY_PITCH_MM,
    clarity_map,
    gate_mask,
    mix_layers,
    reduce_print,
)
from nail2nail.unroll.quality import block_quality
from nail2nail.unroll.render import (
    MM_PER_INCH,
    SUPPORT_PPI,
    PrintGrid,
    binarize,
    blend_cameras,
    camera_samples,
    gray_levels,
    normalized_print,
    print_grid,
    unsharp_mask,
)
from nail2nail.unroll.ridges import camera_layer, masked_gaussian, pixel_spacing_mm, scan_valid

__all__ = ["DEFAULT_LENGTH_MM", "DEFAULT_METHOD", "FLOOR_FRACTION", "MAX_LENGTH_MM", "MAX_PPI",
           "MIN_CLARITY", "MIN_LENGTH_MM", "MIN_PPI", "RolledPrint", "check_print_size",
           "image_up_direction", "unroll_scans"]

#: The default unrolling method: the one with the least length and area distortion (README).
DEFAULT_METHOD = "rolled"

#: Length of skin kept below the fingertip by default, mm (:data:`~nail2nail.io.rolled.
#: ROLLED_LENGTH_MM`)
DEFAULT_LENGTH_MM = ROLLED_LENGTH_MM

#: Shortest and longest skin kept below the fingertip (`length_mm`), mm: under 5 mm a print
#: holds no 3.2 mm quality block below the tip's rounded edge (about ten ridges); 100 mm is
#: longer than any finger (``length_mm=None`` keeps all the cameras saw)
MIN_LENGTH_MM = 5.0
MAX_LENGTH_MM = 100.0

#: Resolution range of the print, pixels per inch: under 100 ppi (0.25 mm pixels) a ridge
#: period of 0.4–0.5 mm is under two pixels; 2000 ppi (12.7 µm pixels) is twice the FBI's
#: finest (1000 ppi) and 2.6 times finer than the full-resolution cameras sample the skin
#: (0.033 mm), so a finer print only interpolates, at four times the memory per doubling (a
#: full-resolution finger at 2000 ppi: 31 s, 1.4 GB; at 4000 ppi its grid of 20.1 M pixels
#: exceeds :data:`~nail2nail.unroll.render.MAX_PRINT_PIXELS`)
MIN_PPI = 100.0
MAX_PPI = 2000.0

#: Band of ridge periods the print's quality blocks search, px of a 500-ppi print (the
#: defaults of :func:`~nail2nail.unroll.quality.block_quality`: 0.2–1.27 mm), scaled to the
#: print's pitch so that it is the same in mm at any ppi (4–25 px at 2000 ppi missed the
#: ridges, 38 px there)
QUALITY_PERIOD_PX_500 = (4.0, 25.0)

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

#: Amount and σ (mm) of the grey print's unsharp mask (``unroll.render.to_gray``): the ridges'
#: edges, which the cameras' and the projector's optics, subsurface scattering and the
#: pipeline's own smoothing blur, are given back (a 0.48 mm ridge period gains 1.8×, its
#: second harmonic 2.7×, before the RMS is brought back). Chosen on tuning conditions 0–7 and
#: 0–3 (probe.png) by SourceAFIS scores; reported on held-out conditions in the README
SHARPEN = 2.0
SHARPEN_SIGMA_MM = 0.075
#: the largest amount accepted: at 10 a 0.48 mm ridge period is multiplied by 4.8 and its
#: second harmonic by 9.5 before the RMS is brought back
MAX_SHARPEN = 10.0


@dataclass
class RolledPrint:
    """A rolled-equivalent print in the legacy convention (mirror of the pad view, tip up).

    Attributes
    ----------
    image : (H, W) uint8
        Ridges dark on white; 255 off `mask`; sharpened (:data:`SHARPEN`).
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
    outliers : dict
        The scans' far points left out of the print (:func:`unroll_scans`).
    plain : (H, W) uint8 or None
        `image` before its sharpening: the quality blocks and the ridge periods of
        :func:`~nail2nail.unroll.accuracy.geometric_accuracy` are measured on it.
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
    #: far points left out (``unroll_scans``): ``{"points", "per_camera", "center_mm",
    #: "radius_mm"}``; empty when not measured
    outliers: dict = field(default_factory=dict)
    #: the grey print before the sharpening (``unroll_scans(sharpen=)``), on which ridge
    #: periods and clarity are measured; None when not kept (then `image` serves)
    plain: np.ndarray | None = field(default=None, repr=False)

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
            "outliers": self.outliers or None,
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
                "sharpening": q.get("sharpening"),
                "fingertip": q.get("fingertip"),
                "fringes": q.get("fringes"),
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


def _cut_length(grid: PrintGrid, value, mask, share, length_mm: float,
                tip_row: float | None = None):
    """Drop the rows more than `length_mm` below the fingertip's row; crop.

    `tip_row` is the fingertip's print row (:func:`_tip_row`, above the scanned skin when the
    scanner did not see the tip); None: the print's top row with data.
    """
    if not length_mm > 0:
        raise ValueError(f"length_mm: expected a positive length, got {length_mm}")
    rows = np.flatnonzero(mask.any(axis=1))
    top = rows[0] if tip_row is None else tip_row
    last = int(np.clip(np.floor(top + length_mm / grid.pitch), 0, mask.shape[0] - 1))
    keep = min(mask.shape[0], last + 1 + int(np.ceil(1.0 / grid.pitch)))  # 1 mm margin
    mask = mask[:keep].copy()
    mask[last + 1:] = False
    value = np.where(mask, value[:keep], np.nan).astype(np.float32)
    share = share[:, :keep] * mask
    return PrintGrid(grid.s0, grid.t0, grid.pitch, mask.shape), value, mask, share


def _tip_row(flat, tip: dict, grid: PrintGrid, method: str) -> float | None:
    """The fingertip's print row (fractional), from :func:`~nail2nail.unroll.flatten.fingertip`:
    the last scanned point of the pad's profile, moved towards the tip by the estimated arc
    (the axial distance for the cylinder map, whose ``t`` runs along the axis). None when not
    estimated."""
    if not tip.get("estimated"):
        return None
    t_last = float(flat(np.asarray(tip["last_point"], np.float64)[None])[0, 1])
    t_tip = t_last + (tip["axial_mm"] if method == "cylinder" else tip["arc_mm"])
    return (grid.t0 - t_tip) / grid.pitch


def _tip_summary(tip: dict, tip_row: float | None, mask, pitch: float) -> dict:
    """JSON-ready :func:`~nail2nail.unroll.flatten.fingertip`: how far beyond the print's top
    row with data the fingertip was placed (mm), the cap fitted; or why it was not."""
    if tip_row is None:
        return {"estimated": False, "reason": tip.get("reason")}
    rows = np.flatnonzero(mask.any(axis=1))
    above = (rows[0] - tip_row) * pitch if rows.size else None
    return {"estimated": True,
            "above_print_mm": None if above is None else round(float(above), 3),
            "arc_beyond_scan_mm": round(float(tip["arc_mm"]), 3),
            "cap_semi_axes_mm": [round(float(x), 3) for x in tip["cap_semi_axes_mm"]],
            "last_angle_deg": round(float(tip["last_angle_deg"]), 1),
            "fit": tip.get("fit", "cap")}


def _direction(v, name: str) -> np.ndarray:
    """A direction given by the caller (three finite numbers, not all 0), made unit."""
    try:
        d = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected three numbers X, Y, Z, got {v!r}") from None
    if not (d.shape == (3,) and np.isfinite(d).all() and np.any(d != 0)):
        raise ValueError(f"{name}: expected three finite numbers X, Y, Z, not all 0, got "
                         f"{v!r}")
    d = d / np.max(np.abs(d))  # (1e308, 1e308, 0) has no finite length
    return d / np.linalg.norm(d)


def _leave_out_far_points(scans, valids) -> tuple[list[np.ndarray], dict]:
    """The scans' valid pixels without the far outliers of all of them together.

    A scanner's stray points (a reflection, a wrong phase order) can lie metres away; the
    flattening, the mesh and the print are sized from the points, so they are left out first:
    every camera's pixels outside the sphere of :func:`~nail2nail.unroll.flatten.bulk_sphere`
    of every camera's points (twice the 90th percentile of their distances from their median).
    """
    sample = np.concatenate([np.asarray(s.xyz).reshape(-1, 3)[np.flatnonzero(v)[::16]]
                             for s, v in zip(scans, valids, strict=True)])
    center, radius = bulk_sphere(sample)
    out, per_camera = [], {}
    for s, v in zip(scans, valids, strict=True):
        index = np.flatnonzero(v)
        far = index[~within_sphere(np.asarray(s.xyz).reshape(-1, 3)[index], center, radius)]
        per_camera[s.name] = int(far.size)
        if far.size:
            v = v.copy()
            v.reshape(-1)[far] = False
            if not v.any():
                raise ValueError(f"scans: {s.name!r} has no valid pixels near the others' "
                                 f"points (all beyond {radius:.4g} mm of their median)")
        out.append(v)
    info = {"points": sum(per_camera.values()), "per_camera": per_camera,
            "center_mm": np.round(center, 4).tolist(), "radius_mm": round(radius, 4)}
    return out, info


#: Finest print pixel, in sample spacings of the coarsest camera, whose data region a camera
#: alone fills: the pad's centre then holds 0.64 samples per pixel (0.3 is the threshold,
#: ``render.blend_cameras``), and the finger's sides, seen obliquely, fewer. Measured on the
#: centre camera of a scale-0.25 finger (0.13 mm): no data at 500 ppi, a print at 250 ppi.
MIN_PIXEL_SPACINGS = 0.8


def _no_data(scans, valids, ppi: float) -> str:
    """Why the blend left no pixel with data: the cameras' samples too sparse for the print's
    pixels (with the finest ppi that works), or no pixel with a blending weight."""
    spacing = {}
    for s, v in zip(scans, valids, strict=True):
        try:
            spacing[s.name] = pixel_spacing_mm(s.xyz, v)
        except ValueError:  # no two adjacent valid pixels
            continue
    pitch = max(MM_PER_INCH / ppi, MM_PER_INCH / SUPPORT_PPI)  # the data region's pixel
    if spacing:
        name = max(spacing, key=spacing.__getitem__)
        finest = MM_PER_INCH / (MIN_PIXEL_SPACINGS * spacing[name])
        if finest < MM_PER_INCH / pitch:
            return (f"scans: the print has no pixel with data at {ppi:g} ppi: the cameras sample "
                    f"the skin every {spacing[name]:.3g} mm ({name!r}), too sparsely for a data "
                    f"region of {pitch:.3g} mm pixels (0.3 samples each); at most "
                    f"{10 * int(finest // 10)} ppi, or scans of finer cameras, or more of them "
                    "overlapping")
    return ("scans: the print has no pixel with data: no camera pixel got a blending weight "
            "(every view beyond 75 degrees from the skin's normal, or no fringe modulation)")


def _print_quality(image, mask, pitch: float) -> dict:
    """:func:`~nail2nail.unroll.quality.block_quality` of the print in 3.2 mm blocks, on the
    print reduced to 500 ppi at most (by whole block means, as
    :func:`~nail2nail.unroll.mixing.clarity_map`), in the print's pixels."""
    f = max(1, int(CLARITY_PITCH_MM / pitch * (1 + 1e-9)))
    if f > 1:
        small, _, full = reduce_print(image, mask, f)
        image, mask, pitch = small, full, pitch * f
    per_500 = (MM_PER_INCH / 500.0) / pitch  # 500-ppi pixels to this print's
    q = block_quality(image, mask, block_px=round(3.2 / pitch),
                      min_period_px=QUALITY_PERIOD_PX_500[0] * per_500,
                      max_period_px=QUALITY_PERIOD_PX_500[1] * per_500)
    if f > 1:  # back to the print's pixels: block i covers pixels i·step … i·step + block − 1
        q.update(rows=q["rows"] * f + (f - 1) / 2, cols=q["cols"] * f + (f - 1) / 2,
                 period_px=q["period_px"] * f, block_px=q["block_px"] * f,
                 step_px=q["step_px"] * f)
    return q


def image_up_direction(scans, *, step: int = 4, valid=None) -> np.ndarray:
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
    valid : sequence of (H, W) bool, optional
        Per scan, its pixels to use (default: its mask and finite points).

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
    for i, s in enumerate(scans):
        xyz = np.asarray(s.xyz)[::step, ::step].astype(np.float64)
        ok = np.asarray(s.mask if valid is None else valid[i])[::step, ::step]
        ok = ok & np.all(np.isfinite(xyz), axis=-1)
        both = ok[:-1] & ok[1:]
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


def check_print_size(ppi, length_mm) -> None:
    """Refuse a print resolution outside :data:`MIN_PPI` … :data:`MAX_PPI` pixels per inch or
    a length outside :data:`MIN_LENGTH_MM` … :data:`MAX_LENGTH_MM` (``None``: all the skin),
    with ``ValueError`` naming the argument and the value as given."""
    if not (isinstance(ppi, (int, float)) and MIN_PPI <= ppi <= MAX_PPI):
        raise ValueError(f"ppi: expected a number in {MIN_PPI:g}..{MAX_PPI:g}, got {ppi!r}")
    if length_mm is not None and not (isinstance(length_mm, (int, float))
                                      and MIN_LENGTH_MM <= length_mm <= MAX_LENGTH_MM):
        raise ValueError(f"length_mm: expected {MIN_LENGTH_MM:g}..{MAX_LENGTH_MM:g} mm or None, "
                         f"got {length_mm!r}")


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
    estimate_tip: bool = True,
    mix: bool = True,
    polarity: str = "global",
    deshade: bool = False,
    min_clarity: float | None = MIN_CLARITY,
    sharpen: float = SHARPEN,
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
        Resolution of the print, pixels per inch, :data:`MIN_PPI` … :data:`MAX_PPI` (500 is the
        FBI's rolled-print standard).
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
        adult finger), :data:`MIN_LENGTH_MM` … :data:`MAX_LENGTH_MM`; None keeps everything
        the cameras saw. The fingertip is the apex of the pad's profile: where the scan stops
        short of it (cameras facing the pad see the tip's cap at a grazing angle), the unseen
        arc is estimated from an ellipse fitted to the scanned part of the cap
        (:func:`~nail2nail.unroll.flatten.fingertip`; ``quality["fingertip"]`` says how far
        above the print's first row it was placed).
    estimate_tip : bool
        False: count `length_mm` from the print's top row with data instead (the scanned
        skin nearest the tip, which depends on how much of the cap the rig saw; the behaviour
        before the estimate existed).
    mix : bool
        Blend relief and albedo apart and average them by their measured ridge clarity, the
        albedo's sign measured (:func:`~nail2nail.unroll.mixing.mix_layers`); normalise with
        an RMS floor (``FLOOR_FRACTION`` of the ridges' level) and take the smooth surface's
        curvature bias back. False: the fixed sum of earlier versions (relief + 0.3 × albedo,
        no floor), for comparison.
    polarity : {"global", "local"}
        How the albedo's sign is measured when mixing (``mix_layers``): "global" (default),
        one sign for the print from the albedo's correlation with the relief over it; "local",
        per 1.5 mm window (earlier versions; flips the albedo where the correlation crosses
        zero), for comparison.
    deshade : bool
        Take the ridges' own shading out of the albedo before mixing
        (:func:`~nail2nail.unroll.mixing.deshade_albedo`: the albedo brought into phase with
        the relief); with `mix` only. False (default): the albedo as blended; deshading brings
        the print's ridges closer to the skin's but did not raise SourceAFIS scores on
        held-out conditions (``docs/unroll.md``).
    min_clarity : float or None
        Leave out of the print (mask) the pixels whose ridge clarity is below this
        (:func:`~nail2nail.unroll.mixing.clarity_map`, 3.2 mm blocks) or whose signal is faint
        (local RMS of the normalised signal under ``MIN_AMPLITUDE``): skin without a ridge
        signal is not printed as noise or stripes (the faint test with `mix` only). None: keep
        every pixel with data.
    sharpen : float
        Amount of the unsharp mask that gives the grey print back the ridges' edges the
        capture chain blurred (:func:`~nail2nail.unroll.render.to_gray`, σ
        :data:`SHARPEN_SIGMA_MM`): :data:`SHARPEN` by default, 0 for none. The clarity mask is
        measured on the print before it.

    Returns
    -------
    RolledPrint
        Its ``outliers`` counts the far points left out: every camera's points farther from
        the median of all cameras' points than twice the 90th percentile of their distances
        from it (:func:`~nail2nail.unroll.flatten.bulk_sphere`), a scanner's stray points,
        which would otherwise size the mesh and the print.

    Raises
    ------
    ValueError
        No scans, a scan without valid pixels (near the others'), an unknown method, `ppi`
        outside :data:`MIN_PPI` … :data:`MAX_PPI`, `length_mm` outside :data:`MIN_LENGTH_MM`
        … :data:`MAX_LENGTH_MM`, a direction not three finite numbers (not all 0), points
        spanning more than a finger can (``flatten.MAX_EXTENT_MM``, ``render.
        MAX_PRINT_PIXELS``), or cameras too coarse for the print's pixels (the message gives
        the finest ppi that works).
    """
    scans = list(scans)
    if not scans:
        raise ValueError("scans: expected at least one Scan")
    for i, s in enumerate(scans):
        if not isinstance(s, Scan):
            raise TypeError(f"scans[{i}]: expected a Scan, got {type(s).__name__}")
    if method not in METHODS:
        raise ValueError(f"method: expected one of {', '.join(METHODS)}, got {method!r}")
    check_print_size(ppi, length_mm)
    if not (isinstance(sharpen, numbers.Real) and np.isfinite(sharpen)
            and 0 <= sharpen <= MAX_SHARPEN):
        raise ValueError(f"sharpen: expected a number from 0 to {MAX_SHARPEN:g}, got "
                         f"{sharpen!r}")
    if tip_direction is not None:
        tip_direction = _direction(tip_direction, "tip_direction")
    if pad_direction is not None:
        pad_direction = _direction(pad_direction, "pad_direction")
    lap = StepClock()
    timings = lap.seconds

    valids = []
    for s in scans:
        v = scan_valid(s)
        if not v.any():
            raise ValueError(f"scans: {s.name!r} has no valid pixels")
        valids.append(v)
    valid_near, outliers = _leave_out_far_points(scans, valids)
    picked, near = [], []
    for s, v, k in zip(scans, valids, valid_near, strict=True):
        # every fourth valid point (row-major), converted once they are picked; the far
        # outliers stay among them, for the flattening's fits draw their random subsets first
        # and leave the far points out after (flatten._check_points): the fits of a scan with a
        # few far outliers are those of the scan without them
        index = np.flatnonzero(v)[::4]
        picked.append(np.asarray(s.xyz).reshape(-1, 3)[index].astype(np.float64))
        near.append(k.reshape(-1)[index])
    points = np.concatenate(picked)
    # the feather ramps from the edge of each camera's region as scanned: a far outlier
    # left out leaves a pixel without weight, not a dip of feather_px around it
    feathers = [None if k is v else v for v, k in zip(valids, valid_near, strict=True)]
    valids = valid_near
    if tip_direction is None:
        tip_direction = image_up_direction(scans, valid=valids)
    pad_from_section = pad_direction is None
    if pad_direction is None:
        centers = [np.asarray(s.camera_center, float) for s in scans if s.camera_center is not None]
        if centers:
            centroid = points[np.concatenate(near)].mean(axis=0)
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
    infos: list[dict] = [{} for _ in scans]
    layers = [camera_layer(s, feather_px=feather_px, valid=v, feather_mask=f, separate=mix,
                           info=i, **options)
              for s, v, f, i in zip(scans, valids, feathers, infos, strict=True)]
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
    # the data region found at 500 ppi's pitch at most (render.SUPPORT_PPI); the outline
    # smoothed over about one ridge period (0.5 mm)
    blend = {"edge_sigma_px": 0.25 / grid.pitch, "support_pitch": MM_PER_INCH / SUPPORT_PPI}
    value, mask, share = blend_cameras(grid, samples, **blend)
    albedo = None
    if albedo_samples and len(albedo_samples) == len(samples):
        albedo, _, _ = blend_cameras(grid, albedo_samples, **blend)
    lap("blend")
    if not mask.any():
        raise ValueError(_no_data(scans, valids, ppi))
    tip = mesh.extra.get("fingertip", {"estimated": False, "reason": "not measured"}) \
        if estimate_tip else {"estimated": False, "reason": "estimate_tip=False"}
    tip_row = _tip_row(flat, tip, grid, method)
    if length_mm is not None:
        grid, value, mask, share = _cut_length(grid, value, mask, share, length_mm, tip_row)
        if albedo is not None:
            albedo = albedo[:mask.shape[0]]
    pitch = grid.pitch
    mixing = None
    if mix:
        value, mixing = mix_layers(value, albedo, mask, pitch, polarity=polarity,
                                   deshade=deshade)
    lap("mix")
    gray_options: dict[str, Any] = {"sigma_px": 1.0 / pitch, "reduce": max(1, int(0.25 / pitch))}
    if mix:
        gray_options["floor_fraction"] = GRAY_FLOOR_FRACTION
    z_print = normalized_print(value, mask, **gray_options)
    image = gray_levels(z_print, mask)
    # the print as delivered: sharpened; the clarity below is measured before, so that what
    # the mask keeps does not depend on the rendering's sharpening
    sharp = gray_levels(unsharp_mask(z_print, mask, amount=sharpen,
                                     sigma_px=SHARPEN_SIGMA_MM / pitch), mask) \
        if sharpen else image
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
            sharp = np.where(mask, sharp, 255).astype(np.uint8)
    plain = np.where(mask, image, 255).astype(np.uint8)
    image = sharp
    binary = binarize(image, mask, period_px=0.48 / pitch)
    lap("render")
    # measured on the print before the sharpening: the unsharp mask's gain rises across the
    # ring of the ridge frequency, which shortens the measured period by about 1 %
    quality = _print_quality(plain, mask, pitch)
    quality["mixing"] = None if mixing is None else {
        "albedo_share": round(mixing["albedo_share"], 4), "polarity": polarity,
        "albedo_polarity": mixing["albedo_polarity"], "shading": mixing["shading"]}
    quality["gate"] = gated
    quality["sharpening"] = {"amount": float(sharpen), "sigma_mm": SHARPEN_SIGMA_MM} \
        if sharpen else None
    quality["fingertip"] = _tip_summary(tip, tip_row, mask, grid.pitch)
    # the phase-locked error taken out of each camera's relief and albedo (fringes.py)
    quality["fringes"] = {s.name: i["fringes"] for s, i in zip(scans, infos, strict=True)
                          if "fringes" in i} or None
    distortion = map_distortion(flat, mesh)
    lap("quality")
    return RolledPrint(image=image, mask=mask, binary=binary, ridge=value, share=share,
                       grid=grid, method=method, flattening=flat,
                       cameras=[s.name for s in scans], distortion=distortion,
                       quality=quality, timings=timings, outliers=outliers, plain=plain)
