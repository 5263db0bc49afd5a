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
phase rule of ``docs/conventions.md``: ``u = Phi size / (2 pi n) + origin``, computed as
``phi size / (2 pi n) + k size / n + origin`` from the finest phase and its exact period count
``k`` (in float64, rounded once to float32: the float32 ``Phi`` itself, up to 402 rad, would
carry errors of 1e-4 px).

:func:`decode` is the plain NumPy reference. :func:`decode_fast` (``method="numba"``) is the fast
path, the one ``nail2nail scan`` runs: one numba kernel, parallel over chunks of rows, reads the
frames as stored (uint8, uint16, float32), decodes, unwraps, runs the neighbourhood checks and
triangulates in one pass, holding only per-row temporaries besides the frames and the outputs;
given a :class:`~nail2nail.reconstruction.RayTable` it triangulates on the camera rays in
float64, compensating the projector's distortion model and lens as
:func:`~nail2nail.reconstruction.reconstruct_image` does, given a
:class:`~nail2nail.reconstruction.TriangulationTable` it uses the rational form of thesis
eq. 3.12–3.14. Precision against the reference (``tests/test_scan_fast.py``, virtual finger,
every option): the same mask (no pixel differs; at most a pixel within rounding of a threshold
could), ``xp``, ``yp`` within one float32 step (6.1e-5 px below 1024 px, 1.2e-4 px above; the
kernel's arctangent is exact to 1.5e-7 rad), points within 1e-6 mm of the float64 reference
triangulation of the same coordinates.

Validity: per pixel, the amplitude of the finest frequency (``min_modulation``) and of the
coarser, unwrap-only ones (``cue_modulation``, by default the same) (:data:`LOW_MODULATION`),
saturation, shadow, the unwrapping residual and the panel extent; then two neighbourhood checks:
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
    "NO_POINT",
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
NO_POINT = 128  #: triangulation gave no finite point (:func:`decode_fast` with a table)

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
        :data:`UNWRAP_ERROR`, :data:`OUT_OF_PANEL` (per pixel), :data:`EDGE`, :data:`STEEP`
        (neighbourhood checks on the per-pixel validity) and :data:`NO_POINT` (triangulation).
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


def _check_scale(full_scale) -> float | None:
    if full_scale is None:
        return None
    if isinstance(full_scale, bool) or not 0 < float(full_scale) < np.inf:
        raise ValueError(f"full_scale: expected a positive number or None, got {full_scale!r}")
    return float(full_scale)


def _check_modulation(value, name: str) -> float | None:
    """A modulation threshold: a finite number >= 0 (``None`` allowed for `cue_modulation`)."""
    if value is None and name == "cue_modulation":
        return None
    if (isinstance(value, bool) or not isinstance(value, (int, float, np.number))
            or not 0 <= float(value) < np.inf):
        raise ValueError(f"{name}: expected a finite number >= 0"
                         f"{' or None' if name == 'cue_modulation' else ''}, got {value!r}")
    return float(value)


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


def _panel_coordinate(wrapped, unwrapped, size: float, periods: float, origin: float):
    """``u = Phi size / (2 pi n) + origin`` (float32) of the finest wrapped and unwrapped phase.

    Computed as ``phi size / (2 pi n) + k size / n + origin`` in float64 with the exact period
    count ``k``, then rounded once: the float32 unwrapped phase itself (up to ``2 pi n`` = 402
    rad, steps of 3e-5 rad) carries errors of 1e-4 px.
    """
    k = np.rint((unwrapped - wrapped) * np.float32(1.0 / TWO_PI))
    u = (wrapped.astype(np.float64) * (size / (TWO_PI * periods))
         + (k.astype(np.float64) * (size / periods) + origin))
    return u.astype(np.float32)


def _decode_numpy(frames, pattern_set, *, min_modulation, cue_modulation, min_albedo,
                  saturation, unwrap_tolerance, erode, max_gradient, keep_invalid,
                  full_scale) -> Decoded:
    if pattern_set.scheme != "pmp":
        from .gray_code import decode_gray

        return decode_gray(frames, pattern_set, min_modulation=min_modulation,
                           cue_modulation=cue_modulation, min_albedo=min_albedo,
                           saturation=saturation, unwrap_tolerance=unwrap_tolerance, erode=erode,
                           max_gradient=max_gradient, keep_invalid=keep_invalid,
                           full_scale=full_scale)
    cue = min_modulation if cue_modulation is None else cue_modulation
    scale = _full_scale(frames.dtype) if full_scale is None else full_scale
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
            block = frames[start:start + f.steps].astype(np.float32)
            if scale != 1.0:
                block /= np.float32(scale)
            start += f.steps
            phi, b, _ = wrapped_phase(block, pattern_set.shifts(f.steps))
            phases.append(phi)
            amplitudes.append(b)
        finest = int(np.argmax([f.periods for f in freqs]))
        np.minimum(finest_amplitude, amplitudes[finest], out=finest_amplitude)
        for i, b in enumerate(amplitudes):  # the coarser, unwrap-only frequencies
            if i != finest:
                np.minimum(min_amplitude, b, out=min_amplitude)
        unwrapped, bad = unwrap_hierarchical(
            phases, [f.periods for f in freqs], tolerance=unwrap_tolerance
        )
        reason[bad] |= UNWRAP_ERROR
        size = pattern_set.axis_size(direction)
        u = _panel_coordinate(phases[finest], unwrapped, size, freqs[finest].periods,
                              pattern_set.phase_origin)
        with np.errstate(invalid="ignore"):
            outside = (u < -0.5) | (u > size - 0.5)
        reason[outside] |= OUT_OF_PANEL
        coords[direction] = u
    reason[(finest_amplitude < min_modulation) | (min_amplitude < cue)] |= LOW_MODULATION
    return finish_decoded(reason, coords, finest_amplitude, albedo, erode=erode,
                          max_gradient=max_gradient, keep_invalid=keep_invalid)


def finish_decoded(reason, coords: dict, modulation, albedo, *, erode: int,
                   max_gradient: float | None, keep_invalid: bool) -> Decoded:
    """The :class:`Decoded` of any scheme from its per-pixel reasons: the neighbourhood checks
    (:func:`neighbourhood_reasons`), the mask, NaN outside it (unless `keep_invalid`) and the
    lit intensity ``2 B`` (``B`` = `modulation`, the finest fringe's amplitude).

    Parameters
    ----------
    reason : (H, W) uint8
        Per-pixel reasons so far.
    coords : dict of str to (H, W) float32
        Decoded panel coordinate per direction (``"x"``, ``"y"``), modified in place.
    modulation, albedo : (H, W) float
        Fringe amplitude and mean intensity, fractions of full scale.
    """
    reason = neighbourhood_reasons(reason, list(coords.values()), erode=erode,
                                   max_gradient=max_gradient)
    mask = reason == 0
    if not keep_invalid:
        for u in coords.values():
            u[~mask] = np.nan
    intensity = np.where(mask, np.float32(2.0) * modulation, np.float32(0.0))
    return Decoded(
        xp=coords.get("x"),
        yp=coords.get("y"),
        modulation=modulation.astype(np.float32, copy=False),
        albedo=albedo.astype(np.float32, copy=False),
        intensity=np.minimum(intensity, np.float32(1.0)).astype(np.float32),
        mask=mask,
        reason=reason,
    )


def decode(
    frames,
    pattern_set: PatternSet,
    *,
    min_modulation: float = 0.03,
    cue_modulation: float | None = None,
    min_albedo: float = 0.02,
    saturation: float = 254.5 / 255.0,
    unwrap_tolerance: float = np.pi / 2,
    erode: int = 1,
    max_gradient: float | None = None,
    keep_invalid: bool = False,
    full_scale: float | None = None,
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
        Smallest accepted amplitude ``B`` of the finest frequency of each direction, fraction of
        full scale (0.03 = 7.7 grey levels of 8-bit amplitude; ``sigma_phi = sqrt(2/N) sigma /
        B``); for the Gray-code schemes the fine signal's (:mod:`nail2nail.gray_code`).
    cue_modulation : float or None
        Smallest accepted amplitude of the coarser frequencies, which only unwrap (their phase
        scaled by the frequency ratio must err by less than ``unwrap_tolerance``, not set the
        precision), and of the Gray-code bits' contrast; ``None`` (default): `min_modulation`,
        i.e. every frequency alike.
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
    full_scale : float, optional
        Value of full intensity of integer frames: 255 for uint8 and 65535 for uint16 by
        default; ``2**bit_depth - 1`` for right-aligned values (frames read with ``raw=True``).
    method : {"numpy", "numba"}
        Plain NumPy reference, or the fused kernel of :func:`decode_fast`.
    table : RayTable or TriangulationTable, optional
        With ``method="numba"``, also triangulate into ``Decoded.xyz`` (:func:`decode_fast`).

    Returns
    -------
    Decoded

    Notes
    -----
    The Gray-code schemes (``pattern_set.scheme`` ``"gray-phase"``, ``"gray"``) are decoded by
    :func:`nail2nail.gray_code.decode_gray` in NumPy whatever `method` (the fused kernel
    decodes PMP only), unless a `table` is asked for (an error).

    Raises
    ------
    ValueError, TypeError
        On a frame count that does not match the pattern set, a wrong shape or dtype, an
        option out of range.

    Examples
    --------
    >>> from nail2nail.patterns import PatternSet, make_patterns
    >>> ps = PatternSet(x=[(1, 3), (8, 4)], panel_size=(64, 4))
    >>> d = decode(make_patterns(ps), ps, saturation=1.01)  # the patterns reach 255
    >>> bool(np.abs(d.xp - np.arange(64)).max() < 0.05), d.yp is None
    (True, True)
    """
    frames = _check_frames(frames, pattern_set)
    options = dict(min_modulation=_check_modulation(min_modulation, "min_modulation"),
                   cue_modulation=_check_modulation(cue_modulation, "cue_modulation"),
                   min_albedo=float(min_albedo),
                   saturation=float(saturation), unwrap_tolerance=float(unwrap_tolerance),
                   erode=_check_erode(erode), max_gradient=_check_gradient(max_gradient),
                   keep_invalid=bool(keep_invalid), full_scale=_check_scale(full_scale))
    if method not in ("numpy", "numba"):
        raise ValueError(f"method: expected 'numpy' or 'numba', got {method!r}")
    if method == "numpy" or (pattern_set.scheme != "pmp" and table is None):
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

# Fast-math flags of the decoding arithmetic: fused multiply-adds and signed zeros only. Not
# nnan/ninf (the NaN and finiteness tests must hold), not arcp/reassoc (divisions and sums round
# as the reference's do, so thresholds fall on the same pixels).
_FAST = {"nsz", "contract"}


@numba.njit(inline="always", fastmath=_FAST, error_model="numpy")
def _atan2_0_2pi(y, x):  # pragma: no cover - compiled
    """``atan2(y, x)`` in float32 mapped to ``[0, 2 pi)``, branch-free, |error| < 1.5e-7 rad.

    ``atan(a) = a P(a^2)`` on ``[0, 1]`` with ``P`` of degree 7 (minimax, 3.7e-8 rad in exact
    arithmetic), then the octant. The error is 5e-7 px of the finest 20 px period: float32
    rounding of ``u`` dominates.
    """
    ax = abs(x)
    ay = abs(y)
    mx = max(ax, ay)
    mn = min(ax, ay)
    a = mn / mx  # 0 / 0 (no signal): NaN, which the last line maps to 0 as atan2 does
    s = a * a
    p = np.float32(-0.004054565772773874)
    p = p * s + np.float32(0.021862953069985366)
    p = p * s + np.float32(-0.05591232053743348)
    p = p * s + np.float32(0.09642196935403262)
    p = p * s + np.float32(-0.13908629429165978)
    p = p * s + np.float32(0.19946565636345642)
    p = p * s + np.float32(-0.3332986078429215)
    p = p * s + np.float32(0.9999993355789593)
    r = a * p
    r = np.float32(1.5707964) - r if ay > ax else r
    r = np.float32(3.1415927) - r if x < 0 else r
    r = np.float32(6.2831855) - r if y < 0 else r
    return r if r < np.float32(6.2831855) else np.float32(0.0)


@numba.njit(fastmath=_FAST, error_model="numpy")
def _decode_row(frames, r, block_frame, block_cos, block_sin, block_size, group_block,
                group_bscale, group_ratio, dir_groups, dir_levels, dir_coef, dir_period,
                dir_origin, dir_size, inv_scale, sat_native, min_mod2, cue_mod2, min_alb, tol,
                acc_s, acc_c, b2, total, peak, flags, min_b, fine_b, big_phi,
                u_row, reason_row, mod_row, alb_row):  # pragma: no cover - compiled
    """Decode camera row `r`: ``u_row (n_dirs, W)``, per-pixel reasons, modulation, albedo.

    Every loop runs over the columns without branches (conditional expressions become
    selects), for LLVM's vectoriser; the frames are read as stored (uint8, uint16, float32),
    three at a time, and the amplitudes are kept squared until the output: `min_b` the
    smallest of the coarser (unwrap-only) levels', checked against `cue_mod2`, `fine_b` the
    finest levels', against `min_mod2`.
    """
    width = frames.shape[2]
    zero = np.float32(0.0)
    half = np.float32(0.5)
    two_pi = np.float32(TWO_PI)
    inv_two_pi = np.float32(1.0 / TWO_PI)
    inf = np.float32(np.inf)
    for d in range(dir_groups.shape[0]):
        for j in range(dir_levels[d]):  # coarse to fine
            g = dir_groups[d, j]
            coarse = j < dir_levels[d] - 1
            first = group_block[g, 0]
            for bi in range(first, first + group_block[g, 1]):
                k0, k1, k2 = block_frame[bi, 0], block_frame[bi, 1], block_frame[bi, 2]
                c0, c1, c2 = block_cos[bi, 0], block_cos[bi, 1], block_cos[bi, 2]
                s0, s1, s2 = block_sin[bi, 0], block_sin[bi, 1], block_sin[bi, 2]
                start = (d == 0) & (j == 0) & (bi == first)  # the row's first frames
                if block_size[bi] == 1:  # a frequency's last frame or two, one at a time
                    for c in range(width):
                        f0 = np.float32(frames[k0, r, c])
                        acc_s[c] += f0 * s0
                        acc_c[c] += f0 * c0
                        total[c] += f0
                        peak[c] = max(peak[c], f0)
                elif start:
                    for c in range(width):
                        f0 = np.float32(frames[k0, r, c])
                        f1 = np.float32(frames[k1, r, c])
                        f2 = np.float32(frames[k2, r, c])
                        acc_s[c] = f0 * s0 + f1 * s1 + f2 * s2
                        acc_c[c] = f0 * c0 + f1 * c1 + f2 * c2
                        total[c] = f0 + f1 + f2
                        peak[c] = max(f0, max(f1, f2))
                elif bi == first:
                    for c in range(width):
                        f0 = np.float32(frames[k0, r, c])
                        f1 = np.float32(frames[k1, r, c])
                        f2 = np.float32(frames[k2, r, c])
                        acc_s[c] = f0 * s0 + f1 * s1 + f2 * s2
                        acc_c[c] = f0 * c0 + f1 * c1 + f2 * c2
                        total[c] += f0 + f1 + f2
                        peak[c] = max(peak[c], max(f0, max(f1, f2)))
                else:
                    for c in range(width):
                        f0 = np.float32(frames[k0, r, c])
                        f1 = np.float32(frames[k1, r, c])
                        f2 = np.float32(frames[k2, r, c])
                        acc_s[c] += f0 * s0 + f1 * s1 + f2 * s2
                        acc_c[c] += f0 * c0 + f1 * c1 + f2 * c2
                        total[c] += f0 + f1 + f2
                        peak[c] = max(peak[c], max(f0, max(f1, f2)))
            bscale = group_bscale[g]
            ratio = group_ratio[g]
            # acc_s, acc_c become this level's wrapped phase and period count
            if j == 0:
                for c in range(width):
                    sv = acc_s[c]
                    cv = acc_c[c]
                    q = (sv * sv + cv * cv) * bscale
                    qc = q if coarse else inf
                    min_b[c] = qc if d == 0 else min(min_b[c], qc)
                    phi = _atan2_0_2pi(sv, cv)
                    big_phi[c] = phi
                    acc_s[c] = phi
                    acc_c[c] = zero
                    b2[c] = q
                    flags[c] = np.uint8(0) if d == 0 else flags[c]
            else:
                for c in range(width):
                    sv = acc_s[c]
                    cv = acc_c[c]
                    q = (sv * sv + cv * cv) * bscale
                    min_b[c] = min(min_b[c], q if coarse else inf)
                    phi = _atan2_0_2pi(sv, cv)
                    target = big_phi[c] * ratio
                    k = np.rint((target - phi) * inv_two_pi)
                    unwrapped = phi + two_pi * k
                    flags[c] |= np.uint8(8) if abs(target - unwrapped) > tol else np.uint8(0)
                    big_phi[c] = unwrapped
                    acc_s[c] = phi
                    acc_c[c] = k
                    b2[c] = q
        # u = phi size / (2 pi n) + k size / n + origin in float64 from the finest level's phase
        # and its exact period count: rounded once, where the float32 unwrapped phase (up to
        # 2 pi n = 402 rad) would carry errors of 1e-4 px
        coef = dir_coef[d]
        period = dir_period[d]
        origin = dir_origin[d]
        upper = dir_size[d] - half
        u_out = u_row[d]
        for c in range(width):
            fine_b[c] = b2[c] if d == 0 else min(fine_b[c], b2[c])
            u = np.float32(np.float64(acc_s[c]) * coef + (np.float64(acc_c[c]) * period + origin))
            u_out[c] = u
            flags[c] |= np.uint8(16) if (u < -half) | (u > upper) else np.uint8(0)
    for c in range(width):
        alb = total[c] * inv_scale
        f = flags[c]
        f |= np.uint8(2) if peak[c] >= sat_native else np.uint8(0)
        f |= np.uint8(4) if alb < min_alb else np.uint8(0)
        f |= np.uint8(1) if (min_b[c] < cue_mod2) | (fine_b[c] < min_mod2) else np.uint8(0)
        reason_row[c] = f
        alb_row[c] = alb
        mod_row[c] = np.sqrt(fine_b[c])


# Layout of the packed ray-triangulation constants (_pack_ray, _ray_points).
_RAY_INV, _RAY_CENTER, _RAY_G, _RAY_H, _RAY_NORM = 0, 9, 12, 21, 24
_RAY_DIST, _RAY_K, _RAY_KINV, _RAY_LENS, _RAY_SIZE = 29, 32, 38, 44, 49
_USE_CODE = {"xpyp": 0, "xp": 1, "yp": 2}


def _pack_ray(table) -> tuple[np.ndarray, np.ndarray]:
    """A :class:`~nail2nail.reconstruction.RayTable`'s constants as the kernel reads them:
    ``(ray_f (49,) float64, ray_i (4,) int64)``."""
    f = np.zeros(_RAY_SIZE)
    f[_RAY_INV:_RAY_INV + 9] = table.camera_inverse.ravel()
    center = table.camera_center
    f[_RAY_CENTER:_RAY_CENTER + 3] = center
    M = table.projector_matrix
    P = M[:, :3]
    f[_RAY_G:_RAY_G + 9] = (P @ table.camera_inverse).ravel()  # q = P d from (x, y, 1)
    f[_RAY_H:_RAY_H + 3] = P @ center + M[:, 3]  # the camera centre seen by the projector
    f[_RAY_NORM:_RAY_NORM + 5] = [P[0] @ P[0], P[1] @ P[1], P[2] @ P[2], P[0] @ P[2],
                                  P[1] @ P[2]]
    has_dist = table.panel_distortion is not None
    if has_dist:
        f[_RAY_DIST:_RAY_DIST + 3] = table.panel_distortion
    has_lens = table.projector_intrinsics is not None
    if has_lens:
        K = table.projector_intrinsics
        f[_RAY_K:_RAY_K + 6] = K[:2].ravel()
        f[_RAY_KINV:_RAY_KINV + 6] = np.linalg.inv(K)[:2].ravel()
        f[_RAY_LENS:_RAY_LENS + 5] = table.projector_dist
    i = np.array([_USE_CODE[table.use], has_dist, has_lens, table.lens_iterations], np.int64)
    return f, i


@numba.njit(fastmath=_FAST, error_model="numpy")
def _ideal_panel(px, py, ray_f, ray_i, xd, yd, ideal_x, ideal_y):  # pragma: no cover
    """Ideal pinhole coordinates ``ideal_x, ideal_y`` (float64) of panel coordinates
    ``px, py`` of a projector with lens distortion: the radial distortion model
    ``r -> r + rho^3 r^3`` (:func:`~nail2nail.distortion.ideal_from_panel`) if any, then the
    OpenCV lens inverted by the fixed-point iteration of
    :meth:`~nail2nail.camera_models.Pinhole.undistort` (same formula, same iteration count).
    `xd`, `yd` are scratch."""
    n = px.shape[0]
    has_dist = ray_i[1]
    cx, cy, k = ray_f[_RAY_DIST], ray_f[_RAY_DIST + 1], ray_f[_RAY_DIST + 2]
    a0, a1, a2 = ray_f[_RAY_KINV], ray_f[_RAY_KINV + 1], ray_f[_RAY_KINV + 2]
    a3, a4, a5 = ray_f[_RAY_KINV + 3], ray_f[_RAY_KINV + 4], ray_f[_RAY_KINV + 5]
    k1, k2, p1 = ray_f[_RAY_LENS], ray_f[_RAY_LENS + 1], ray_f[_RAY_LENS + 2]
    p2, k3 = ray_f[_RAY_LENS + 3], ray_f[_RAY_LENS + 4]
    for i in range(n):
        x = np.float64(px[i])
        y = np.float64(py[i])
        dx = x - cx
        dy = y - cy
        f = 1.0 + k * (dx * dx + dy * dy)
        x = cx + dx * f if has_dist else x
        y = cy + dy * f if has_dist else y
        xd[i] = x * a0 + y * a1 + a2  # normalised, distorted
        yd[i] = x * a3 + y * a4 + a5
        ideal_x[i] = xd[i]
        ideal_y[i] = yd[i]
    for _ in range(ray_i[3]):  # iterations outermost: the column loop vectorises
        for i in range(n):
            x = ideal_x[i]
            y = ideal_y[i]
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            ideal_x[i] = (xd[i] - dx) / radial
            ideal_y[i] = (yd[i] - dy) / radial
    b0, b1, b2 = ray_f[_RAY_K], ray_f[_RAY_K + 1], ray_f[_RAY_K + 2]
    b3, b4, b5 = ray_f[_RAY_K + 3], ray_f[_RAY_K + 4], ray_f[_RAY_K + 5]
    for i in range(n):
        x = ideal_x[i]
        y = ideal_y[i]
        ideal_x[i] = x * b0 + y * b1 + b2
        ideal_y[i] = x * b3 + y * b4 + b5


@numba.njit(fastmath=_FAST, error_model="numpy")
def _ray_points(px, py, x0, x_step, xo, y0, yo, ray_f, use, has_dist, x_out, y_out,
                z_out):  # pragma: no cover - compiled
    """World points (float64, mm) on the rays of the camera pixels ``(x0 + x_step i + xo[i],
    y0 + yo[i])`` from the panel coordinates ``px, py`` (ideal ones, or with the radial
    distortion model `has_dist` removed here, :func:`~nail2nail.distortion.ideal_from_panel`).

    The point ``X = C + t d``: ``t`` solves one projector plane (`use` 1: ``xp``, 2: ``yp``)
    or, `use` 0, both in least squares, each residual divided by its plane normal's norm
    (:func:`~nail2nail.reconstruction.reconstruct_points_ray`); in float64.
    """
    m0, m1, m2 = ray_f[_RAY_INV], ray_f[_RAY_INV + 1], ray_f[_RAY_INV + 2]
    m3, m4, m5 = ray_f[_RAY_INV + 3], ray_f[_RAY_INV + 4], ray_f[_RAY_INV + 5]
    m6, m7, m8 = ray_f[_RAY_INV + 6], ray_f[_RAY_INV + 7], ray_f[_RAY_INV + 8]
    g0, g1, g2 = ray_f[_RAY_G], ray_f[_RAY_G + 1], ray_f[_RAY_G + 2]
    g3, g4, g5 = ray_f[_RAY_G + 3], ray_f[_RAY_G + 4], ray_f[_RAY_G + 5]
    g6, g7, g8 = ray_f[_RAY_G + 6], ray_f[_RAY_G + 7], ray_f[_RAY_G + 8]
    h0, h1, h2 = ray_f[_RAY_H], ray_f[_RAY_H + 1], ray_f[_RAY_H + 2]
    n00, n11, n22 = ray_f[_RAY_NORM], ray_f[_RAY_NORM + 1], ray_f[_RAY_NORM + 2]
    n02, n12 = ray_f[_RAY_NORM + 3], ray_f[_RAY_NORM + 4]
    e0, e1, e2 = ray_f[_RAY_CENTER], ray_f[_RAY_CENTER + 1], ray_f[_RAY_CENTER + 2]
    cx, cy, k = ray_f[_RAY_DIST], ray_f[_RAY_DIST + 1], ray_f[_RAY_DIST + 2]
    both = use == 0
    on_x = use == 1
    for i in range(px.shape[0]):
        u = np.float64(px[i])
        v = np.float64(py[i])
        du = u - cx
        dv = v - cy
        f = 1.0 + k * (du * du + dv * dv)
        u = cx + du * f if has_dist else u
        v = cy + dv * f if has_dist else v
        x = x0 + x_step * i + np.float64(xo[i])
        y = y0 + np.float64(yo[i])
        # projector coordinate p of row k of the projector matrix (P | p4): its plane's
        # residual at C + t d is (a t - b) / |r| with r = P_k - p P_2, a = q_k - p q_2 for
        # q = P d, b = p h_2 - h_k for h = P C + p4; t for one division
        q2 = g6 * x + g7 * y + g8
        ax = g0 * x + g1 * y + g2 - q2 * u
        bx = h2 * u - h0
        ay = g3 * x + g4 * y + g5 - q2 * v
        by = h2 * v - h1
        nx = n00 + u * (n22 * u - 2.0 * n02)  # |r|^2
        ny = n11 + v * (n22 * v - 2.0 * n12)
        num = (ax * bx * ny + ay * by * nx) if both else (bx if on_x else by)
        den = (ax * ax * ny + ay * ay * nx) if both else (ax if on_x else ay)
        t = num / den
        x_out[i] = e0 + t * (m0 * x + m1 * y + m2)
        y_out[i] = e1 + t * (m3 * x + m4 * y + m5)
        z_out[i] = e2 + t * (m6 * x + m7 * y + m8)


@numba.njit(fastmath=_FAST, error_model="numpy", cache=_CACHE)
def _ray_points_flat(xc, yc, px, py, ray_f, ray_i):  # pragma: no cover - compiled
    """:func:`_ray_points` (and :func:`_ideal_panel`) on 1-D float64 arrays:
    ``(n, 3)`` float64."""
    n = xc.shape[0]
    out = np.empty((3, n))
    if ray_i[2]:
        ideal = np.empty((2, n))
        _ideal_panel(px, py, ray_f, ray_i, out[0], out[1], ideal[0], ideal[1])
        _ray_points(ideal[0], ideal[1], 0.0, 0.0, xc, 0.0, yc, ray_f, ray_i[0], False, out[0],
                    out[1], out[2])
    else:
        _ray_points(px, py, 0.0, 0.0, xc, 0.0, yc, ray_f, ray_i[0], ray_i[1] != 0, out[0],
                    out[1], out[2])
    return out.T.copy()


@numba.njit(error_model="numpy")
def _check_row(e, height, ring, reason_ring, u_ring, erode, max_gradient, check_gradient,
               flags, near, column):  # pragma: no cover - compiled
    """Per-pixel reasons of row `e` plus :data:`EDGE` and :data:`STEEP` into `flags`, as
    :func:`neighbourhood_reasons` (rows ``e - halo … e + halo`` in the ring buffers).

    EDGE: a pixel within Chebyshev distance `erode` (inside the image) is invalid; STEEP: a
    central-difference gradient of a decoded coordinate exceeds `max_gradient` (all four
    neighbours valid). Compiled without fast-math: the gradients round as the reference's.
    """
    n_dirs = u_ring.shape[1]
    width = u_ring.shape[2]
    slot = e % ring
    here = reason_ring[slot]
    half = np.float32(0.5)
    for c in range(width):
        flags[c] = here[c]
    if erode > 0:
        for c in range(width):
            column[c] = 0
        for rr in range(max(e - erode, 0), min(e + erode + 1, height)):
            row = reason_ring[rr % ring]
            for c in range(width):
                column[c] |= row[c]
        for c in range(width):
            near[c] = column[c]
        for s in range(1, min(erode, width - 1) + 1):  # Chebyshev: the columns s to each side
            for c in range(width - s):
                near[c] |= column[c + s]
            for c in range(width - s):
                near[c + s] |= column[c]
        for c in range(width):
            flags[c] |= np.uint8(32) if (flags[c] == 0) & (near[c] != 0) else np.uint8(0)
    if check_gradient and 0 < e < height - 1:
        g2 = max_gradient * max_gradient
        above = reason_ring[(e - 1) % ring]
        below = reason_ring[(e + 1) % ring]
        ok = column  # STEEP where the pixel and its four neighbours are valid
        for c in range(1, width - 1):
            valid = (here[c] | here[c - 1] | here[c + 1] | above[c] | below[c]) == 0
            ok[c] = np.uint8(64) if valid else np.uint8(0)
        for d in range(n_dirs):
            ua = u_ring[(e - 1) % ring, d]
            uc = u_ring[slot, d]
            ub = u_ring[(e + 1) % ring, d]
            for c in range(1, width - 1):
                gx = (uc[c + 1] - uc[c - 1]) * half
                gy = (ub[c] - ua[c]) * half
                near[c] = ok[c] if gx * gx + gy * gy > g2 else np.uint8(0)
            for c in range(1, width - 1):
                flags[c] |= near[c]


@numba.njit(fastmath=_FAST, error_model="numpy")
def _finish_row(e, height, ring, reason_ring, u_ring, erode, max_gradient, check_gradient,
                keep_invalid, tri_mode, table_dir, num, den, ray_f, ray_i, offsets, mod_row,
                flags, near, column, f64, nan_row, zero_row, out_u, out_int, out_reason,
                out_mask, out_xyz):  # pragma: no cover - compiled
    """Row `e`'s neighbourhood checks (:func:`_check_row`), triangulation and outputs.

    ``tri_mode`` 1: the rational table of one projector coordinate (float32); 2: on the camera
    rays (:func:`_ray_points`, float64). Pixels without a finite point get :data:`NO_POINT`.
    `f64` ``(7, W)`` float64 is scratch; `nan_row`, `zero_row` ``(W,)`` float32 hold NaN, 0.
    """
    width = u_ring.shape[2]
    slot = e % ring
    nan = np.float32(np.nan)
    _check_row(e, height, ring, reason_ring, u_ring, erode, max_gradient, check_gradient, flags,
               near, column)
    x_out, y_out, z_out = f64[0], f64[1], f64[2]
    lo = width  # triangulated: the columns from the row's first valid pixel to its last
    hi = 0
    if tri_mode > 0:
        for c in range(width):
            valid = flags[c] == 0
            lo = min(lo, c) if valid else lo
            hi = max(hi, c + 1) if valid else hi
    if tri_mode == 1 and lo < hi:
        one = np.float32(1.0)
        up = u_ring[slot, table_dir]
        n0, n1, n2, n3, n4, n5 = num[0, e], num[1, e], num[2, e], num[3, e], num[4, e], num[5, e]
        d0, d1 = den[0, e], den[1, e]
        for c in range(lo, hi):
            p = up[c]
            inv = one / (d0[c] + d1[c] * p)
            x_out[c] = (n0[c] + n1[c] * p) * inv
            y_out[c] = (n2[c] + n3[c] * p) * inv
            z_out[c] = (n4[c] + n5[c] * p) * inv
    elif tri_mode == 2 and lo < hi:
        ix, iy = ray_i[4], ray_i[5]
        # a direction the pattern set lacks: the reference's NaN image
        ux = u_ring[slot, ix, lo:hi] if ix >= 0 else nan_row[lo:hi]
        uy = u_ring[slot, iy, lo:hi] if iy >= 0 else nan_row[lo:hi]
        ox = offsets[0, e, lo:hi] if ray_i[6] else zero_row[lo:hi]  # lens-undistorted centres
        oy = offsets[1, e, lo:hi] if ray_i[6] else zero_row[lo:hi]
        xs, ys, zs = x_out[lo:hi], y_out[lo:hi], z_out[lo:hi]
        if ray_i[2]:  # projector lens: ideal coordinates first
            _ideal_panel(ux, uy, ray_f, ray_i, f64[3, lo:hi], f64[4, lo:hi], f64[5, lo:hi],
                         f64[6, lo:hi])
            _ray_points(f64[5, lo:hi], f64[6, lo:hi], np.float64(lo), 1.0, ox, np.float64(e), oy,
                        ray_f, ray_i[0], False, xs, ys, zs)
        else:
            _ray_points(ux, uy, np.float64(lo), 1.0, ox, np.float64(e), oy, ray_f, ray_i[0],
                        ray_i[1] != 0, xs, ys, zs)
    if tri_mode > 0:  # no point: NO_POINT (separate loops: each vectorises)
        for c in range(lo, hi):
            finite = np.isfinite(x_out[c]) & np.isfinite(y_out[c]) & np.isfinite(z_out[c])
            f = flags[c]
            flags[c] = f | (np.uint8(128) if (f == 0) & ~finite else np.uint8(0))
        xyz = out_xyz[e]
        for c in range(width):
            valid = flags[c] == 0
            xyz[c, 0] = np.float32(x_out[c]) if valid else nan
            xyz[c, 1] = np.float32(y_out[c]) if valid else nan
            xyz[c, 2] = np.float32(z_out[c]) if valid else nan
    reason = out_reason[e]
    mask = out_mask[e]
    intensity = out_int[e]
    two = np.float32(2.0)
    one = np.float32(1.0)
    zero = np.float32(0.0)
    for c in range(width):
        f = flags[c]
        valid = f == 0
        reason[c] = f
        mask[c] = valid
        intensity[c] = min(two * mod_row[c], one) if valid else zero
    for d in range(u_ring.shape[1]):
        src = u_ring[slot, d]
        dst = out_u[d, e]
        for c in range(width):
            dst[c] = src[c] if (flags[c] == 0) | keep_invalid else nan


@numba.njit(parallel=True, fastmath=_FAST, error_model="numpy", cache=_CACHE)
def _decode_kernel(frames, block_frame, block_cos, block_sin, block_size, group_block,
                   group_bscale, group_ratio, dir_groups, dir_levels, dir_coef, dir_period,
                   dir_origin, dir_size, inv_scale, sat_native, min_mod2, cue_mod2, min_alb, tol,
                   erode, max_gradient, check_gradient, keep_invalid, chunk, tri_mode, table_dir,
                   num,
                   den, ray_f, ray_i, offsets, out_u, out_mod, out_alb, out_int, out_reason,
                   out_mask, out_xyz):  # pragma: no cover - compiled
    """Decode, check, triangulate: chunks of `chunk` rows in parallel, each decoding its rows
    and ``halo`` rows beyond either end (those the neighbourhood checks read) into ring
    buffers of ``2 halo + 1`` rows; only per-row temporaries, no full-image scratch."""
    height = frames.shape[1]
    width = frames.shape[2]
    n_dirs = dir_groups.shape[0]
    halo = max(erode, 1 if check_gradient else 0)
    ring = 2 * halo + 1
    n_chunks = (height + chunk - 1) // chunk
    for ci in numba.prange(n_chunks):
        a = ci * chunk
        b = min(a + chunk, height)
        lo = max(a - halo, 0)
        hi = min(b + halo, height)
        u_ring = np.empty((ring, n_dirs, width), np.float32)
        reason_ring = np.empty((ring, width), np.uint8)
        f32 = np.empty((11, width), np.float32)
        f32[9] = np.nan
        f32[10] = 0.0
        u8 = np.empty((3, width), np.uint8)
        f64 = np.empty((7, width))
        for rr in range(lo, hi):
            slot = rr % ring
            mod_row = f32[8]  # halo rows: modulation and albedo to scratch
            alb_row = f32[8]
            if (rr >= a) & (rr < b):
                mod_row = out_mod[rr]
                alb_row = out_alb[rr]
            _decode_row(frames, rr, block_frame, block_cos, block_sin, block_size, group_block,
                        group_bscale, group_ratio, dir_groups, dir_levels, dir_coef, dir_period,
                        dir_origin, dir_size, inv_scale, sat_native, min_mod2, cue_mod2, min_alb,
                        tol,
                        f32[0], f32[1], f32[2], f32[3], f32[4], u8[0], f32[5], f32[6], f32[7],
                        u_ring[slot], reason_ring[slot], mod_row, alb_row)
            e = rr - halo
            if e >= a:
                _finish_row(e, height, ring, reason_ring, u_ring, erode, max_gradient,
                            check_gradient, keep_invalid, tri_mode, table_dir, num, den, ray_f,
                            ray_i, offsets, out_mod[e], u8[0], u8[1], u8[2], f64, f32[9],
                            f32[10], out_u, out_int, out_reason, out_mask, out_xyz)
        for e in range(max(hi - halo, a), b):  # the last rows of the image
            _finish_row(e, height, ring, reason_ring, u_ring, erode, max_gradient,
                        check_gradient, keep_invalid, tri_mode, table_dir, num, den, ray_f,
                        ray_i, offsets, out_mod[e], u8[0], u8[1], u8[2], f64, f32[9], f32[10],
                        out_u, out_int, out_reason, out_mask, out_xyz)


@dataclass
class _KernelPlan:
    block_frame: np.ndarray  # (n_blocks, 3) frames summed together (single: the first)
    block_cos: np.ndarray  # (n_blocks, 3) float32 cos of the shifts
    block_sin: np.ndarray
    block_size: np.ndarray  # (n_blocks,) 3 or 1
    group_block: np.ndarray  # (n_groups, 2) first block, number of blocks
    group_bscale: np.ndarray  # (2 / (N full_scale))^2
    group_ratio: np.ndarray  # periods / periods of the next coarser frequency
    dir_groups: np.ndarray  # (n_dirs, 16) groups coarse to fine, -1 padded
    dir_levels: np.ndarray  # (n_dirs,) number of groups
    dir_coef: np.ndarray  # float64 size / (2 pi n_finest)
    dir_period: np.ndarray  # float64 size / n_finest
    dir_origin: np.ndarray  # float64
    dir_size: np.ndarray  # float32
    directions: tuple[str, ...]


def _plan(pattern_set: PatternSet, scale: float) -> _KernelPlan:
    block_frame, block_cos, block_sin, block_size = [], [], [], []
    group_block, bscale, ratio = [], [], []
    n_dirs = len(pattern_set.directions)
    dir_groups = -np.ones((n_dirs, 16), dtype=np.int64)
    levels, coef, period, origin, size = [], [], [], [], []
    frame = 0
    for d, direction in enumerate(pattern_set.directions):
        freqs = pattern_set.frequencies(direction)
        if len(freqs) > 16:
            raise ValueError(f"{direction}: at most 16 frequencies per direction")
        first_group = len(group_block)
        for f in freqs:  # groups in frame order; N >= 3: threes, then the one or two left
            shifts = pattern_set.shifts(f.steps)
            starts = [*range(0, f.steps - 2, 3), *range(f.steps - f.steps % 3, f.steps)]
            group_block.append((len(block_frame), len(starts)))
            for b in starts:
                k = [b, b + 1, b + 2] if b + 3 <= f.steps else [b, b, b]
                block_frame.append([frame + i for i in k])
                block_cos.append(np.cos(shifts[k]))
                block_sin.append(np.sin(shifts[k]))
                block_size.append(3 if b + 3 <= f.steps else 1)
            bscale.append((2.0 / (f.steps * scale)) ** 2)
            frame += f.steps
        order = np.argsort([f.periods for f in freqs], kind="stable")
        previous = None
        ratio.extend([1.0] * len(freqs))
        for j, i in enumerate(order):  # unwrapping order: coarse to fine
            g = first_group + int(i)
            dir_groups[d, j] = g
            ratio[g] = 1.0 if previous is None else freqs[i].periods / previous
            previous = freqs[i].periods
        size_px = pattern_set.axis_size(direction)
        levels.append(len(freqs))
        coef.append(size_px / (TWO_PI * previous))
        period.append(size_px / previous)
        origin.append(pattern_set.phase_origin)
        size.append(size_px)
    f32 = np.float32
    return _KernelPlan(
        block_frame=np.asarray(block_frame, np.int64), block_cos=np.asarray(block_cos, f32),
        block_sin=np.asarray(block_sin, f32), block_size=np.asarray(block_size, np.int64),
        group_block=np.asarray(group_block, np.int64), group_bscale=np.asarray(bscale, f32),
        group_ratio=np.asarray(ratio, f32), dir_groups=dir_groups,
        dir_levels=np.asarray(levels, np.int64), dir_coef=np.asarray(coef, np.float64),
        dir_period=np.asarray(period, np.float64), dir_origin=np.asarray(origin, np.float64),
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


def _chunk_rows(height: int) -> int:
    """Rows per parallel chunk: four chunks a thread (each decodes ``2 halo`` extra rows)."""
    return max(1, -(-height // (4 * numba.get_num_threads())))


def decode_fast(
    frames,
    pattern_set: PatternSet,
    *,
    table=None,
    min_modulation: float = 0.03,
    cue_modulation: float | None = None,
    min_albedo: float = 0.02,
    saturation: float = 254.5 / 255.0,
    unwrap_tolerance: float = np.pi / 2,
    erode: int = 1,
    max_gradient: float | None = None,
    keep_invalid: bool = False,
    full_scale: float | None = None,
    out: Decoded | None = None,
) -> Decoded:
    """Fused decode + unwrap + neighbourhood checks (+ triangulation) in numba, one pass.

    Parallel over chunks of rows; each chunk decodes its rows and the few beyond either end
    that the neighbourhood checks read (``erode`` rows, one for ``max_gradient``) into ring
    buffers, so the only full-size arrays are the frames (read as stored: uint8, uint16 or
    float32) and the outputs. Options as :func:`decode`; the results agree with the NumPy
    reference within float32 rounding: ``xp``, ``yp`` within one float32 step (6.1e-5 px below
    1024 px, 1.2e-4 px above), the arctangent being exact to 1.5e-7 rad; the mask the same but
    for pixels whose value lies within rounding of a threshold (``tests/test_scan_fast.py``).
    The first call with a frame dtype compiles the kernel (15 s; then cached on disk,
    ``nail2nail._numba_cache``: 0.2 s in a new process).

    Parameters
    ----------
    frames : (n_frames, H, W) uint8, uint16 or float array
        As for :func:`decode`; float64 frames are copied to float32.
    pattern_set : PatternSet
        What was projected.
    min_modulation, cue_modulation, min_albedo, saturation, unwrap_tolerance, erode, max_gradient,
    keep_invalid
        As for :func:`decode` (`cue_modulation` is the plan's threshold of the coarser levels).
    table : RayTable, TriangulationTable or tuple, optional
        Also triangulate into ``Decoded.xyz``: a
        :class:`~nail2nail.reconstruction.RayTable` (:func:`~nail2nail.reconstruction.ray_table`:
        on the camera rays from one or both projector coordinates, float64, the projector's
        distortion compensated) or a :class:`~nail2nail.reconstruction.TriangulationTable`
        (one projector coordinate, rational form in float32; :func:`planar_table` saves its
        layout change). Pixels without a finite point get :data:`NO_POINT`.
    full_scale : float, optional
        Value of full intensity of integer frames: 255 for uint8 and 65535 for uint16 by
        default; ``2**bit_depth - 1`` for right-aligned values (``raw=True`` frames).
    out : Decoded, optional
        A previous result of the same shape and table kind, overwritten (no allocation).

    Returns
    -------
    Decoded
        With ``xyz (H, W, 3) float32`` (mm) when `table` is given; ``xp``, ``yp`` are views of
        one ``(n_dirs, H, W)`` buffer.

    Raises
    ------
    ValueError, TypeError
        As :func:`decode`; a table for another image size, or whose projector coordinates the
        pattern set does not decode; a pattern set of another scheme than PMP (the Gray-code
        schemes are decoded by :func:`decode`'s NumPy path).

    Examples
    --------
    >>> from nail2nail.patterns import PatternSet, make_patterns
    >>> ps = PatternSet(x=[(1, 3), (8, 4)], panel_size=(64, 4))
    >>> fast = decode_fast(make_patterns(ps), ps, saturation=1.01)
    >>> ref = decode(make_patterns(ps), ps, saturation=1.01)
    >>> bool((fast.mask == ref.mask).all()), float(np.abs(fast.xp - ref.xp).max()) < 1e-5
    (True, True)
    """
    from .reconstruction import RayTable

    frames = _check_frames(frames, pattern_set)
    if pattern_set.scheme != "pmp":
        raise ValueError(f"pattern_set: the fused kernel decodes PMP only, got scheme "
                         f"{pattern_set.scheme!r} (decode it with decode(), the NumPy path)")
    erode = _check_erode(erode)
    max_gradient = _check_gradient(max_gradient)
    min_modulation = _check_modulation(min_modulation, "min_modulation")
    cue_modulation = _check_modulation(cue_modulation, "cue_modulation")
    cue = min_modulation if cue_modulation is None else cue_modulation
    if not frames.flags.c_contiguous:
        frames = np.ascontiguousarray(frames)
    if np.issubdtype(frames.dtype, np.floating) and frames.dtype != np.float32:
        frames = frames.astype(np.float32)
    full_scale = _check_scale(full_scale)
    scale = _full_scale(frames.dtype) if full_scale is None else full_scale
    plan = _plan(pattern_set, scale)
    height, width = frames.shape[1:]
    n_dirs = len(plan.directions)
    num = np.zeros((6, 1, 1), np.float32)
    den = np.zeros((2, 1, 1), np.float32)
    ray_f, ray_i = np.zeros(_RAY_SIZE), np.array([0, 0, 0, 0, -1, -1, 0], np.int64)
    offsets = np.zeros((2, 1, 1), np.float32)
    tri_mode, table_dir = 0, -1
    if isinstance(table, RayTable):
        if tuple(table.shape) != (height, width):
            raise ValueError(f"table: expected a table for images of shape {(height, width)}, "
                             f"got {tuple(table.shape)}")
        missing = [d for d in ("x", "y") if d not in plan.directions]
        if missing and table.needs_both:
            raise ValueError(f"table: triangulation with use={table.use!r}, a projector "
                             "distortion model or lens distortion needs both projector "
                             f"coordinates; the pattern set has no {missing[0]!r} direction")
        tri_mode = 2
        packed, codes = _pack_ray(table)
        ray_f = packed
        ix = plan.directions.index("x") if "x" in plan.directions else -1
        iy = plan.directions.index("y") if "y" in plan.directions else -1
        has_offsets = table.pixel_offsets is not None
        ray_i = np.concatenate([codes, [ix, iy, has_offsets]]).astype(np.int64)
        if has_offsets:
            offsets = table.pixel_offsets
    elif table is not None:
        num, den, axis = planar_table(table)
        if num.shape != (6, height, width) or den.shape != (2, height, width):
            raise ValueError(
                f"table: expected a table for images of shape {(height, width)}, "
                f"got {num.shape[1:]}"
            )
        if axis not in plan.directions:
            raise ValueError(f"table: its axis {axis!r} is not decoded by this pattern set")
        tri_mode, table_dir = 1, plan.directions.index(axis)
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
    if u is None or u.shape[0] != n_dirs:
        raise ValueError("out: expected a Decoded returned by decode_fast for this pattern set")
    xyz = out.xyz if table is not None else np.zeros((1, 1, 3), np.float32)
    f32 = np.float32
    _decode_kernel(
        frames, plan.block_frame, plan.block_cos, plan.block_sin, plan.block_size,
        plan.group_block, plan.group_bscale, plan.group_ratio, plan.dir_groups, plan.dir_levels,
        plan.dir_coef, plan.dir_period, plan.dir_origin, plan.dir_size,
        f32(1.0 / (pattern_set.n_frames * scale)), f32(saturation * scale),
        f32(min_modulation) * f32(min_modulation), f32(cue) * f32(cue), f32(min_albedo),
        f32(unwrap_tolerance), erode, f32(np.inf if max_gradient is None else max_gradient),
        max_gradient is not None, bool(keep_invalid), _chunk_rows(height), tri_mode, table_dir,
        num, den, ray_f, ray_i, offsets, u, out.modulation, out.albedo, out.intensity,
        out.reason, out.mask, xyz,
    )
    return out
