"""The scanner's phase-locked error: what in a camera's signals follows the projector's fringes.

A phase-shifting scanner's decoded phase carries a systematic error that is a periodic function
of the phase itself: a projector whose response is not the one the patterns were
pre-compensated for, fringes that are not pure sinusoids (a sharp pixel grid, 8-bit levels),
phase steps that are not the nominal ones. Zhang & Yau (2007) and Pan et al. (2009) correct it
with a look-up table of the error against the wrapped phase. On a finger it turns into relief
(and, with a visible pixel grid, albedo) of the fringes' own period on the skin, 0.6–0.9 mm,
right in the band of the ridges, and a print made of it shows stripes where the skin has no
ridges and a grating mixed into the ridges where it has.

Here the error is modelled per camera, on its pixel grid, as a Fourier series of the decoded
projector coordinate in each direction: harmonics ``k = 1 … K`` of the finest fringe period
``T`` (``cos, sin 2πk u / T``) and the first harmonic of the panel's pixel pitch
(``cos, sin 2π u``), each with an amplitude that varies linearly over the image (the error in
mm along the normal scales with the triangulation's sensitivity, which changes slowly across the
finger). The series is fitted by least squares to the signal (relief, or the albedo less its
smooth part) over the camera's valid pixels. The skin's ridges are not locked to the
projector's phase, but a fit of 60 terms picks some of them up by chance (a few % of their RMS
where they run at the fringes' second harmonic, as on skin), and taking that out would print a
faint grating. So the image is cut in two halves (a checkerboard of blocks), each fitted apart,
and each harmonic is taken out times the agreement of the two halves' fits (a Wiener gain:
about 1 for a real error, about 0 for what one half found by chance).

References
----------
S. Zhang and S.-T. Yau, "Generic nonsinusoidal phase error correction for three-dimensional
shape measurement using a digital video projector," Appl. Opt. 46(1), 36–43 (2007).
B. Pan, Q. Kemao, L. Huang and A. Asundi, "Phase error analysis and compensation for
nonsinusoidal waveforms in phase-shifting digital fringe projection profilometry," Opt. Lett.
34(4), 416–418 (2009).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

__all__ = ["DEFAULT_HARMONICS", "MAX_FIT_SAMPLES", "fringe_basis", "remove_phase_locked"]

#: harmonics of the finest fringe period modelled (4: down to a quarter period, 0.15–0.2 mm on
#: the skin; higher ones are below the ridges' band and smoothed away)
DEFAULT_HARMONICS = 4
#: at most this many of a camera's valid pixels (evenly strided) enter the fit (a
#: full-resolution camera has 300,000–450,000): 200,000 cost 4.5 s more per finger and moved
#: the held-out matcher figures only within their noise (bench/interop.py, conditions 800–807)
MAX_FIT_SAMPLES = 60_000


def fringe_basis(coords: Mapping[str, np.ndarray], periods: Mapping[str, float],
                 harmonics: int = DEFAULT_HARMONICS) -> list[tuple[str, np.ndarray]]:
    """The periodic functions of the projector coordinates the error is expanded in.

    Parameters
    ----------
    coords : mapping of {"x", "y"} to (...) float
        Decoded projector (panel) coordinates of the same pixels, px; NaN where not decoded.
    periods : mapping of {"x", "y"} to float
        The finest fringe period of each direction, panel px (``size / periods`` of the
        pattern set's finest frequency; :func:`nail2nail.scan.patterns.fringe_periods`).
        Directions missing here, or whose coordinates are all NaN, are skipped.
    harmonics : int
        Harmonics of the fringe period, ``k = 1 … harmonics``.

    Returns
    -------
    list of (label, (...) float32)
        ``cos`` and ``sin`` of ``2πk u / T`` for each direction and harmonic, then of ``2π u``
        (the pixel pitch); 0 where the coordinate is NaN.
    """
    labels, matrix = _basis_matrix(coords, periods, harmonics)
    return [(label, matrix[..., j]) for j, label in enumerate(labels)]


def _basis_matrix(coords: Mapping[str, np.ndarray], periods: Mapping[str, float],
                  harmonics: int) -> tuple[list[str], np.ndarray]:
    """:func:`fringe_basis` as one ``(..., terms)`` float32 array (and the terms' labels)."""
    axes = []
    for axis in ("x", "y"):
        if axis not in periods or axis not in coords:
            continue
        u = np.asarray(coords[axis], np.float64)
        finite = np.isfinite(u)
        if finite.any():
            axes.append((axis, np.where(finite, u, 0.0), finite))
    shape = np.shape(axes[0][1]) if axes else np.shape(next(iter(coords.values()), ()))
    labels: list[str] = []
    out = np.empty((*shape, 2 * (harmonics + 1) * len(axes)), np.float32)
    for axis, u, finite in axes:

        def unit(c, finite=finite):  # e^{2πi c}: the argument reduced in float64, so that
            # float32 keeps its digits
            angle = (2 * np.pi * (c - np.floor(c))).astype(np.float32)
            z = np.empty(angle.shape, np.complex64)
            z.real, z.imag = np.cos(angle), np.sin(angle)  # float32: vectorised, 30× float64's
            z[~finite] = 0
            return z

        # harmonics k of the fringe by powers of the first, e^{ikθ} = (e^{iθ})^k (a rounding
        # of float32's 6e-8 per product, against two trigonometric functions per harmonic)
        first = unit(u / float(periods[axis]))
        z = first
        cycles = []
        for k in range(1, harmonics + 1):
            if k > 1:
                z = z * first
            cycles.append((f"{axis}/{k}", z))
        cycles.append((f"{axis}/pixel", unit(u)))
        for label, z in cycles:
            j = len(labels)
            out[..., j], out[..., j + 1] = z.real, z.imag
            labels += [f"cos {label}", f"sin {label}"]
    return labels, out


def _unit_coordinates(index: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Row and column of flat pixel indices, each scaled to [−1, 1] over the image (float32):
    the variables the series' amplitudes are linear in."""
    h, w = shape
    rows, cols = np.divmod(index, w)
    return ((2 * rows / max(h - 1, 1) - 1).astype(np.float32),
            (2 * cols / max(w - 1, 1) - 1).astype(np.float32))


def remove_phase_locked(signals: np.ndarray, valid: np.ndarray,
                        coords: Mapping[str, np.ndarray], periods: Mapping[str, float], *,
                        harmonics: int = DEFAULT_HARMONICS,
                        fit_mask: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    """Take the phase-locked error out of one camera's signals.

    Parameters
    ----------
    signals : (H, W, m) float
        ``m`` signals on the camera's pixel grid (relief in mm, albedo less its smooth part),
        each with a local mean of about 0.
    valid : (H, W) bool
        Pixels whose values count (all signals finite there).
    coords : mapping of {"x", "y"} to (H, W) float
        Decoded projector coordinates, panel px.
    periods : mapping of {"x", "y"} to float
        Finest fringe period per direction, panel px.
    harmonics : int
        Harmonics of the fringe period (:func:`fringe_basis`); 0 leaves the signals as they are.
    fit_mask : (H, W) bool, optional
        The pixels the fit is made on (default `valid`; e.g. leave out grazing views).

    Returns
    -------
    signals : (H, W, m) float32
        The signals less the fitted series on the valid pixels (unchanged elsewhere).
    info : dict
        ``{"terms": n_basis, "samples": n, "removed_rms": [per signal], "gains": {harmonic:
        [per signal]}}``: the RMS of what was taken out over the fit's pixels, in the signals'
        units, and each harmonic's gain (``terms`` 0 and nothing removed when there is no
        coordinate, period or pixel to fit).
    """
    out = np.array(signals, dtype=np.float32, copy=True)
    m = out.shape[-1]
    info: dict = {"terms": 0, "samples": 0, "removed_rms": [0.0] * m}
    valid = np.asarray(valid, bool)
    fit_on = valid if fit_mask is None else valid & np.asarray(fit_mask, bool)
    if harmonics < 0:
        raise ValueError(f"harmonics: expected >= 0, got {harmonics}")
    if harmonics == 0 or not periods:
        return out, info
    h, w = valid.shape
    index = np.flatnonzero(fit_on)
    index = index[:: max(1, index.size // MAX_FIT_SAMPLES)]
    # the series at the fit's pixels only (the whole grid's basis would cost seconds)
    labels, basis = _basis_matrix(
        {k: np.asarray(v).reshape(-1)[index] for k, v in coords.items()}, periods, harmonics)
    n_terms = 3 * len(labels)
    if not labels or index.size < 20 * n_terms:
        return out, info
    rows, cols = np.divmod(index, w)
    r, c = _unit_coordinates(index, (h, w))
    design = np.empty((index.size, n_terms), np.float32)
    design[:, 0::3], design[:, 1::3], design[:, 2::3] = basis, basis * r[:, None], \
        basis * c[:, None]
    target = out.reshape(-1, m)[index].astype(np.float64)
    # two halves of the image, a checkerboard of blocks a sixteenth of its size (several mm:
    # the ridges of one block are independent of the other half's, the scanner's error is not)
    block = max(16, max(h, w) // 16)
    half = ((rows // block + cols // block) % 2).astype(bool)
    a = design.astype(np.float64)
    # normal equations of each half (n ≫ terms; 20× faster than an SVD of the design), solved
    # by least squares so that a term without support (a direction hardly varying) is harmless
    parts = [(a[sel], target[sel]) for sel in (~half, half)]
    grams = [p.T @ p for p, _ in parts]
    rhs = [p.T @ t for p, t in parts]
    coef, *_ = np.linalg.lstsq(grams[0] + grams[1], rhs[0] + rhs[1], rcond=1e-10)
    halves = [np.linalg.lstsq(g, b, rcond=1e-10)[0] for g, b in zip(grams, rhs, strict=True)]
    # each harmonic (its cos and sin, 6 coefficients) kept by the agreement of the halves'
    # fits, ⟨m₁, m₂⟩ / ½(|m₁|² + |m₂|²) over the fit's pixels, clipped to [0, 1]: for an error
    # E and a chance fit L in each half that estimates |E|² / (|E|² + 2|L|²), a (conservative)
    # Wiener gain; ~1 for a real error, ~0 for ridges and noise the fit picked up by chance
    gains = np.zeros((len(labels) // 2, m))
    for g in range(len(labels) // 2):
        cols6 = slice(6 * g, 6 * g + 6)
        m1 = design[:, cols6] @ halves[0][cols6].astype(np.float32)
        m2 = design[:, cols6] @ halves[1][cols6].astype(np.float32)
        cross = np.einsum("ik,ik->k", m1, m2, dtype=np.float64)
        power = 0.5 * (np.einsum("ik,ik->k", m1, m1, dtype=np.float64)
                       + np.einsum("ik,ik->k", m2, m2, dtype=np.float64))
        gains[g] = np.clip(np.divide(cross, power, out=np.zeros(m), where=power > 0), 0, 1)
    coef = coef * np.repeat(gains, 6, axis=0)
    model_at_fit = design @ coef.astype(np.float32)
    info = {"terms": len(labels), "samples": int(index.size),
            "removed_rms": [float(np.sqrt(np.mean(model_at_fit[:, k] ** 2))) for k in range(m)],
            "gains": {labels[2 * g].split(" ", 1)[1]: [round(float(x), 3) for x in gains[g]]
                      for g in range(len(labels) // 2)}}
    # subtract on the valid pixels, the harmonics kept only
    kept = np.flatnonzero(valid)
    r, c = _unit_coordinates(kept, (h, w))
    _, b = _basis_matrix({k: np.asarray(v).reshape(-1)[kept] for k, v in coords.items()},
                         periods, harmonics)
    coef = coef.astype(np.float32)
    flat = out.reshape(-1, m)
    # Σ_j b_j (a0 + ar r + ac c) = B a0 + r (B ar) + c (B ac), B the (n, terms) basis
    model = (b @ coef[0::3] + r[:, None] * (b @ coef[1::3])
             + c[:, None] * (b @ coef[2::3]))
    flat[kept] -= model
    return out, info
