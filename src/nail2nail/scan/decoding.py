"""The NumPy reference decoder: any scheme's frames to a :class:`~nail2nail.scan.results.Decoded`.

:func:`decode` checks its input (:mod:`~nail2nail.scan.inputs`), decodes multi-frequency PMP
(:mod:`~nail2nail.scan.phase_shift`) or a Gray-code scheme (:mod:`~nail2nail.scan.gray`) and
finishes with the neighbourhood checks. It is the reference of the fused kernel
(:func:`~nail2nail.scan.kernels.decode_fast`), plain NumPy and float32, every step an array
operation.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from nail2nail.scan.gray import decode_gray
from nail2nail.scan.inputs import (
    CUE_MODULATION,
    ERODE,
    MIN_ALBEDO,
    MIN_MODULATION,
    SATURATION,
    UNWRAP_TOLERANCE,
    _check_erode,
    _check_frames,
    _check_gradient,
    _check_modulation,
    _check_scale,
    _full_scale,
)
from nail2nail.scan.kernels import decode_fast
from nail2nail.scan.patterns import PatternSet
from nail2nail.scan.phase_shift import _panel_coordinate, unwrap_hierarchical, wrapped_phase
from nail2nail.scan.results import (
    LOW_MODULATION,
    OUT_OF_PANEL,
    SATURATED,
    SHADOW,
    UNWRAP_ERROR,
    Decoded,
    finish_decoded,
)

__all__ = [
    "decode",
]


def _decode_numpy(frames, pattern_set, *, min_modulation, cue_modulation, min_albedo,
                  saturation, unwrap_tolerance, erode, max_gradient, keep_invalid,
                  full_scale) -> Decoded:
    if pattern_set.scheme != "pmp":

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


def decode(
    frames,
    pattern_set: PatternSet,
    *,
    min_modulation: float = MIN_MODULATION,
    cue_modulation: float | None = CUE_MODULATION,
    min_albedo: float = MIN_ALBEDO,
    saturation: float = SATURATION,
    unwrap_tolerance: float = UNWRAP_TOLERANCE,
    erode: int = ERODE,
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
        B``); for the Gray-code schemes the fine signal's (:mod:`nail2nail.scan.gray`).
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
    :func:`nail2nail.scan.gray.decode_gray` in NumPy whatever `method` (the fused kernel
    decodes PMP only), unless a `table` is asked for (an error).

    Raises
    ------
    ValueError, TypeError
        On a frame count that does not match the pattern set, a wrong shape or dtype, an
        option out of range.

    Examples
    --------
    >>> from nail2nail.scan.patterns import PatternSet, make_patterns
    >>> ps = PatternSet(x=[(1, 3), (8, 4)], panel_size=(64, 4))
    >>> d = decode(make_patterns(ps), ps, saturation=1.01)  # the patterns reach 255
    >>> bool(np.abs(d.xp - np.arange(64)).max() < 0.05), d.yp is None
    (True, True)
    """
    frames = _check_frames(frames, pattern_set)
    options: dict[str, Any] = dict(
        min_modulation=_check_modulation(min_modulation, "min_modulation"),
        cue_modulation=_check_modulation(cue_modulation, "cue_modulation"),
                                   min_albedo=float(min_albedo),
                                   saturation=float(saturation),
                                   unwrap_tolerance=float(unwrap_tolerance),
                                   erode=_check_erode(erode),
                                   max_gradient=_check_gradient(max_gradient),
                                   keep_invalid=bool(keep_invalid),
                                   full_scale=_check_scale(full_scale))
    if method not in ("numpy", "numba"):
        raise ValueError(f"method: expected 'numpy' or 'numba', got {method!r}")
    if method == "numpy" or (pattern_set.scheme != "pmp" and table is None):
        if table is not None:
            raise ValueError("table: triangulation is fused only with method='numba'")
        return _decode_numpy(frames, pattern_set, **options)
    if method == "numba":
        return decode_fast(frames, pattern_set, table=table, **options)
    raise ValueError(f"method: expected 'numpy' or 'numba', got {method!r}")

