"""The skin's ridges apart from the scanner's errors: relief and albedo weighed by their clarity.

A touchless scan measures the ridges twice: as relief (the 3D points' offset from the smooth
finger) and as albedo (ridges and furrows reflect differently). Which one is cleaner depends on
the scanner and on the region: the relief carries the scanner's periodic phase errors and
suffers at grazing view; the albedo's ridge contrast is 5–20 % on live skin (subsurface
scattering lowers it), has either sign, and carries shading and highlights. So neither gets a
fixed weight. On the print grid, each signal's *ridge clarity* (the fraction of its local
spectral energy in the ring of the ridge frequency, :func:`~nail2nail.unroll.quality.
block_quality`) is measured per region, the albedo's sign is taken from its correlation with
the relief over the whole print (one polarity: how ridges reflect is the capture's, while the
local correlation crosses zero wherever the two signals' ridge phases drift apart), and the
two are averaged with weights ``q / (1 − q)``, the ridge-to-rest energy ratio each clarity
implies (an estimate's weight in an average is its signal-to-noise ratio).

On request (``mix_layers(deshade=True)``, off by default: the print's ridges come closer to the
skin's, SourceAFIS scores do not rise, ``docs/unroll.md``) the albedo is first *deshaded*
(:func:`deshade_albedo`): what a camera records as albedo is reflectance × shading, and the
ridges' own slopes shade them, ``∂h/∂l`` along the light's direction in the skin's tangent
plane. That term is in quadrature with the ridges (a quarter period off), as large as the
reflectance contrast or larger for high ridges (a 70 µm relief of 0.47 mm period slopes by up
to 0.49), and its weight turns with the light's direction around the finger: added to the
relief as it is, the albedo partly cancels it. For locally
sinusoidal ridges the shading is a phase rotation, undone by adding ``K(x) · (L(x) · R a)``
(``R``: the Riesz transform) with the light field ``K L`` smooth over the print and fitted to
the relief by least squares.

Then what carries no ridge signal is left out of the print: :func:`clarity_map` of the final
print, and pixels below ``min_clarity`` are masked (white, as off the finger), so a patch of
skin without ridges is never printed as noise or as the scanner's stripes.
"""

from __future__ import annotations

import numpy as np
import scipy.ndimage as ndi

from nail2nail.unroll._kernels import block_mean
from nail2nail.unroll.quality import block_quality
from nail2nail.unroll.ridges import masked_gaussian

__all__ = ["CLARITY_PITCH_MM", "DESHADE_DEGREE", "MAX_SHADING_GAIN", "clarity_map",
           "deshade_albedo", "gate_mask", "mix_layers", "reduce_print", "riesz_transform",
           "upsample_blocks"]

#: block size and step of the clarity maps, mm (3.2 mm: about six ridges per block, the
#: print's quality blocks)
CLARITY_BLOCK_MM = 3.2
CLARITY_STEP_MM = 0.8
#: σ of the high-pass applied before measuring clarity, mm: shading and bands of a few mm
#: would otherwise fill the ring of a block whose peak is a long period
HIGHPASS_MM = 0.35
#: ridge periods searched, mm (adult friction ridges: 0.3–0.7 mm, wider on the sides)
PERIOD_RANGE_MM = (0.3, 1.0)
#: finest pitch clarity is measured at, mm (500 ppi): a finer print is reduced by block means
#: first (by the largest whole factor that keeps the pitch at most this), so that the measure
#: (its share of the block's energy, which a finer grid spreads over more noise frequencies)
#: and its cost do not grow with the ppi; the ridges (periods ≥ 0.3 mm) are far below 500
#: ppi's Nyquist period (0.1 mm)
CLARITY_PITCH_MM = 25.4 / 500

#: Degree of the polynomial (in the print's coordinates) of the shading's light field
#: (:func:`deshade_albedo`): 1, the tangential light of one projector on a finger turns
#: smoothly, roughly linearly across it (degrees 2 and 3 fitted no better on tuning fingers)
DESHADE_DEGREE = 1
#: The largest RMS of the shading correction, as a multiple of the albedo's own RMS: a
#: rotation by up to 72° (tan 72° ≈ 3); beyond, the albedo carries hardly any reflectance
#: contrast and the correction would only amplify its noise
MAX_SHADING_GAIN = 3.0
#: σ of the window over which the deshaded albedo is given the albedo's local RMS back, mm
RMS_SIGMA_MM = 1.0


def clarity_map(value, mask, pitch: float, *, block_mm: float = CLARITY_BLOCK_MM,
                step_mm: float = CLARITY_STEP_MM) -> np.ndarray:
    """Ridge clarity per pixel: blocks of `block_mm` every `step_mm`, interpolated.

    The signal is high-passed first (less its normalised Gaussian of σ :data:`HIGHPASS_MM`)
    and the ridge frequency searched between the periods :data:`PERIOD_RANGE_MM`, so that
    shading and smooth bands count as what they are, not ridges: noise scores about 0.2–0.3,
    clean ridges above 0.8.

    Parameters
    ----------
    value : (H, W) float or uint8
        A ridge signal or a print on the print grid (NaN or anything off `mask`).
    mask : (H, W) bool
    pitch : float
        Print pixel, mm.
    block_mm, step_mm : float

    Returns
    -------
    (H, W) float32
        Clarity in [0, 1] (:func:`~nail2nail.unroll.quality.block_quality`) bilinearly
        interpolated between block centres; pixels of `mask` nearer the edge than half a
        block take the nearest measured block's value; NaN off `mask`, and everywhere when no
        block fits. A print finer than :data:`CLARITY_PITCH_MM` is measured reduced to it.
    """
    mask = np.asarray(mask, dtype=bool)
    f = int(CLARITY_PITCH_MM / pitch * (1 + 1e-9))  # whole reduction factor
    if f >= 2:
        return _reduced_clarity(value, mask, pitch, f, block_mm=block_mm, step_mm=step_mm)
    v = np.where(mask, np.nan_to_num(np.asarray(value, dtype=np.float32)), 0.0)
    v = np.where(mask, v - np.nan_to_num(masked_gaussian(v, mask, HIGHPASS_MM / pitch)), 0.0)
    n = max(8, round(block_mm / pitch))
    step = max(1, round(step_mm / pitch))
    # blocks reaching at most a quarter block past the mask: the edge is measured as well
    inner = ndi.binary_dilation(mask, iterations=max(1, n // 4))
    q = block_quality(v, inner, block_px=n, step_px=step,
                      min_period_px=PERIOD_RANGE_MM[0] / pitch,
                      max_period_px=PERIOD_RANGE_MM[1] / pitch)
    grid = q["grid"]
    out = np.full(mask.shape, np.nan, np.float32)
    if not np.isfinite(grid).any():
        return out
    missing = ~np.isfinite(grid)
    if missing.any():
        _, (ir, ic) = ndi.distance_transform_edt(missing, return_indices=True)
        grid = grid[ir, ic]
    rows = (np.arange(mask.shape[0]) - (n - 1) / 2) / step
    cols = (np.arange(mask.shape[1]) - (n - 1) / 2) / step
    rr, cc = np.meshgrid(np.clip(rows, 0, grid.shape[0] - 1), np.clip(cols, 0, grid.shape[1] - 1),
                         indexing="ij")
    out[mask] = ndi.map_coordinates(grid.astype(np.float64), [rr[mask], cc[mask]], order=1)
    return out


def reduce_print(value, mask, f: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Means of `value` over the `mask` pixels of ``f × f`` blocks.

    Returns
    -------
    value : (⌈H/f⌉, ⌈W/f⌉) float32
        Mean over each block's pixels in `mask` (0 where none).
    half : (⌈H/f⌉, ⌈W/f⌉) bool
        Blocks with at least half their pixels in `mask`.
    full : (⌈H/f⌉, ⌈W/f⌉) bool
        Blocks wholly in `mask` (and inside the image).
    """
    mask = np.asarray(mask, dtype=bool)
    v = np.where(mask, np.nan_to_num(np.asarray(value, dtype=np.float32)), np.float32(0))
    total, share = block_mean(v[..., None], mask, f)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(share > 0, total[..., 0] / share, 0).astype(np.float32)
    return mean, share >= 0.5, share >= 1 - 0.5 / (f * f)


def upsample_blocks(small, f: int, shape) -> np.ndarray:
    """``(H, W) float32``: bilinear interpolation of a map of ``f × f`` blocks (NaN filled from
    the nearest finite block) at the pixels of the full grid of `shape`; NaN when none is
    finite."""
    small = np.asarray(small, dtype=np.float64)
    finite = np.isfinite(small)
    if not finite.any():
        return np.full(shape, np.nan, np.float32)
    if not finite.all():
        _, (ir, ic) = ndi.distance_transform_edt(~finite, return_indices=True)
        small = small[ir, ic]
    # the centre of block i is full pixel i·f + (f − 1)/2
    rows = np.clip((np.arange(shape[0]) - (f - 1) / 2) / f, 0, small.shape[0] - 1)
    cols = np.clip((np.arange(shape[1]) - (f - 1) / 2) / f, 0, small.shape[1] - 1)
    r0 = np.floor(rows).astype(int)
    c0 = np.floor(cols).astype(int)
    r1 = np.minimum(r0 + 1, small.shape[0] - 1)
    c1 = np.minimum(c0 + 1, small.shape[1] - 1)
    fr = (rows - r0)[:, None]
    fc = (cols - c0)[None, :]
    top = small[r0][:, c0] * (1 - fc) + small[r0][:, c1] * fc
    bottom = small[r1][:, c0] * (1 - fc) + small[r1][:, c1] * fc
    return (top * (1 - fr) + bottom * fr).astype(np.float32)


def _reduced_clarity(value, mask, pitch: float, f: int, **blocks) -> np.ndarray:
    """:func:`clarity_map` of the print reduced by ``f × f`` block means, at every pixel."""
    small, half, _ = reduce_print(value, mask, f)
    out = upsample_blocks(clarity_map(small, half, pitch * f, **blocks), f, mask.shape)
    out[~mask] = np.nan
    return out


def riesz_transform(value, mask) -> tuple[np.ndarray, np.ndarray]:
    """The Riesz transform of a zero-mean signal over a mask, by FFT.

    ``R_j f = F⁻¹(−i ω_j / |ω| · F f)`` along rows (``j = 0``) and columns (``j = 1``)
    (Felsberg and Sommer, *The monogenic signal*, IEEE Trans. Signal Processing 49(12), 2001).
    For a locally sinusoidal pattern ``cos(ω·x + φ)`` it is ``(ω/|ω|) sin(ω·x + φ)``: the
    quadrature of the ridges along their normal, whatever their orientation. No thesis
    equation covers it (the thesis does not unroll); frequencies are in cycles per pixel, so
    the result is unitless and the same at any print pitch.

    Parameters
    ----------
    value : (H, W) float
        High-passed signal (0 mean); taken as 0 off `mask`.
    mask : (H, W) bool

    Returns
    -------
    rows, cols : (H, W) float32
        The two components along rows and columns (0 off `mask`). The grid is zero-padded by
        16 px (to an FFT-friendly size), which keeps the opposite edges apart but does not
        remove every edge effect: the transform's kernel decays as ``1/r²``, so within a few
        ridge periods of the mask's edge the components are only approximately the
        quadrature (the tests measure them 2 mm inside).
    """
    from scipy import fft

    mask = np.asarray(mask, dtype=bool)
    v = np.where(mask, np.nan_to_num(np.asarray(value, dtype=np.float64)), 0.0)
    h, w = v.shape
    hp, wp = fft.next_fast_len(h + 16, real=True), fft.next_fast_len(w + 16, real=True)
    spectrum = fft.rfft2(v, s=(hp, wp), workers=-1)
    fr = fft.fftfreq(hp)[:, None]
    fc = fft.rfftfreq(wp)[None, :]
    norm = np.hypot(fr, fc)
    norm[0, 0] = 1.0
    out = []
    for f in (fr, fc):
        comp = fft.irfft2(spectrum * (-1j * f / norm), s=(hp, wp), workers=-1)[:h, :w]
        out.append(np.where(mask, comp, 0.0).astype(np.float32))
    return out[0], out[1]


def deshade_albedo(relief, albedo, mask, pitch: float, *, weights=None,
                   degree: int = DESHADE_DEGREE, max_gain: float = MAX_SHADING_GAIN):
    """The albedo signal less the ridges' own shading, brought into phase with the relief.

    A camera's albedo of ridged skin is ``a = c h + k ∂h/∂l``: reflectance contrast ``c``
    and the shading of the ridges' slopes along ``l``, the light's direction in the skin's
    tangent plane (Lambertian ``n · l``), which turns around the finger. For locally
    sinusoidal ridges ``h = cos φ`` this is ``ρ cos(φ + θ)`` with ``tan θ = (k/c) (l · ω)``,
    and, with the Riesz transform ``R a = ω̂ ρ sin(φ + θ)`` (:func:`riesz_transform`),

        ``a + K (L · R a) = ρ cos φ / cos θ``   for ``K L = (k |ω| / c) l``,

    so the ridges' phase comes back by adding the Riesz components weighed by a smooth vector
    field: no orientation estimate, no sign ambiguity. The field ``K L(x)`` is a polynomial
    of `degree` in the print's coordinates, fitted by weighted least squares of the relief
    on ``[a, p_k(x) R_row a, p_k(x) R_col a]`` (the relief's noise is not correlated with the
    albedo, so it does not bias the fit; its ridge phase is what the albedo is brought to).
    The result is given the albedo's local RMS back (σ :data:`RMS_SIGMA_MM`). The model is
    Lambertian shading (``n · l``) of a sinusoidal relief; no thesis equation covers it.

    Parameters
    ----------
    relief, albedo : (H, W) float
        High-passed, locally normalised ridge signals on the print grid (NaN off `mask`).
    mask : (H, W) bool
    pitch : float
        Print pixel, mm.
    weights : (H, W) float, optional
        Weight of each pixel in the fit (the relief's signal-to-noise ratio), default 1.
    degree : int
        Degree of the light field's polynomial (0: one constant direction).
    max_gain : float
        The correction's RMS is capped at this multiple of the albedo's RMS.

    Returns
    -------
    deshaded : (H, W) float32
        The albedo signal brought into phase with the relief, positive on the relief's crests
        (the albedo's polarity taken out); NaN off `mask`.
    info : dict
        ``polarity`` (+1 / −1: the sign of the albedo's reflectance term against the relief),
        ``correction_rms`` (the correction's RMS over the albedo's, after the cap),
        ``relief_correlation`` (the weighted correlation of the relief with the albedo before
        and with the deshaded albedo after), ``degree``.
    """
    mask = np.asarray(mask, dtype=bool)
    a = np.where(mask, np.nan_to_num(np.asarray(albedo, dtype=np.float32)), 0.0)
    r = np.where(mask, np.nan_to_num(np.asarray(relief, dtype=np.float32)), 0.0)
    rows, cols = np.nonzero(mask)
    if rows.size < 16:
        return np.where(mask, a, np.nan).astype(np.float32), {
            "polarity": 1, "correction_rms": 0.0, "relief_correlation": None,
            "degree": degree}
    w = np.ones(rows.size) if weights is None \
        else np.nan_to_num(np.asarray(weights, dtype=np.float64)[mask])
    riesz = riesz_transform(a, mask)
    # polynomial terms in coordinates centred on the mask and scaled to about ±1
    y = (rows - rows.mean()) / max(float(np.ptp(rows)) / 2, 1.0)
    x = (cols - cols.mean()) / max(float(np.ptp(cols)) / 2, 1.0)
    terms = [y**i * x**j for i in range(degree + 1) for j in range(degree + 1 - i)]
    design = np.column_stack([a[mask]] + [t * c[mask] for c in riesz for t in terms])
    sw = np.sqrt(w)
    coef, *_ = np.linalg.lstsq(design * sw[:, None], r[mask] * sw, rcond=None)
    a_m = design[:, 0]

    def corr(u):
        return float(np.sum(w * u * r[mask]) / np.sqrt(max(
            float(np.sum(w * u * u)) * float(np.sum(w * r[mask] ** 2)), 1e-30)))

    if not abs(coef[0]) > 0:
        return np.where(mask, a, np.nan).astype(np.float32), {
            "polarity": 1, "correction_rms": 0.0,
            "relief_correlation": [round(corr(a_m), 4)] * 2, "degree": degree}
    polarity = 1 if coef[0] > 0 else -1
    correction = design[:, 1:] @ (coef[1:] / coef[0])
    gain = float(np.sqrt(np.mean(correction**2) / max(float(np.mean(a_m**2)), 1e-30)))
    if gain > max_gain:
        correction *= max_gain / gain
        gain = max_gain
    out = np.zeros(mask.shape, np.float32)
    out[mask] = polarity * (a_m + correction)
    # the albedo's local RMS back (σ 1 mm): its floors (faint skin stays faint) are kept
    sigma = RMS_SIGMA_MM / pitch
    reduce = max(1, int(sigma // 4))
    level = masked_gaussian(np.stack([a * a, out * out], -1), mask, sigma, reduce=reduce)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.sqrt(level[..., 0] / np.maximum(level[..., 1], 1e-12))
    out = np.where(mask, out * np.nan_to_num(scale), np.nan).astype(np.float32)
    info = {"polarity": polarity, "correction_rms": round(gain, 4),
            "relief_correlation": [round(polarity * corr(a_m), 4), round(corr(out[mask]), 4)],
            "degree": degree}
    return out, info


def mix_layers(relief, albedo, mask, pitch: float, *, correlation_mm: float = 1.5,
               polarity: str = "global", deshade: bool = False):
    """Relief and albedo signals of the print grid averaged by their measured clarity.

    Parameters
    ----------
    relief, albedo : (H, W) float
        Blended, locally normalised ridge signals (positive on crests for the relief; the
        albedo's sign is measured); NaN off `mask`. `albedo` may be None (relief alone).
    mask : (H, W) bool
    pitch : float
        Print pixel, mm.
    correlation_mm : float
        σ of the window of the albedo's local correlation ``ρ`` with the relief, mm.
    polarity : {"global", "local"}
        "global" (default): the albedo's sign ``s`` is that of its correlation with the
        relief over the whole mask. "local": ``s = sign(ρ)`` per pixel (earlier versions;
        flips the albedo wherever ``ρ`` crosses zero).
    deshade : bool
        Take the ridges' own shading out of the albedo first (:func:`deshade_albedo`, fitted
        with the relief's clarity weights); the albedo's clarity is then measured on the
        deshaded signal. False (default): the albedo as blended (the ridges come closer to
        the skin's with it, but SourceAFIS scores did not rise on held-out conditions:
        ``docs/unroll.md``).

    Returns
    -------
    mixed : (H, W) float32
        ``(w_r R + s w_a A) / (w_r + w_a)``, ``w = q / (1 − q)`` of each signal's clarity
        ``q`` (clipped to [0.05, 0.98]); NaN off `mask`.
    info : dict
        ``relief_clarity``, ``albedo_clarity``, ``correlation`` (H, W) maps (of the
        deshaded albedo, already of the relief's sign, with `deshade`),
        ``albedo_share``, the albedo's mean weight fraction over the mask,
        ``albedo_polarity`` (+1 or −1; with "local", the sign of the mean of ``sign(ρ)``),
        and ``shading`` (:func:`deshade_albedo`'s info, None without `deshade`).
    """
    if polarity not in ("global", "local"):
        raise ValueError(f"polarity must be 'global' or 'local', not {polarity!r}")
    mask = np.asarray(mask, dtype=bool)
    r = np.where(mask, np.nan_to_num(relief), 0.0).astype(np.float32)
    q_r = clarity_map(r, mask, pitch)
    if albedo is None:
        return np.where(mask, r, np.nan).astype(np.float32), {
            "relief_clarity": q_r, "albedo_clarity": None, "correlation": None,
            "albedo_share": 0.0, "albedo_polarity": None, "shading": None}

    def snr(q):
        q = np.clip(np.nan_to_num(q, nan=0.05), 0.05, 0.98)
        return q / (1 - q)

    w_r = snr(q_r)
    shading = None
    if deshade:
        albedo, shading = deshade_albedo(r, albedo, mask, pitch, weights=w_r)
    a = np.where(mask, np.nan_to_num(albedo), 0.0).astype(np.float32)
    q_a = clarity_map(a, mask, pitch)
    sigma = correlation_mm / pitch
    reduce = max(1, int(sigma // 4))
    ra = masked_gaussian(r * a, mask, sigma, reduce=reduce)
    rr = masked_gaussian(r * r, mask, sigma, reduce=reduce)
    aa = masked_gaussian(a * a, mask, sigma, reduce=reduce)
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = np.clip(ra / np.sqrt(np.maximum(rr * aa, 1e-12)), -1, 1)
    rho = np.nan_to_num(rho)
    w_a = snr(q_a)
    overall = 1 if float(np.sum((r * a)[mask])) >= 0 else -1
    if polarity == "local":
        sign = np.sign(rho)
        overall = 1 if float(np.mean(sign[mask])) >= 0 else -1
    else:
        # one polarity for the print: it is the capture's (how ridges reflect), while the
        # local correlation crosses zero wherever the two signals' ridge phases drift apart
        # (the ridges' own shading turns the albedo's, deshade_albedo; scanner errors bias
        # the relief's), and a sign taken there flips the albedo
        # abruptly, printing seams and cancelling ridges
        sign = np.float32(overall)
    mixed = (w_r * r + sign * w_a * a) / (w_r + w_a)
    share = float(np.mean((w_a / (w_r + w_a))[mask])) if mask.any() else 0.0
    return np.where(mask, mixed, np.nan).astype(np.float32), {
        "relief_clarity": q_r, "albedo_clarity": q_a, "correlation": rho,
        "albedo_share": share,
        "albedo_polarity": overall if shading is None else shading["polarity"] * overall,
        "shading": shading}


def gate_mask(clarity, mask, *, min_clarity: float, min_area_px: int = 0,
              min_share: float = 0.25) -> np.ndarray:
    """`mask` less the pixels whose clarity is below `min_clarity`; the large pieces kept.

    Parameters
    ----------
    clarity : (H, W) float
        :func:`clarity_map` of the print (NaN counts as below).
    mask : (H, W) bool
    min_clarity : float
    min_area_px : int
        Pieces of the remaining mask smaller than this are dropped as well (the largest is
        always kept).
    min_share : float
        So are pieces smaller than this fraction of the largest (a print is one piece of skin,
        or a few large ones parted by a scar or a crease; strips along the scan's edge are
        not).

    Returns
    -------
    (H, W) bool
    """
    keep = np.asarray(mask, dtype=bool) & (np.nan_to_num(clarity, nan=0.0) >= min_clarity)
    label, n = ndi.label(keep)
    if n > 1:
        sizes = np.bincount(label.ravel())
        sizes[0] = 0
        big = sizes >= max(min_area_px, min_share * sizes.max())
        big[sizes.argmax()] = True
        big[0] = False
        keep = big[label]
    return keep
