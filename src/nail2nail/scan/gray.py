"""Gray-code schemes: Gray code plus phase shifting (GCPS) and Gray code plus line shifting.

Two pattern schemes of :class:`~nail2nail.scan.patterns.PatternSet` besides multi-frequency PMP:

``"gray-phase"`` (GCPS)
    Per direction one phase-shifted sinusoid of ``n`` periods (``N`` steps, period
    ``T = size / n`` panel px) and ``ceil(log2 n)`` Gray-code bit planes giving its period
    index ``k`` (Sansoni et al. 1999). With ``complementary=True`` (default) one more bit plane,
    the least significant bit of the Gray code of the half-period index (stripes ``T / 2``
    wide, edges half a period away from the others', i.e. at the sinusoid's phase ``pi``),
    removes the one-period errors where the code edges and the wrapped phase's jumps disagree
    (Zhang Q. et al. 2011; Wu Z. et al. 2019).
``"gray"`` (Gray code plus line shifting, after Gühring 2001)
    Per direction ``ceil(log2(size / w))`` Gray-code bit planes of stripes ``w`` px wide (plus
    the complementary bit of stripes ``w / 2`` wide) for the coarse stripe index, and ``w``
    frames of thin lines, one panel pixel wide, every ``w`` px, shifted by one pixel from frame
    to frame. Each camera pixel's temporal profile over the ``w`` line frames peaks at the
    frame whose line passes through it; the line's position is the profile's circular centroid
    (the argument of its first temporal harmonic), sub-pixel. Gühring located each line in the
    camera image (along camera rows); here the peak is found per camera pixel in time, which
    gives ``xp``/``yp`` on the camera's own pixel grid as the other schemes do.

Panel coordinates (``docs/conventions.md``): ``u`` is the panel pixel-centre coordinate
(``u = 0`` is the centre of column 0) and ``s = u - origin`` (``origin = phase_origin``,
``-1/2`` by default: the panel's physical edge) the coordinate the stripes are cut in: stripe
``k`` of width ``T`` covers ``k T <= s < (k + 1) T`` (a panel pixel shows the value at its
centre), so with the default origin stripe 0 starts at the panel's edge, as the sinusoid's phase
does. Line frame ``j`` (of ``w``) lights the panel pixels with ``(u - ceil(origin)) mod w == j``
(with the default origin: columns ``j, j + w, …``).

Decoding (:func:`decode_gray`; :func:`nail2nail.scan.decoding.decode` dispatches here): every code
bit
is thresholded against a reference, per the pattern set's ``reference``: ``"mean"`` the mean
``A`` of the phase frames (GCPS only), ``"pair"`` the mean of an all-lit and an all-dark frame
(the set's first two frames), ``"inverse"`` each bit's inverse pattern (the frame after it). The
code ``g`` (most significant bit first) gives the period index ``k = gray^-1(g)``, with the
complementary bit the half-period index ``v``; the coarse position is the centre of the stripe
found, ``c = (k + 1/2) T`` (or ``(v + 1/2) T / 2``), and the fine cyclic position ``f`` in
``[0, T)`` (the wrapped phase ``phi T / 2 pi``, or the line centre) is placed in the period
nearest to it: ``s = f + T round((c - f) / T)``. Without the complementary bit this is the
classical ``s = k T + f``, off by one period where ``k`` and ``f`` disagree at a code edge; with
it ``c`` errs by at most ``T / 4`` plus the edge blur (one half-stripe off at most, since the
Gray code changes one bit per edge and the main code's edges fall mid-stripe of the
complementary bit), well inside ``T / 2``.

Validity reasons are those of :class:`~nail2nail.scan.results.Decoded`: :data:`LOW_MODULATION` where
the fine signal's amplitude (the sinusoid's ``B``; for lines the first temporal harmonic's
amplitude) is below ``min_modulation`` or the code's contrast is below ``cue_modulation``
(``min_modulation`` if ``None``); the code's contrast is the largest ``|I - reference|`` over
its bit planes (``|I - I_inverse| / 2`` with inverse patterns): at least one bit is far from
its edge at every lit pixel, while every bit's contrast drops to zero at its own edges, which
the complementary bit makes harmless. :data:`SATURATED`, :data:`SHADOW`,
:data:`OUT_OF_PANEL`, :data:`EDGE` and :data:`STEEP` as for PMP. A Gray code has no redundancy
that would flag a wrong bit, so :data:`UNWRAP_ERROR` is never set here.

Only the NumPy path decodes these schemes; :func:`nail2nail.scan.kernels.decode_fast` (the fused
kernel) decodes PMP only and :func:`nail2nail.scan.capture.scan_capture` routes other schemes to
the NumPy reference.

References
----------
G. Sansoni, M. Carocci, R. Rodella, "Three-dimensional vision based on a combination of
gray-code and phase-shift light projection", Appl. Opt. 38 (1999) 6565,
doi:10.1364/AO.38.006565. J. Gühring, "Dense 3D surface acquisition by structured light using
off-the-shelf components", Proc. SPIE 4309 (2001) 220, doi:10.1117/12.410877. Q. Zhang, X. Su,
L. Xiang, X. Sun, "3-D shape measurement based on complementary Gray-code light", Opt. Lasers
Eng. 50 (2012) 574, doi:10.1016/j.optlaseng.2011.06.024. Z. Wu, W. Guo, Q. Zhang, "High-speed
three-dimensional shape measurement based on shifting Gray-code light", Opt. Express 27 (2019)
22631, doi:10.1364/OE.27.022631.
"""

from __future__ import annotations

import math

import numpy as np

from nail2nail.scan.codes import gray_from_index, index_from_gray
from nail2nail.scan.inputs import _full_scale
from nail2nail.scan.patterns import frame_table, stripe_width
from nail2nail.scan.phase_shift import wrapped_phase
from nail2nail.scan.results import (
    LOW_MODULATION,
    OUT_OF_PANEL,
    SATURATED,
    SHADOW,
    finish_decoded,
)

__all__ = [
    "decode_gray",
    "reference_level",
]


def _frames_of(table, direction, kind) -> list[int]:
    rows = [t for t in table if t.direction == direction and t.kind == kind]
    rows.sort(key=lambda t: (t.bit, t.step))
    return [t.index for t in rows]


def _code_position(frames, table, pattern_set, direction, reference, scale, phase_mean):
    """Coarse position ``c`` (stripe centre in ``s``, float64) and the code's contrast."""

    width = stripe_width(pattern_set, direction)
    bits = _frames_of(table, direction, "gray")
    comp = _frames_of(table, direction, "complementary")
    planes = bits + comp
    inverse = (_frames_of(table, direction, "gray-inverse")
               + _frames_of(table, direction, "complementary-inverse"))
    code = np.zeros(frames.shape[1:], dtype=np.int64)
    contrast = np.zeros(frames.shape[1:], dtype=np.float32)
    level = (phase_mean if reference == "mean" else
             reference_level(frames, table, scale) if reference == "pair" else None)
    for i, k in enumerate(planes):
        value = frames[k].astype(np.float32) / np.float32(scale)
        if reference == "inverse":
            diff = (value - frames[inverse[i]].astype(np.float32) / np.float32(scale)) * 0.5
        else:
            diff = value - level
        code = (code << 1) | (diff > 0)
        np.maximum(contrast, np.abs(diff), out=contrast)
    index = index_from_gray(code)
    if comp:
        centre = (index.astype(np.float64) + 0.5) * (width / 2.0)
    else:
        centre = (index.astype(np.float64) + 0.5) * width
    return centre, contrast, width


def _edge_position(frames, table, direction, centre, width) -> np.ndarray:
    """Sub-stripe position of a Gray-code-only capture with inverse frames (float64 ``s``).

    Each stripe boundary changes exactly one bit plane; at a pixel of stripe ``k`` the
    normalised difference ``d = (I − Ī) / (I + Ī)`` of a bit and its inverse falls to 0 at that
    bit's edge. The pixel lies at ``t = |d_left| / (|d_left| + |d_right|)`` of the way from the
    stripe's left boundary to its right one (``d_left``, ``d_right``: the planes that change at
    the two boundaries), interpolating between the stripe's edges as the blurred edges' own
    profiles say; ``t = ½`` (the centre) where a boundary is missing (the first and last stripe)
    or both differences vanish.
    """
    planes = _frames_of(table, direction, "gray")
    inverse = _frames_of(table, direction, "gray-inverse")
    n_bits = len(planes)
    d = np.empty((n_bits, *frames.shape[1:]), np.float32)
    for i, (k, kbar) in enumerate(zip(planes, inverse, strict=True)):
        a, b = frames[k].astype(np.float32), frames[kbar].astype(np.float32)
        with np.errstate(invalid="ignore", divide="ignore"):
            d[i] = np.abs(a - b) / (a + b)
    index = np.rint(centre / width - 0.5).astype(np.int64)
    last = (1 << n_bits) - 1
    t = np.full(centre.shape, 0.5)
    inner = (index > 0) & (index < last)

    def changed_plane(k1, k2):  # the plane (MSB first) of the one bit two neighbours differ in
        diff = gray_from_index(k1) ^ gray_from_index(k2)
        return n_bits - 1 - np.floor(np.log2(np.maximum(diff, 1))).astype(np.int64)

    k = index[inner]
    rows, cols = np.nonzero(inner)
    d_left = d[changed_plane(k - 1, k), rows, cols].astype(np.float64)
    d_right = d[changed_plane(k, k + 1), rows, cols].astype(np.float64)
    total = d_left + d_right
    with np.errstate(invalid="ignore", divide="ignore"):
        t[inner] = np.where(total > 0, d_left / total, 0.5)
    return (index + t) * width


def reference_level(frames, table, scale) -> np.ndarray:
    """``(white + black) / 2`` of the all-lit and all-dark frames, float32 ``[0, 1]``."""
    white = next(t.index for t in table if t.kind == "white")
    black = next(t.index for t in table if t.kind == "black")
    return ((frames[white].astype(np.float32) + frames[black].astype(np.float32))
            * np.float32(0.5 / scale))


def _fine_position(frames, table, pattern_set, direction, scale):
    """Fine cyclic position ``f`` in ``[0, T)`` of ``s`` (float64), its amplitude and the
    mean of its frames (GCPS's threshold)."""

    width = stripe_width(pattern_set, direction)
    if pattern_set.scheme == "gray-phase":

        (freq,) = pattern_set.frequencies(direction)
        idx = _frames_of(table, direction, "phase")
        block = frames[idx].astype(np.float32) / np.float32(scale)
        phi, amplitude, mean = wrapped_phase(block, pattern_set.shifts(freq.steps))
        return phi.astype(np.float64) * (width / (2.0 * np.pi)), amplitude, mean
    idx = _frames_of(table, direction, "line")
    n = len(idx)
    block = frames[idx].astype(np.float32) / np.float32(scale)
    angles = 2.0 * np.pi * np.arange(n) / n
    # circular centroid of the temporal profile: the first harmonic's argument, frame units
    s = np.tensordot(np.sin(angles).astype(np.float32), block, axes=1)
    c = np.tensordot(np.cos(angles).astype(np.float32), block, axes=1)
    frame = np.mod(np.arctan2(s, c).astype(np.float64) * (n / (2.0 * np.pi)), n)
    amplitude = (np.float32(2.0 / n) * np.hypot(s, c)).astype(np.float32)
    # line j is lit at pixel centres u = ceil(origin) + j (mod w): s = u - origin
    offset = math.ceil(pattern_set.phase_origin) - pattern_set.phase_origin
    return np.mod(frame + offset, n), amplitude, block.mean(axis=0)


def decode_gray(frames, pattern_set, *, min_modulation: float, cue_modulation: float | None,
                min_albedo: float, saturation: float, erode: int, max_gradient: float | None,
                keep_invalid: bool, full_scale: float | None, unwrap_tolerance: float = 0.0):
    """Decode a Gray-code capture (scheme ``"gray-phase"``, ``"gray"`` or ``"gray-code"``), NumPy.

    ``"gray-code"`` has no fine frames: the coordinate is the centre of the decoded stripe
    (quantised to the stripe width ``w``: error uniform in ``±w/2``), and ``modulation`` is the
    code's contrast. No sub-stripe refinement yet.

    Called by :func:`nail2nail.scan.decoding.decode` (which checks the options); the arguments are
    those of :func:`~nail2nail.scan.decoding.decode`. `unwrap_tolerance` is not used (a Gray code
    has no
    redundant frequency to check against).

    Parameters
    ----------
    frames : (n_frames, H, W) uint8, uint16 or float array
        In the frame order of ``frame_table(pattern_set)``.
    pattern_set : PatternSet
        Scheme ``"gray-phase"`` or ``"gray"``.

    Returns
    -------
    Decoded
        ``xp``, ``yp`` in panel px (pixel-centre convention), NaN where invalid unless
        `keep_invalid`; ``modulation`` the fine signal's amplitude.

    Examples
    --------
    >>> from nail2nail.scan.patterns import PatternSet, make_patterns
    >>> ps = PatternSet(x=[(8, 4)], scheme="gray-phase", panel_size=(64, 4))
    >>> from nail2nail.scan.decoding import decode
    >>> d = decode(make_patterns(ps), ps, saturation=1.01, erode=0)
    >>> bool(np.abs(d.xp - np.arange(64)).max() < 0.05)
    True
    """

    if pattern_set.scheme not in ("gray-phase", "gray", "gray-code"):
        raise ValueError(f"pattern_set: expected a Gray-code scheme, got {pattern_set.scheme!r}")
    cue = min_modulation if cue_modulation is None else cue_modulation
    scale = _full_scale(frames.dtype) if full_scale is None else full_scale
    table = frame_table(pattern_set)
    height, width = frames.shape[1:]
    reason = np.zeros((height, width), dtype=np.uint8)
    reason[frames.max(axis=0) >= saturation * scale] |= SATURATED
    albedo = (frames.mean(axis=0, dtype=np.float32) / np.float32(scale)).astype(np.float32)
    reason[albedo < min_albedo] |= SHADOW
    fine_amplitude = np.full((height, width), np.inf, dtype=np.float32)
    coords: dict[str, np.ndarray] = {}
    for direction in pattern_set.directions:
        if pattern_set.scheme == "gray-code":  # the stripe centre, or its edges' interpolation
            s, contrast, width = _code_position(frames, table, pattern_set, direction,
                                                pattern_set.reference, scale, None)
            if pattern_set.reference == "inverse":
                s = _edge_position(frames, table, direction, s, width)
            amplitude = contrast
        else:
            fine, amplitude, mean = _fine_position(frames, table, pattern_set, direction, scale)
            centre, contrast, period = _code_position(frames, table, pattern_set, direction,
                                                      pattern_set.reference, scale, mean)
            s = fine + period * np.rint((centre - fine) / period)
        u = (s + pattern_set.phase_origin).astype(np.float32)
        size = pattern_set.axis_size(direction)
        with np.errstate(invalid="ignore"):
            reason[(u < -0.5) | (u > size - 0.5)] |= OUT_OF_PANEL
        reason[(amplitude < min_modulation) | (contrast < cue)] |= LOW_MODULATION
        np.minimum(fine_amplitude, amplitude, out=fine_amplitude)
        coords[direction] = u
    return finish_decoded(reason, coords, fine_amplitude, albedo, erode=erode,
                          max_gradient=max_gradient, keep_invalid=keep_invalid)

