"""Phase decoding of multi-frequency PMP captures: wrapped phase, temporal unwrapping, (xp, yp).

For every camera pixel and every frequency of a :class:`~nail2nail.patterns.PatternSet` the
``N`` frames ``I_k = A + B cos(phi - delta_k)`` give, by least squares (equally spaced shifts),

    ``S = sum_k I_k sin(delta_k) = (N/2) B sin(phi)``,
    ``C = sum_k I_k cos(delta_k) = (N/2) B cos(phi)``,
    ``phi = atan2(S, C)``,  ``B = (2/N) sqrt(S^2 + C^2)``,  ``A = mean_k I_k``.

The coarsest frequency of a direction has at most one period across the panel, so its phase is
unambiguous; every finer one is unwrapped from the previous (hierarchical temporal unwrapping):
``Phi_i = phi_i + 2 pi round((r Phi_{i-1} - phi_i) / 2 pi)`` with ``r = n_i / n_{i-1}``, and the
residual ``|r Phi_{i-1} - Phi_i|`` flags inconsistent pixels. The projector coordinate inverts the
phase rule of ``docs/conventions.md``: ``u = Phi size / (2 pi n) + origin``.

:func:`decode` is the plain NumPy reference; ``method="numba"`` runs the fused kernels of
:func:`decode_fast`, parallel over rows, which also triangulate when given a
:class:`~nail2nail.reconstruction.TriangulationTable` (thesis eq. 3.12–3.14 in rational form).

Validity: per pixel, the amplitude of every frequency (:data:`LOW_MODULATION`), saturation,
shadow, the unwrapping residual and the panel extent; then two neighbourhood checks:
:data:`EDGE` (``erode``: pixels next to invalid ones, whose blurred signal mixes two surfaces or
surface and background) and, optionally, :data:`STEEP` (``max_gradient``). On the virtual
scanner's finger (full scale, default noise, projector distortion off) the default set decodes
with RMS 0.036–0.047 px (x) and 0.034–0.037 px (y) and no pixel off by more than 1 px with
``erode=1, max_gradient=2``; without the gradient check the oblique side cameras reach 0.08 px
(x) with a few hundred pixels off by 1–2.6 px where the fringes are dense and the ridges blur.

References
----------
Thesis chapter two (multi-frequency PMP). K. Liu, Y. Wang, D. L. Lau, Q. Hao, L. G. Hassebrook,
"Dual-frequency pattern scheme for high-speed 3-D shape measurement", Opt. Express 18 (2010)
5229, doi:10.1364/OE.18.005229.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import scipy.ndimage as ndi

from nail2nail._numba_cache import cache_enabled
from nail2nail.patterns import PatternSet

__all__ = [
    "EDGE",
    "LOW_MODULATION",
    "OUT_OF_PANEL",
    "SATURATED",
    "SHADOW",
    "STEEP",
    "UNWRAP_ERROR",
    "Decoded",
    "decode",
    "decode_fast",
    "neighbourhood_reasons",
    "normalize_frames",
    "planar_table",
    "unwrap_hierarchical",
    "wrapped_phase",
]

# Bits of Decoded.reason (0 = valid).
LOW_MODULATION = 1  #: some frequency's amplitude B below ``min_modulation``
SATURATED = 2  #: some frame at or above ``saturation``
SHADOW = 4  #: mean intensity below ``min_albedo``
UNWRAP_ERROR = 8  #: inconsistency between frequencies above ``unwrap_tolerance``
OUT_OF_PANEL = 16  #: decoded coordinate outside the panel's physical extent
EDGE = 32  #: an invalid pixel within ``erode`` pixels
STEEP = 64  #: decoded coordinate changes faster than ``max_gradient`` panel px per camera px

TWO_PI = 2.0 * np.pi


@dataclass
class Decoded:
    """Per-pixel result of :func:`decode` for one camera.

    Attributes
    ----------
    xp, yp : (H, W) float32 or None
        Projector panel coordinates (column, row), px, NaN where invalid; ``None`` when the
        pattern set has no frequencies in that direction.
    modulation : (H, W) float32
        Fringe amplitude ``B`` of the finest frequency (the smaller of the two directions), in
        intensity units ``[0, 1]`` (full scale = 1).
    albedo : (H, W) float32
        Mean intensity over all frames, ``[0, 1]`` (the thesis's C image).
    intensity : (H, W) float32
        Projector-lit intensity ``2 B`` (the thesis's I image), 0 where invalid.
    mask : (H, W) bool
        Valid pixels (``reason == 0``).
    reason : (H, W) uint8
        Bit set of :data:`LOW_MODULATION`, :data:`SATURATED`, :data:`SHADOW`,
        :data:`UNWRAP_ERROR`, :data:`OUT_OF_PANEL` (per pixel) and :data:`EDGE`, :data:`STEEP`
        (neighbourhood checks on the per-pixel validity).
    xyz : (H, W, 3) float32 or None
        World points (mm, NaN where invalid) when a triangulation table was given.
    """

    xp: np.ndarray | None
    yp: np.ndarray | None
    modulation: np.ndarray
    albedo: np.ndarray
    intensity: np.ndarray
    mask: np.ndarray
    reason: np.ndarray
    xyz: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)``."""
        return self.mask.shape


# ------------------------------------------------------------------------------------------------
# Input checks
# ------------------------------------------------------------------------------------------------
def _full_scale(dtype: np.dtype) -> float:
    if dtype == np.uint8:
        return 255.0
    if dtype == np.uint16:
        return 65535.0
    if np.issubdtype(dtype, np.floating):
        return 1.0
    raise TypeError(f"frames: expected uint8, uint16 or float frames, got dtype {dtype}")


def _check_frames(frames, pattern_set: PatternSet) -> np.ndarray:
    if not isinstance(pattern_set, PatternSet):
        raise TypeError(f"pattern_set: expected a PatternSet, got {type(pattern_set).__name__}")
    if isinstance(frames, (list, tuple)):
        frames = np.stack([np.asarray(f) for f in frames])
    frames = np.asarray(frames)
    _full_scale(frames.dtype)
    if frames.ndim != 3:
        raise ValueError(f"frames: expected shape (n_frames, H, W), got {frames.shape}")
    if frames.shape[0] != pattern_set.n_frames:
        raise ValueError(
            f"frames: the pattern set has {pattern_set.n_frames} frames, got {frames.shape[0]}"
        )
    return frames


def normalize_frames(frames) -> np.ndarray:
    """Frames as ``float32`` in ``[0, 1]`` of full scale.

    ``uint8`` is divided by 255, ``uint16`` (left-aligned 10/12/16-bit) by 65535; float input is
    taken as already normalised.

    Examples
    --------
    >>> normalize_frames(np.array([0, 51, 255], np.uint8)).tolist()
    [0.0, 0.20000000298023224, 1.0]
    """
    frames = np.asarray(frames)
    scale = _full_scale(frames.dtype)
    out = frames.astype(np.float32)
    if scale != 1.0:
        out /= np.float32(scale)
    return out


# ------------------------------------------------------------------------------------------------
# NumPy reference
# ------------------------------------------------------------------------------------------------
def wrapped_phase(frames, shifts) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares wrapped phase, amplitude and mean of an ``N``-step sequence.

    Parameters
    ----------
    frames : (N, ...) array_like
        Intensities ``I_k = A + B cos(phi - delta_k)`` (any float units).
    shifts : (N,) array_like
        ``delta_k`` in radians, equally spaced over a full turn (``N >= 3``).

    Returns
    -------
    phase : (...) float32
        ``phi`` in ``[0, 2 pi)``.
    amplitude : (...) float32
        ``B`` (same units as `frames`).
    mean : (...) float32
        ``A``.

    Examples
    --------
    >>> d = 2 * np.pi * np.arange(4) / 4
    >>> phi, b, a = wrapped_phase(0.5 + 0.25 * np.cos(1.0 - d), d)
    >>> round(float(phi), 6), round(float(b), 6), round(float(a), 6)
    (1.0, 0.25, 0.5)
    """
    frames = np.asarray(frames, dtype=np.float32)
    shifts = np.asarray(shifts, dtype=np.float64)
    if shifts.ndim != 1 or shifts.size < 3 or frames.shape[:1] != shifts.shape:
        raise ValueError(
            f"shifts: expected (N,) with N >= 3 matching frames' first axis, got {shifts.shape} "
            f"for frames {frames.shape}"
        )
    # Summed frame by frame, each product and sum rounded to float32: every pixel's value
    # depends on that pixel alone, whatever the array's size (a BLAS dot product fuses some
    # multiply-adds depending on the size, so bands of rows would differ from the whole image).
    sin_d = np.sin(shifts).astype(np.float32)
    cos_d = np.cos(shifts).astype(np.float32)
    s = frames[0] * sin_d[0]
    c = frames[0] * cos_d[0]
    for k in range(1, shifts.size):
        s = s + frames[k] * sin_d[k]
        c = c + frames[k] * cos_d[k]
    n = shifts.size
    phase = np.arctan2(s, c)
    phase = np.where(phase < 0, phase + np.float32(TWO_PI), phase).astype(np.float32)
    phase[phase >= np.float32(TWO_PI)] = 0.0
    amplitude = (np.float32(2.0 / n) * np.hypot(s, c)).astype(np.float32)
    mean = frames.mean(axis=0, dtype=np.float32)
    return phase, amplitude, mean


def unwrap_hierarchical(phases, periods, *, tolerance: float = np.pi / 2):
    """Temporal multi-frequency unwrapping, coarse to fine.

    Parameters
    ----------
    phases : sequence of (...) array_like
        Wrapped phases in ``[0, 2 pi)``, one per frequency, in the order of `periods`.
    periods : sequence of float
        Periods across the panel; sorted here, the smallest must be ``<= 1``.
    tolerance : float
        Largest accepted residual ``|r Phi_coarse - Phi_fine|`` (radians of the finer phase).

    Returns
    -------
    phase : (...) float32
        Unwrapped phase of the finest frequency, ``[0, 2 pi n_max)`` up to noise.
    inconsistent : (...) bool
        Pixels where some level's residual exceeded `tolerance`.

    Examples
    --------
    >>> u = np.array([10.0, 700.0]); size = 1280
    >>> wrap = lambda n: np.mod(2 * np.pi * n * (u + 0.5) / size, 2 * np.pi)
    >>> phi, bad = unwrap_hierarchical([wrap(1), wrap(8), wrap(64)], [1, 8, 64])
    >>> np.round(phi * size / (2 * np.pi * 64) - 0.5, 3).tolist(), bad.tolist()
    ([10.0, 700.0], [False, False])
    """
    periods = [float(p) for p in periods]
    if len(phases) != len(periods) or not periods:
        raise ValueError(
            f"phases, periods: expected equal non-zero lengths, got {len(phases)}, {len(periods)}"
        )
    order = np.argsort(periods, kind="stable")
    if periods[order[0]] > 1.0:
        raise ValueError(f"periods: the coarsest must be <= 1 period, got {periods[order[0]]:g}")
    unwrapped = np.asarray(phases[order[0]], dtype=np.float32)
    inconsistent = np.zeros(unwrapped.shape, dtype=bool)
    previous = periods[order[0]]
    for i in order[1:]:
        wrapped = np.asarray(phases[i], dtype=np.float32)
        target = unwrapped * np.float32(periods[i] / previous)
        k = np.rint((target - wrapped) * np.float32(1.0 / TWO_PI))
        unwrapped = wrapped + np.float32(TWO_PI) * k
        inconsistent |= np.abs(target - unwrapped) > tolerance
        previous = periods[i]
    return unwrapped, inconsistent


def _check_erode(erode) -> int:
    if isinstance(erode, bool) or not isinstance(erode, (int, np.integer)) or erode < 0:
        raise ValueError(f"erode: expected an integer >= 0, got {erode!r}")
    return int(erode)


def _check_gradient(max_gradient) -> float | None:
    if max_gradient is None:
        return None
    if not max_gradient > 0:
        raise ValueError(f"max_gradient: expected a positive number or None, got {max_gradient!r}")
    return float(max_gradient)


def neighbourhood_reasons(reason, coords, *, erode: int = 1, max_gradient: float | None = None):
    """Add :data:`EDGE` and :data:`STEEP` to per-pixel reasons (NumPy reference).

    Parameters
    ----------
    reason : (H, W) uint8
        Per-pixel reasons (0 = valid).
    coords : sequence of (H, W) float arrays
        Decoded coordinates (values at invalid pixels are ignored).
    erode : int
        A valid pixel with an invalid pixel within Chebyshev distance `erode` gets
        :data:`EDGE`: mixed pixels at silhouettes and shadow borders.
    max_gradient : float or None
        A valid pixel whose 4 neighbours are valid gets :data:`STEEP` when the central-difference
        gradient of a coordinate exceeds this, panel px per camera px (fringes too dense for the
        camera's blur: the phase is biased). ``None`` disables.

    Returns
    -------
    (H, W) uint8
    """
    reason = np.asarray(reason, dtype=np.uint8)
    valid = reason == 0
    out = reason.copy()
    if erode > 0:
        kept = ndi.binary_erosion(valid, structure=np.ones((3, 3), bool), iterations=erode,
                                  border_value=1)
        out[valid & ~kept] |= EDGE
    if max_gradient is not None:
        inner = np.zeros_like(valid)
        inner[1:-1, 1:-1] = (valid[1:-1, 1:-1] & valid[1:-1, :-2] & valid[1:-1, 2:]
                             & valid[:-2, 1:-1] & valid[2:, 1:-1])
        for u in coords:
            u = np.asarray(u, dtype=np.float32)
            gx = np.zeros_like(u)
            gy = np.zeros_like(u)
            gx[1:-1, 1:-1] = (u[1:-1, 2:] - u[1:-1, :-2]) * np.float32(0.5)
            gy[1:-1, 1:-1] = (u[2:, 1:-1] - u[:-2, 1:-1]) * np.float32(0.5)
            with np.errstate(invalid="ignore"):
                steep = inner & (gx * gx + gy * gy > np.float32(max_gradient) ** 2)
            out[steep] |= STEEP
    return out


def _decode_numpy(frames, pattern_set, *, min_modulation, min_albedo, saturation,
                  unwrap_tolerance, erode, max_gradient, keep_invalid) -> Decoded:
    scale = _full_scale(frames.dtype)
    height, width = frames.shape[1:]
    reason = np.zeros((height, width), dtype=np.uint8)
    saturated = frames.max(axis=0) >= saturation * scale
    reason[saturated] |= SATURATED
    albedo = frames.mean(axis=0, dtype=np.float32) / np.float32(scale)
    reason[albedo < min_albedo] |= SHADOW
    min_amplitude = np.full((height, width), np.inf, dtype=np.float32)
    finest_amplitude = np.full((height, width), np.inf, dtype=np.float32)
    coords: dict[str, np.ndarray] = {}
    start = 0
    for direction in pattern_set.directions:
        freqs = pattern_set.frequencies(direction)
        phases = []
        amplitudes = []
        for f in freqs:
            block = normalize_frames(frames[start:start + f.steps])
            start += f.steps
            phi, b, _ = wrapped_phase(block, pattern_set.shifts(f.steps))
            phases.append(phi)
            amplitudes.append(b)
            np.minimum(min_amplitude, b, out=min_amplitude)
        finest = int(np.argmax([f.periods for f in freqs]))
        np.minimum(finest_amplitude, amplitudes[finest], out=finest_amplitude)
        unwrapped, bad = unwrap_hierarchical(
            phases, [f.periods for f in freqs], tolerance=unwrap_tolerance
        )
        reason[bad] |= UNWRAP_ERROR
        size = pattern_set.axis_size(direction)
        n = freqs[finest].periods
        u = unwrapped * np.float32(size / (TWO_PI * n)) + np.float32(pattern_set.phase_origin)
        with np.errstate(invalid="ignore"):
            outside = (u < -0.5) | (u > size - 0.5)
        reason[outside] |= OUT_OF_PANEL
        coords[direction] = u.astype(np.float32)
    reason[min_amplitude < min_modulation] |= LOW_MODULATION
    reason = neighbourhood_reasons(reason, list(coords.values()), erode=erode,
                                   max_gradient=max_gradient)
    mask = reason == 0
    if not keep_invalid:
        for u in coords.values():
            u[~mask] = np.nan
    intensity = np.where(mask, np.float32(2.0) * finest_amplitude, np.float32(0.0))
    return Decoded(
        xp=coords.get("x"),
        yp=coords.get("y"),
        modulation=finest_amplitude,
        albedo=albedo.astype(np.float32),
        intensity=np.minimum(intensity, np.float32(1.0)).astype(np.float32),
        mask=mask,
        reason=reason,
    )


def decode(
    frames,
    pattern_set: PatternSet,
    *,
    min_modulation: float = 0.03,
    min_albedo: float = 0.02,
    saturation: float = 254.5 / 255.0,
    unwrap_tolerance: float = np.pi / 2,
    erode: int = 1,
    max_gradient: float | None = None,
    keep_invalid: bool = False,
    method: str = "numpy",
    table=None,
) -> Decoded:
    """Decode one camera's capture into projector coordinates and quality images.

    Parameters
    ----------
    frames : (n_frames, H, W) uint8, uint16 or float array
        The capture, in the frame order of ``frame_table(pattern_set)``; integers are full scale
        255 / 65535, floats are ``[0, 1]``.
    pattern_set : PatternSet
        What was projected.
    min_modulation : float
        Smallest accepted amplitude ``B`` of every frequency, fraction of full scale
        (0.03 = 7.7 grey levels of 8-bit amplitude; ``sigma_phi = sqrt(2/N) sigma / B``).
    min_albedo : float
        Smallest accepted mean intensity (shadow), fraction of full scale.
    saturation : float
        A pixel is saturated when any frame reaches this fraction of full scale.
    unwrap_tolerance : float
        Largest accepted inconsistency between frequencies, radians of the finer phase.
    erode : int
        Drop valid pixels within this many pixels of an invalid one (:data:`EDGE`): blur mixes
        their signal with the neighbour's (silhouettes, shadow borders).
    max_gradient : float or None
        Drop pixels where ``xp`` or ``yp`` changes faster than this many panel px per camera px
        (:data:`STEEP`): there the finest fringe spans few camera pixels and the camera's blur,
        with the surface's texture, biases its phase (on the virtual scanner's finger the
        decoded error RMS grows from 0.05 px at gradient < 1 to 0.13 px at 2–3 and 0.9 px above
        6). ``None`` (default) disables. The threshold is in camera pixels: 2 suits the full-scale
        virtual scanner; scale it by ``1 / scale`` for reduced-resolution cameras.
    keep_invalid : bool
        Keep ``xp``, ``yp`` where invalid instead of NaN (diagnostics).
    method : {"numpy", "numba"}
        Plain NumPy reference, or the fused kernel of :func:`decode_fast`.
    table : TriangulationTable, optional
        With ``method="numba"``, also triangulate into ``Decoded.xyz``.

    Returns
    -------
    Decoded

    Raises
    ------
    ValueError, TypeError
        On a frame count that does not match the pattern set, a wrong shape or dtype.

    Examples
    --------
    >>> from nail2nail.patterns import PatternSet, make_patterns
    >>> ps = PatternSet(x=[(1, 3), (8, 4)], panel_size=(64, 4))
    >>> d = decode(make_patterns(ps), ps, saturation=1.01)  # the patterns reach 255
    >>> bool(np.abs(d.xp - np.arange(64)).max() < 0.05), d.yp is None
    (True, True)
    """
    frames = _check_frames(frames, pattern_set)
    options = dict(min_modulation=float(min_modulation), min_albedo=float(min_albedo),
                   saturation=float(saturation), unwrap_tolerance=float(unwrap_tolerance),
                   erode=_check_erode(erode), max_gradient=_check_gradient(max_gradient),
                   keep_invalid=bool(keep_invalid))
    if method == "numpy":
        if table is not None:
            raise ValueError("table: triangulation is fused only with method='numba'")
        return _decode_numpy(frames, pattern_set, **options)
    if method == "numba":
        return decode_fast(frames, pattern_set, table=table, **options)
    raise ValueError(f"method: expected 'numpy' or 'numba', got {method!r}")


# ------------------------------------------------------------------------------------------------
# Fused fast path
# ------------------------------------------------------------------------------------------------
# cache=True unless no directory at all can hold numba's cache (nail2nail._numba_cache)
_CACHE = cache_enabled()


@numba.njit(inline="always", fastmath=True)
def _atan2_0_2pi(y, x):  # pragma: no cover - compiled
    """``atan2(y, x)`` mapped to ``[0, 2 pi)``, branch-free, |error| < 1.1e-5 rad.

    Abramowitz & Stegun 4.4.47: odd degree-9 polynomial for ``atan`` on ``[0, 1]``.
    """
    ax = abs(x)
    ay = abs(y)
    mx = max(ax, ay)
    mn = min(ax, ay)
    a = mn / max(mx, np.float32(1e-30))
    s = a * a
    r = a * (np.float32(0.9998660) + s * (np.float32(-0.3302995) + s * (
        np.float32(0.1801410) + s * (np.float32(-0.0851330) + s * np.float32(0.0208351)))))
    r = np.float32(1.5707964) - r if ay > ax else r
    r = np.float32(3.1415927) - r if x < 0 else r
    r = np.float32(6.2831855) - r if y < 0 else r
    return r if r < np.float32(6.2831855) else np.float32(0.0)


@numba.njit(parallel=True, fastmath=True, cache=_CACHE)
def _fused_kernel(frames, cos_d, sin_d, group_start, group_steps, group_bscale, group_ratio,
                  group_first,
                  dir_groups, dir_coef, dir_origin, dir_size, inv_scale, sat_native,
                  min_mod, min_alb, tol, out_u, out_mod, out_alb, out_reason):  # pragma: no cover
    # Written for LLVM's loop vectoriser: every inner loop runs over the columns of one row
    # without branches (conditional expressions become selects). Amplitudes are kept squared
    # (group_bscale holds (2 / (N scale))^2) until the one square root of the output.
    n_frames, height, width = frames.shape
    n_dirs = dir_groups.shape[0]
    inv_n = np.float32(1.0 / n_frames)
    two_pi = np.float32(TWO_PI)
    inv_two_pi = np.float32(1.0 / TWO_PI)
    half = np.float32(0.5)
    zero = np.float32(0.0)
    min_mod2 = min_mod * min_mod
    for r in numba.prange(height):
        acc_s = np.empty(width, dtype=np.float32)
        acc_c = np.empty(width, dtype=np.float32)
        total = np.zeros(width, dtype=np.float32)
        peak = np.zeros(width, dtype=np.float32)
        flags = np.zeros(width, dtype=np.uint8)
        min_b = np.full(width, np.inf, dtype=np.float32)
        fine_b = np.full(width, np.inf, dtype=np.float32)
        big_phi = np.zeros(width, dtype=np.float32)
        for d in range(n_dirs):
            for j in range(dir_groups.shape[1]):
                g = dir_groups[d, j]
                if g < 0:
                    break
                # accumulate this frequency's frames (the row stays in L1 cache)
                acc_s[:] = zero
                acc_c[:] = zero
                for k in range(group_start[g], group_start[g] + group_steps[g]):
                    cd = cos_d[k]
                    sd = sin_d[k]
                    for c in range(width):
                        fv = np.float32(frames[k, r, c])
                        acc_s[c] += fv * sd
                        acc_c[c] += fv * cd
                        total[c] += fv
                        peak[c] = max(peak[c], fv)
                bscale = group_bscale[g]
                ratio = group_ratio[g]
                if group_first[g]:
                    for c in range(width):
                        sv = acc_s[c]
                        cv = acc_c[c]
                        b2 = (sv * sv + cv * cv) * bscale
                        min_b[c] = min(min_b[c], b2)
                        big_phi[c] = _atan2_0_2pi(sv, cv)
                        acc_c[c] = b2
                else:
                    for c in range(width):
                        sv = acc_s[c]
                        cv = acc_c[c]
                        b2 = (sv * sv + cv * cv) * bscale
                        min_b[c] = min(min_b[c], b2)
                        phi = _atan2_0_2pi(sv, cv)
                        target = big_phi[c] * ratio
                        unwrapped = phi + two_pi * np.floor((target - phi) * inv_two_pi + half)
                        flags[c] |= np.uint8(8) if abs(target - unwrapped) > tol else np.uint8(0)
                        big_phi[c] = unwrapped
                        acc_c[c] = b2
            # acc_c holds the finest frequency's squared amplitude
            coef = dir_coef[d]
            origin = dir_origin[d]
            upper = dir_size[d] - half
            for c in range(width):
                u = big_phi[c] * coef + origin
                out_u[d, r, c] = u
                outside = (u < -half) | (u > upper)
                flags[c] |= np.uint8(16) if outside else np.uint8(0)
                fine_b[c] = min(fine_b[c], acc_c[c])
        for c in range(width):
            alb = total[c] * inv_n * inv_scale
            f = flags[c]
            f |= np.uint8(2) if peak[c] >= sat_native else np.uint8(0)
            f |= np.uint8(4) if alb < min_alb else np.uint8(0)
            f |= np.uint8(1) if min_b[c] < min_mod2 else np.uint8(0)
            out_reason[r, c] = f
            out_alb[r, c] = alb
            out_mod[r, c] = np.sqrt(fine_b[c])


@numba.njit(parallel=True, fastmath=True, cache=_CACHE)
def _finish_kernel(pix_reason, u_raw, erode, max_gradient, keep_invalid, table_dir, num, den,
                   modulation, out_reason, out_u, out_int, out_xyz):  # pragma: no cover
    """Neighbourhood checks (as :func:`neighbourhood_reasons`), masking and triangulation.

    EDGE: a pixel within Chebyshev distance `erode` (inside the image) is invalid; STEEP: a
    central-difference gradient of a decoded coordinate exceeds `max_gradient` (all four
    neighbours valid). Reads `pix_reason`, `u_raw`; writes the outputs (no race between rows).
    """
    n_dirs, height, width = u_raw.shape
    half = np.float32(0.5)
    nan = np.float32(np.nan)
    zero = np.float32(0.0)
    one = np.float32(1.0)
    two = np.float32(2.0)
    g2 = max_gradient * max_gradient
    check_gradient = max_gradient < np.inf
    for r in numba.prange(height):
        flags = np.empty(width, dtype=np.uint8)
        for c in range(width):
            flags[c] = pix_reason[r, c]
        if erode > 0:
            column = np.zeros(width, dtype=np.uint8)
            for rr in range(max(r - erode, 0), min(r + erode + 1, height)):
                for c in range(width):
                    column[c] |= pix_reason[rr, c]
            near = np.zeros(width, dtype=np.uint8)
            for dc in range(-erode, erode + 1):
                for c in range(max(0, -dc), min(width, width - dc)):
                    near[c] |= column[c + dc]
            for c in range(width):
                flags[c] |= np.uint8(32) if (flags[c] == 0) & (near[c] != 0) else np.uint8(0)
        if check_gradient and 0 < r < height - 1:
            for d in range(n_dirs):
                for c in range(1, width - 1):
                    ok = (pix_reason[r, c] | pix_reason[r, c - 1] | pix_reason[r, c + 1]
                          | pix_reason[r - 1, c] | pix_reason[r + 1, c]) == 0
                    gx = (u_raw[d, r, c + 1] - u_raw[d, r, c - 1]) * half
                    gy = (u_raw[d, r + 1, c] - u_raw[d, r - 1, c]) * half
                    steep = ok & (gx * gx + gy * gy > g2)
                    flags[c] |= np.uint8(64) if steep else np.uint8(0)
        for c in range(width):
            out_reason[r, c] = flags[c]
            out_int[r, c] = min(two * modulation[r, c], one) if flags[c] == 0 else zero
        for d in range(n_dirs):
            for c in range(width):
                v = u_raw[d, r, c]
                out_u[d, r, c] = v if (flags[c] == 0) | keep_invalid else nan
        if table_dir >= 0:
            for c in range(width):
                p = u_raw[table_dir, r, c]
                inv = one / (den[0, r, c] + den[1, r, c] * p)
                inv = inv if flags[c] == 0 else nan
                out_xyz[r, c, 0] = (num[0, r, c] + num[1, r, c] * p) * inv
                out_xyz[r, c, 1] = (num[2, r, c] + num[3, r, c] * p) * inv
                out_xyz[r, c, 2] = (num[4, r, c] + num[5, r, c] * p) * inv


@dataclass
class _KernelPlan:
    cos_d: np.ndarray  # (n_frames,) float32, per frame
    sin_d: np.ndarray
    group_start: np.ndarray  # (n_groups,) first frame of each frequency
    group_steps: np.ndarray
    group_bscale: np.ndarray  # (2 / (N full_scale))^2
    group_ratio: np.ndarray  # periods / periods of the next coarser frequency
    group_first: np.ndarray  # coarsest of its direction
    dir_groups: np.ndarray  # (n_dirs, 16) groups coarse to fine, -1 padded
    dir_coef: np.ndarray  # size / (2 pi n_finest)
    dir_origin: np.ndarray
    dir_size: np.ndarray
    directions: tuple[str, ...]


def _plan(pattern_set: PatternSet, scale: float) -> _KernelPlan:
    cos_d, sin_d = [], []
    start, steps, bscale, ratio, first = [], [], [], [], []
    dir_groups = -np.ones((len(pattern_set.directions), 16), dtype=np.int64)
    coef, origin, size = [], [], []
    frame = 0
    for d, direction in enumerate(pattern_set.directions):
        freqs = pattern_set.frequencies(direction)
        if len(freqs) > 16:
            raise ValueError(f"{direction}: at most 16 frequencies per direction")
        first_group = len(start)
        for f in freqs:  # groups in frame order
            shifts = pattern_set.shifts(f.steps)
            cos_d.extend(np.cos(shifts))
            sin_d.extend(np.sin(shifts))
            start.append(frame)
            steps.append(f.steps)
            bscale.append((2.0 / (f.steps * scale)) ** 2)
            frame += f.steps
        order = np.argsort([f.periods for f in freqs], kind="stable")
        previous = None
        ratio.extend([1.0] * len(freqs))
        first.extend([False] * len(freqs))
        for j, i in enumerate(order):  # unwrapping order: coarse to fine
            g = first_group + int(i)
            dir_groups[d, j] = g
            ratio[g] = 1.0 if previous is None else freqs[i].periods / previous
            first[g] = previous is None
            previous = freqs[i].periods
        size_px = pattern_set.axis_size(direction)
        coef.append(size_px / (TWO_PI * previous))
        origin.append(pattern_set.phase_origin)
        size.append(size_px)
    f32 = np.float32
    return _KernelPlan(
        cos_d=np.asarray(cos_d, f32), sin_d=np.asarray(sin_d, f32),
        group_start=np.asarray(start, np.int64), group_steps=np.asarray(steps, np.int64),
        group_bscale=np.asarray(bscale, f32), group_ratio=np.asarray(ratio, f32),
        group_first=np.asarray(first, np.bool_), dir_groups=dir_groups,
        dir_coef=np.asarray(coef, f32), dir_origin=np.asarray(origin, f32),
        dir_size=np.asarray(size, f32), directions=tuple(pattern_set.directions),
    )


def planar_table(table) -> tuple[np.ndarray, np.ndarray, str]:
    """A triangulation table as contiguous planes ``num (6, H, W)``, ``den (2, H, W)`` float32.

    Done once per calibration; :func:`decode_fast` accepts the result in place of the table.
    """
    if isinstance(table, tuple):
        return table
    num = np.ascontiguousarray(
        np.moveaxis(np.asarray(table.numerator, np.float32).reshape(*table.numerator.shape[:2], 6),
                    -1, 0))
    den = np.ascontiguousarray(np.moveaxis(np.asarray(table.denominator, np.float32), -1, 0))
    return num, den, table.axis


def decode_fast(
    frames,
    pattern_set: PatternSet,
    *,
    table=None,
    min_modulation: float = 0.03,
    min_albedo: float = 0.02,
    saturation: float = 254.5 / 255.0,
    unwrap_tolerance: float = np.pi / 2,
    erode: int = 1,
    max_gradient: float | None = None,
    keep_invalid: bool = False,
    out: Decoded | None = None,
) -> Decoded:
    """Fused decode + unwrap (+ triangulate) in numba, parallel over rows.

    One pass over the frames (phase, amplitude, unwrapping, per-pixel reasons), a neighbourhood
    pass (:func:`neighbourhood_reasons`), and a pass that masks and triangulates. Options as
    :func:`decode`; same results within float32 rounding and the 1.1e-5 rad arctangent
    approximation. `table` is a :class:`~nail2nail.reconstruction.TriangulationTable` or the
    output of :func:`planar_table` (precompute it once to save the layout change); `out`, a
    previous result of the same shape, is overwritten in place (no allocation).

    Returns
    -------
    Decoded
        With ``xyz`` when `table` is given.
    """
    frames = _check_frames(frames, pattern_set)
    erode = _check_erode(erode)
    max_gradient = _check_gradient(max_gradient)
    if not frames.flags.c_contiguous:
        frames = np.ascontiguousarray(frames)
    if np.issubdtype(frames.dtype, np.floating) and frames.dtype != np.float32:
        frames = frames.astype(np.float32)
    scale = _full_scale(frames.dtype)
    plan = _plan(pattern_set, scale)
    height, width = frames.shape[1:]
    n_dirs = len(plan.directions)
    if table is not None:
        num, den, axis = planar_table(table)
        if num.shape != (6, height, width) or den.shape != (2, height, width):
            raise ValueError(
                f"table: expected a table for images of shape {(height, width)}, "
                f"got {num.shape[1:]}"
            )
        if axis not in plan.directions:
            raise ValueError(f"table: its axis {axis!r} is not decoded by this pattern set")
        table_dir = plan.directions.index(axis)
    else:
        num = np.zeros((6, 1, 1), np.float32)
        den = np.zeros((2, 1, 1), np.float32)
        table_dir = -1
    if out is None or out.shape != (height, width) or (table is not None and out.xyz is None):
        u = np.empty((n_dirs, height, width), np.float32)
        out = Decoded(
            xp=u[plan.directions.index("x")] if "x" in plan.directions else None,
            yp=u[plan.directions.index("y")] if "y" in plan.directions else None,
            modulation=np.empty((height, width), np.float32),
            albedo=np.empty((height, width), np.float32),
            intensity=np.empty((height, width), np.float32),
            mask=np.empty((height, width), bool),
            reason=np.empty((height, width), np.uint8),
            xyz=np.empty((height, width, 3), np.float32) if table is not None else None,
        )
        out._u = u  # the (n_dirs, H, W) buffer behind xp and yp
    u = getattr(out, "_u", None)
    if u is None:
        raise ValueError("out: expected a Decoded returned by decode_fast")
    xyz = out.xyz if table is not None else np.zeros((1, 1, 3), np.float32)
    scratch = getattr(out, "_scratch", None)
    if scratch is None:  # per-pixel reasons and raw coordinates, read by the neighbourhood pass
        scratch = out._scratch = (np.empty((height, width), np.uint8), np.empty_like(u))
    pix_reason, u_raw = scratch
    sat_native = np.float32(saturation * scale)
    _fused_kernel(
        frames, plan.cos_d, plan.sin_d, plan.group_start, plan.group_steps,
        plan.group_bscale, plan.group_ratio,
        plan.group_first, plan.dir_groups, plan.dir_coef, plan.dir_origin, plan.dir_size,
        np.float32(1.0 / scale), sat_native,
        np.float32(min_modulation), np.float32(min_albedo), np.float32(unwrap_tolerance),
        u_raw, out.modulation, out.albedo, pix_reason,
    )
    _finish_kernel(pix_reason, u_raw, erode,
                   np.float32(np.inf if max_gradient is None else max_gradient),
                   bool(keep_invalid), table_dir, num, den, out.modulation, out.reason, u,
                   out.intensity, xyz)
    np.equal(out.reason, 0, out=out.mask)
    return out

