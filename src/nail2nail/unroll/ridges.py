"""The ridge signal of one camera's scan: relief along the normal plus albedo, normalised.

The friction ridges are relief of a few tens of µm on a smooth finger. On each camera's pixel
grid the smooth surface is a normalised Gaussian average of the valid points (σ about one
millimetre, computed on a reduced grid for speed); the relief is the point's offset from it
along the normal, ``h = (X − X̄)·n``, positive on ridge crests. The albedo's local contrast
(ridges reflect more than furrows on live skin and in the simulator) can be added with a weight.
Each part is normalised by its local RMS so that the blend of cameras has one scale.
"""

from __future__ import annotations

import numpy as np
import scipy.ndimage as ndi

from nail2nail._feather import feather
from nail2nail._quantile import weighted_quantiles
from nail2nail.scan.results import Scan
from nail2nail.unroll._kernels import (
    block_mean,
    deviation,
    layer_outputs,
    normalized,
    ratio,
    row_steps,
    surface_relief,
    upsample,
    valid_points,
)
from nail2nail.unroll.fringes import DEFAULT_HARMONICS, remove_phase_locked

__all__ = [
    "camera_layer",
    "finite_points",
    "local_normalize",
    "masked_gaussian",
    "pixel_spacing_mm",
    "ridge_signal",
    "scan_valid",
]


#: σ of the albedo's smooth part (shading) left out of the phase-locked fit, mm
FRINGE_ALBEDO_SMOOTH_MM = 0.35


def _norm3(a) -> np.ndarray:
    """``|a|`` over the last axis of ``(..., 3)`` (faster than ``linalg.norm`` on small axes)."""
    return np.sqrt(np.einsum("...k,...k->...", a, a))


def finite_points(xyz) -> np.ndarray:
    """Where a grid of points has all three coordinates finite.

    Parameters
    ----------
    xyz : (..., 3) float
        Points, mm; NaN marks a missing point.

    Returns
    -------
    (...) bool
        (A sum of the coordinates is tested: faster than ``isfinite(xyz).all(-1)``.)

    Examples
    --------
    >>> finite_points(np.array([[0.0, 1.0, 2.0], [0.0, np.nan, 2.0]])).tolist()
    [True, False]
    """
    return np.isfinite(xyz[..., 0] + xyz[..., 1] + xyz[..., 2])


def scan_valid(scan: Scan) -> np.ndarray:
    """Pixels of a scan with a 3D point: in its mask and finite.

    Unlike :func:`nail2nail.merge.valid_mask`, the projector coordinates are not required: the
    unroll needs only geometry, so a scan triangulated from one projector direction works.

    Returns
    -------
    (H, W) bool
    """
    xyz = np.asarray(scan.xyz)
    mask = np.asarray(scan.mask, dtype=bool)
    if xyz.dtype == np.float32 and xyz.ndim == 3 and mask.shape == xyz.shape[:2]:
        return valid_points(mask, xyz)  # compiled, the same float32 sum
    return mask & finite_points(xyz)


def pixel_spacing_mm(xyz, valid) -> float:
    """Median distance between horizontally adjacent valid points of a grid.

    Parameters
    ----------
    xyz : (H, W, 3) float
        Points, mm.
    valid : (H, W) bool

    Returns
    -------
    float
        mm (the skin's sampling by the camera: about 0.033 mm for the default rig).

    Raises
    ------
    ValueError
        If no two horizontally adjacent pixels are valid.
    """
    if np.asarray(xyz).dtype == np.float32:
        step = row_steps(xyz, valid)  # compiled, the same float32 arithmetic
    else:
        step = _norm3(np.diff(xyz, axis=1))[valid[:, 1:] & valid[:, :-1]]
    if not step.size:
        raise ValueError("scan: no two adjacent valid pixels")
    return float(np.median(step))


def _laplacian(a) -> np.ndarray:
    """Five-point Laplacian over the first two axes (grid units); 0 where a neighbour is NaN
    or off the grid (no correction there)."""
    out = np.zeros(a.shape, np.float32)
    out[1:-1, 1:-1] = (a[:-2, 1:-1] + a[2:, 1:-1] + a[1:-1, :-2] + a[1:-1, 2:]
                       - 4 * a[1:-1, 1:-1])
    return np.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0)


def masked_gaussian(values, valid, sigma_px: float, *, reduce: int = 1,
                    curvature: bool = False) -> np.ndarray:
    """Normalised Gaussian average of `values` over the `valid` pixels.

    ``G(v · m) / G(m)``: invalid pixels neither contribute nor pull the average to zero. With
    ``reduce > 1`` the average is computed on a grid block-averaged by `reduce` and brought
    back by bilinear interpolation (for wide σ this costs ``reduce²`` less, and the result is
    smooth anyway).

    Parameters
    ----------
    values : (H, W) or (H, W, k) float
    valid : (H, W) bool
    sigma_px : float
        σ in pixels of the full grid.
    reduce : int
        Block size of the reduced grid (1: full resolution).
    curvature : bool
        Take back the Gaussian's bias on a curved field, ``(σ²/2) ∇²``, to second order (on
        the reduced grid): a Gaussian mean of a curved surface lies inside it by about
        ``σ² / 2R`` (0.04 mm for σ 0.8 mm on a finger of radius 8 mm), and where the curvature
        changes (the tip's cap, the sides) that bias would print as bands.

    Returns
    -------
    (H, W) or (H, W, k) float32
        NaN where no valid pixel is near.
    """
    v = np.asarray(values, dtype=np.float32)
    valid = np.asarray(valid)
    squeeze = v.ndim == 2
    if squeeze:
        v = v[..., None]
    h, w = valid.shape
    f = max(1, int(reduce))
    if 1 < f <= 128 and valid.dtype == bool:
        # block means of the masked values and of the mask (compiled; NumPy's float32 sums)
        v, m = block_mean(v, valid, f)
    else:
        m = np.asarray(valid, dtype=np.float32)
        v = np.where(m[..., None] > 0, v, 0).astype(np.float32)
        if f > 1:
            hp, wp = -(-h // f) * f, -(-w // f) * f
            vp = np.zeros((hp, wp, v.shape[2]), np.float32)
            mp = np.zeros((hp, wp), np.float32)
            vp[:h, :w], mp[:h, :w] = v, m
            v = vp.reshape(hp // f, f, wp // f, f, -1).mean(axis=(1, 3))
            m = mp.reshape(hp // f, f, wp // f, f).mean(axis=(1, 3))
    s = sigma_px / f
    num = np.empty(v.shape, np.float32)
    for k in range(v.shape[2]):
        ndi.gaussian_filter(v[..., k], s, truncate=3.0, output=num[..., k])
    den = ndi.gaussian_filter(m, s, truncate=3.0)
    out = ratio(num, den)  # where(den > 1e-3, num / den, nan), compiled
    if curvature:
        out = out - np.float32(0.5 * s * s) * _laplacian(out)
    if f > 1:
        # block centres sit at (f − 1)/2 + f·i on the full grid
        rows = (np.arange(h, dtype=np.float32) - (f - 1) / 2) / f
        cols = (np.arange(w, dtype=np.float32) - (f - 1) / 2) / f
        rows = np.clip(rows, 0, out.shape[0] - 1)
        cols = np.clip(cols, 0, out.shape[1] - 1)
        r0 = np.minimum(rows.astype(np.intp), out.shape[0] - 2) if out.shape[0] > 1 \
            else np.zeros(h, np.intp)
        c0 = np.minimum(cols.astype(np.intp), out.shape[1] - 2) if out.shape[1] > 1 \
            else np.zeros(w, np.intp)
        fr = (rows - r0).astype(np.float32)
        fc = (cols - c0).astype(np.float32)
        r1 = np.minimum(r0 + 1, out.shape[0] - 1)
        c1 = np.minimum(c0 + 1, out.shape[1] - 1)
        # separable: rows first, then columns (compiled, no full-size temporaries)
        out = upsample(out, r0, r1, fr, c0, c1, fc)
    out = out.astype(np.float32, copy=False)
    return out[..., 0] if squeeze else out


def local_normalize(values, valid, sigma_px: float, *, reduce: int = 1,
                    floor_fraction: float = 0.0, floor_percentile: float = 90.0,
                    level_weights=None) -> np.ndarray:
    """``(v − mean) / rms`` over a Gaussian window of σ `sigma_px` (valid pixels only).

    Parameters
    ----------
    values : (H, W) float
    valid : (H, W) bool
    sigma_px : float
        σ of the window, px.
    reduce : int
        Block size of the reduced grid the averages are computed on
        (:func:`masked_gaussian`).
    floor_fraction : float
        The RMS is floored at this fraction of its `floor_percentile`-th percentile over the
        valid pixels (the level of the ridges where they are clear): a patch of skin without
        ridges (noise and scanner errors of a few µm) stays faint instead of being blown up to
        full contrast. 0 (default): only the rounding floor below.
    floor_percentile : float
    level_weights : (H, W) float, optional
        Weights of the pixels in that percentile (the blending weight's viewing factor, so that
        grazing pixels and the scan's edge do not set the ridges' level).

    Returns
    -------
    (H, W) float32
        0 mean and unit RMS locally; NaN off `valid`. The RMS is floored at 10⁻⁴ × the mean
        magnitude of `values`, so a constant field gives 0, not amplified rounding noise.
    """
    v = np.where(valid, values, np.nan).astype(np.float32)
    valid = np.asarray(valid, dtype=bool)
    mean = masked_gaussian(v, valid, sigma_px, reduce=reduce)
    d, dd, ok = deviation(v, mean, valid)  # d = v − mean, d², valid & isfinite(d)
    mean_square = masked_gaussian(dd, ok, sigma_px, reduce=reduce)
    # a floor relative to the values' magnitude: a constant field stays 0 instead of its
    # rounding noise being blown up to unit RMS
    floor = 1e-4 * float(np.nanmean(np.abs(v))) + 1e-12 if valid.any() else 1e-12
    use = ok & np.isfinite(mean_square)
    if floor_fraction > 0 and use.any():
        w = np.ones(int(use.sum())) if level_weights is None \
            else np.nan_to_num(np.asarray(level_weights, np.float64)[use])
        level = np.sqrt(weighted_quantiles(mean_square[use], w, [floor_percentile / 100])[0])
        floor = max(floor, floor_fraction * float(level))
    # where(valid, d / maximum(sqrt(mean_square), floor), nan), float32
    return normalized(d, mean_square, valid, floor)


def _normals(xyz) -> np.ndarray:
    """Unit normals ``∂X/∂row × ∂X/∂col`` of a smooth grid surface (float32, NaN-safe)."""
    d_r = np.gradient(xyz, axis=0)
    d_c = np.gradient(xyz, axis=1)
    n = np.cross(d_r, d_c)
    with np.errstate(invalid="ignore", divide="ignore"):
        n /= _norm3(n)[..., None]
    return n


def _surface_relief(smooth, xyz, camera_center):
    """NumPy :func:`~nail2nail.unroll._kernels.surface_relief` (also for grids under 2 px)."""
    normals = _normals(smooth)
    if camera_center is not None:
        view = np.asarray(camera_center, np.float32) - smooth
        view /= _norm3(view)[..., None]
        cos = np.einsum("...k,...k->...", normals, view)
        # orient the normals towards the camera
        normals *= np.where(cos < 0, -1, 1).astype(np.float32)[..., None]
        cos = np.abs(cos)
    else:
        cos = np.ones(smooth.shape[:2], np.float32)
    relief = np.einsum("...k,...k->...", np.nan_to_num(xyz - smooth), np.nan_to_num(normals))
    return cos, relief, finite_points(smooth) & finite_points(normals)


def _without_fringes(relief, albedo, m, cos, spacing, scan, box, periods, harmonics):
    """Relief and albedo less their phase-locked error (:mod:`nail2nail.unroll.fringes`).

    The albedo is fitted less its smooth part (shading, σ :data:`FRINGE_ALBEDO_SMOOTH_MM`),
    and that part added back; the fit leaves out grazing views (cos < 0.5), where the relief
    is smeared."""
    coords = {"x": np.asarray(scan.xp[box], np.float32), "y": np.asarray(scan.yp[box], np.float32)}
    parts = [relief]
    smooth = None
    if albedo is not None:
        smooth = masked_gaussian(albedo, m, FRINGE_ALBEDO_SMOOTH_MM / spacing,
                                 reduce=max(1, int(FRINGE_ALBEDO_SMOOTH_MM / spacing // 4)))
        parts.append(albedo - smooth)
    ok = m & np.all(np.isfinite(np.stack(parts, -1)), axis=-1)
    cleaned, fit = remove_phase_locked(np.stack(parts, -1), ok, coords, periods,
                                       harmonics=harmonics, fit_mask=cos > 0.5)
    removed = {"terms": fit["terms"], "samples": fit["samples"],
               "relief_um": round(1e3 * fit["removed_rms"][0], 3),
               "gains": fit.get("gains", {})}
    relief = np.where(ok, cleaned[..., 0], relief)
    if albedo is not None:
        albedo = np.where(ok, cleaned[..., 1] + smooth, albedo)
        removed["albedo"] = round(fit["removed_rms"][1], 5)
    return relief, albedo, removed


def camera_layer(
    scan: Scan,
    *,
    surface_sigma_mm: float = 0.8,
    noise_sigma_mm: float = 0.03,
    contrast_sigma_mm: float = 1.0,
    albedo_weight: float = 0.3,
    feather_px: float = 40.0,
    max_view_angle_deg: float = 75.0,
    valid: np.ndarray | None = None,
    feather_mask: np.ndarray | None = None,
    floor_fraction: float = 0.0,
    curvature: bool = False,
    highpass_mm: float = 0.0,
    separate: bool = False,
    fringe_harmonics: int = DEFAULT_HARMONICS,
    fringe_periods: dict | None = None,
    info: dict | None = None,
) -> tuple[np.ndarray, np.ndarray] | tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Ridge signal and blending weight of one camera's scan on its pixel grid.

    The ridge signal is the relief ``h = (X − X̄)·n`` from the smooth surface ``X̄`` (σ
    `surface_sigma_mm`), lightly smoothed against depth noise, normalised by its local RMS,
    plus `albedo_weight` × the albedo's normalised local contrast, divided by
    ``√(1 + albedo_weight²)``. The
    blending weight is fringe modulation × cos² (viewing angle of the smooth surface) × a
    feather rising over `feather_px` camera pixels from the edge of the valid region, so that
    cameras cross-fade over about a millimetre.

    Parameters
    ----------
    scan : Scan
    surface_sigma_mm : float
        σ of the smooth surface the relief is measured from, mm (above the ridge period of
        about 0.5 mm, below the finger's curvature radius).
    noise_sigma_mm : float
        σ of a light smoothing of the relief against depth noise, mm (0 for none).
    contrast_sigma_mm : float
        σ of the local normalisation window, mm.
    albedo_weight : float
        Weight of the normalised albedo contrast added to the normalised relief (0: relief
        only).
    feather_px : float
        Width of the weight's ramp at the edge of the valid region, camera px (0: none): the
        merge's feather (:func:`nail2nail._feather.feather`), positive on every valid pixel.
        It orders the cameras where they overlap; where one camera alone sees the skin (the
        fingertip's cap and the finger's sides at grazing view) its data stay in the print.
    max_view_angle_deg : float
        Pixels that see the smooth surface at a larger angle from its normal get no weight (at
        grazing view a camera pixel spreads over several ridges and the relief is smeared;
        merging rejects pairs beyond 70° for the same reason). Needs ``camera_center``.
    valid : (H, W) bool, optional
        ``scan_valid(scan)`` when the caller has it already (not checked).
    feather_mask : (H, W) bool, optional
        The region whose edge the feather ramps from (default: the valid pixels); pixels left
        out of `valid` inside it (far outliers) then get no weight without a dip of
        `feather_px` around each.
    floor_fraction : float
        RMS floor of the local normalisations, as a fraction of the ridges' level
        (:func:`local_normalize`; 0: none): skin without ridges stays faint.
    curvature : bool
        Take the smooth surface's curvature bias back (:func:`masked_gaussian`).
    highpass_mm : float
        Subtract the signals' normalised Gaussian of this σ, mm (0: none): a band-pass to the
        ridges' periods that keeps ridges (0.993 of a 0.7 mm period at σ 0.35 mm) and removes
        most of longer ones, the scanner's periodic errors of a few mm and the shading's bands
        (0.27 of a 2.8 mm period).
    separate : bool
        Return the relief and albedo signals apart (``relief, albedo, weight``; ``albedo``
        None when `albedo_weight` is 0), for a blend that weighs them by their measured
        clarity (:func:`nail2nail.unroll.mixing.mix_layers`).
    fringe_harmonics : int
        Harmonics of the fringe period whose phase-locked error is taken out of the relief
        and the albedo before anything else (:func:`~nail2nail.unroll.fringes.
        remove_phase_locked`); 0: none.
    fringe_periods : dict, optional
        The finest fringe period per direction, panel px; default the scan's own
        (:attr:`Scan.fringe_periods`, recorded by the scan stage). Without either, nothing
        is taken out.
    info : dict, optional
        Filled with what was taken out (``info["fringes"]``: the fit's terms and the RMS
        removed from the relief, µm, and the albedo).

    Returns
    -------
    signal : (H, W) float32
        Locally normalised ridge signal (unit local RMS), positive on ridge crests; NaN off the
        valid pixels.
    weight : (H, W) float32
        Non-negative blending weight; 0 off the valid pixels. Without ``camera_center`` the
        cosine factor is 1.

    Raises
    ------
    ValueError
        If the scan has no valid pixels.
    """
    valid = scan_valid(scan) if valid is None else valid
    if not valid.any():
        raise ValueError(f"scan {scan.name!r}: no valid pixels")
    rows = np.flatnonzero(valid.any(axis=1))
    cols = np.flatnonzero(valid.any(axis=0))
    box = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
    xyz = np.asarray(scan.xyz[box], dtype=np.float32)
    m = valid[box]
    spacing = pixel_spacing_mm(xyz, m)
    sigma = surface_sigma_mm / spacing
    reduce = max(1, int(sigma // 3))
    smooth = masked_gaussian(xyz, m, sigma, reduce=reduce, curvature=curvature)
    if min(m.shape) >= 2:
        # normals (oriented towards the camera), viewing cosine and relief in one pass
        cos, relief, finite = surface_relief(smooth, xyz, scan.camera_center)
    else:
        cos, relief, finite = _surface_relief(smooth, xyz, scan.camera_center)
    m = m & finite
    albedo = None
    if albedo_weight > 0:
        albedo = np.asarray(scan.albedo[box], dtype=np.float32)
    periods = scan.fringe_periods if fringe_periods is None else fringe_periods
    if fringe_harmonics and periods:
        relief, albedo, removed = _without_fringes(
            relief, albedo, m, cos, spacing, scan, box, periods, fringe_harmonics)
        if info is not None:
            info["fringes"] = removed
    if noise_sigma_mm > 0:
        if albedo is None:
            relief = masked_gaussian(relief, m, noise_sigma_mm / spacing)
        else:
            # one pass for both (the normalising weight G(m) computed once)
            both = masked_gaussian(np.stack([relief, albedo], -1), m, noise_sigma_mm / spacing)
            relief, albedo = both[..., 0], both[..., 1]
    if highpass_mm > 0:
        hsig = highpass_mm / spacing
        hreduce = max(1, int(hsig // 4))
        if albedo is None:
            relief = relief - masked_gaussian(relief, m, hsig, reduce=hreduce)
        else:
            both = np.stack([relief, albedo], -1)
            both = both - masked_gaussian(both, m, hsig, reduce=hreduce)
            relief, albedo = both[..., 0], both[..., 1]
    csig = contrast_sigma_mm / spacing
    creduce = max(1, int(csig // 4))
    # the ridges' level: pixels weighed by cos² of their viewing angle (not the grazing edge)
    floor = {"floor_fraction": floor_fraction, "level_weights": np.nan_to_num(cos) ** 2}
    signal = local_normalize(relief, m, csig, reduce=creduce, **floor)
    fm = m if feather_mask is None else np.asarray(feather_mask, bool)[box]
    # float32 as the compiled layer kernel takes it
    ramp = feather(fm, feather_px).astype(np.float32)
    if separate:
        weight_args = (np.asarray(scan.modulation[box], np.float32), cos,
                       ramp, m)
        cos_min = np.cos(np.radians(max_view_angle_deg))
        relief_out, weight = layer_outputs(*weight_args, signal, cos_min, box, valid.shape)
        albedo_out = None
        if albedo is not None:
            albedo_out, _ = layer_outputs(
                *weight_args, local_normalize(albedo, m, csig, reduce=creduce, **floor),
                cos_min, box, valid.shape)
        return relief_out, albedo_out, weight
    if albedo is not None:
        # both parts have unit local RMS: the sum is brought back to about unit RMS (the grey
        # print is normalised again on the print grid)
        signal = (signal + albedo_weight * local_normalize(albedo, m, csig, reduce=creduce)) \
            / np.float32(np.sqrt(1 + albedo_weight**2))
    # weight = clip(modulation, 0) · cos² · feather, 0 beyond the largest viewing angle; both
    # outputs on the full grid (compiled, one pass over the box)
    return layer_outputs(np.asarray(scan.modulation[box], np.float32), cos,
                         ramp, m, signal,
                         np.cos(np.radians(max_view_angle_deg)), box, valid.shape)


def ridge_signal(scan: Scan, **options) -> np.ndarray:
    """The ridge signal of :func:`camera_layer` alone: ``(H, W) float32``, NaN off the scan."""
    return camera_layer(scan, **options)[0]
