"""Phase decoding of multi-frequency PMP captures: wrapped phase, temporal unwrapping, (xp, yp).

For every camera pixel and every frequency of a :class:`~nail2nail.scan.patterns.PatternSet` the
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
given a :class:`~nail2nail.scan.triangulation.RayTable` it triangulates on the camera rays in
float64, compensating the projector's distortion model and lens as
:func:`~nail2nail.scan.triangulation.reconstruct_image` does, given a
:class:`~nail2nail.scan.triangulation.TriangulationTable` it uses the rational form of thesis
eq. 3.12–3.14. Precision against the reference (``tests/test_scan_kernels.py``, virtual finger,
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

import numpy as np

__all__ = [
    "TWO_PI",
    "unwrap_hierarchical",
    "wrapped_phase",
]


TWO_PI = 2.0 * np.pi


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

