"""A moving finger's frames brought to one time: the skin held still under the pixels.

Phase shifting fits each pixel's intensities to ``a + b cos(φ + δ_k)``. On a trembling finger
(8–12 Hz, 100 µm RMS moves the skin by about a pixel between steps at 120 frames per second)
the skin's texture, the albedo's ridges and the relief's shading, slides under the pixel while
the steps are shown, so ``a`` and ``b`` are not constant and the fitted phase takes an error
that follows the ridges: on the virtual scanner it is most of a moving finger's shape error
(``bench/motion_texture.py``: 27.6 µm after alignment with the ridges, 5.3 µm on the same
finger without them). :func:`~nail2nail.scan.motion.compensate_phase_steps` corrects the
fringes' phase offsets between steps but not that; :func:`stabilise_frames` does:

1. **Texture images without fringes**: the mean of each 3-step group (the DC image, exact for
   harmonics below 3) and, in a group of an even number ``N ≥ 4`` of steps, the mean of every
   pair of opposite steps ``k, k + N/2`` (their fringes cancel, odd harmonics too) and, when
   3 divides ``N``, of every triple ``k, k + N/3, k + 2N/3``: each the average of known
   frames. The remaining fringe (motion between the two steps, even
   harmonics) is notched out at the group's fringe frequency, the shading by a band-pass.
2. **Their motion**: each texture image registered to one anchor (a 3-step group's mean: no
   fine fringe left in it), as one affine map per image (six
   numbers, Lucas–Kanade over every valid pixel: a rigid motion of a finger seen by one camera
   is affine to within what it changes the result; the true motion reduced to an affine map
   per frame gives the same figures as itself, ``bench/motion_texture.py``), then all of them
   moved so that the mean of the reference group's images (the last group with the most
   fringe periods: the geometry's) is the identity.
3. **The motion of every frame**: the smoothest trajectory of the affine maps over the frames
   (least second differences) whose averages over each image's frames are the measured maps.
4. **The frames resampled** at the skin's position at the reference time (``I_k(x + d_k(x))``,
   bilinear), and each group's pixels fitted again with the shift the resampling itself puts
   in the fringes, ``δ_k + ∇φ · (d_k − d̄)`` (``d̄`` the group's mean motion), so that the
   phase a pixel reads is that of the skin point it shows at the reference time, at the
   group's mean time; in the groups with the most fringe periods, the phase error that the
   motion left unseen by the texture images puts in through the texture is fitted and taken
   out (:func:`texture_phase_error`); the frames re-synthesised with the nominal shifts.

Every pixel then shows one point of skin in every frame: the projector coordinates of both
directions are the same skin point's (so two cameras' pairs in projector space are the same
points, ``docs/motion.md``), and the camera ray is that point's at the reference group's time,
with whose phase alone the point is triangulated (``use="yp"`` for the default patterns: the
other direction's phase is that skin point's at another time, another pose).

Conventions: frame indices are time (equally spaced frames); displacements ``(dy, dx)`` in
camera pixels, ``dy`` along rows, of where a pixel's skin is in a frame relative to where it
is at the reference time; the affine map of an image is ``d(x) = P · (1, x̂, ŷ)`` with
``x̂ = (col − W/2) / W``, ``ŷ = (row − H/2) / H``.

References
----------
Lucas and Kanade, "An iterative image registration technique with an application to stereo
vision", IJCAI 1981 (the affine registration); the motion-induced phase errors of phase
shifting and their compensation from the frames: Weise, Leibe and Van Gool, "Fast 3D scanning
with automatic motion compensation", CVPR 2007; Lu, Yin, Zhang and Wang, "Motion induced error
reduction methods for phase shifting profilometry: a review", Opt. Lasers Eng. 141, 106573
(2021), doi:10.1016/j.optlaseng.2021.106573.
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.ndimage as ndi

from nail2nail._interpolate import bilinear_value
from nail2nail._numba_cache import cache_enabled
from nail2nail.scan.motion import _band, dc_groups, fit_pixel_shifts
from nail2nail.scan.patterns import PatternSet, frame_table

__all__ = ["MIN_TEXTURE_CORRELATION", "STABILISE_BAND_PX", "TEXTURE_PHASE_SIGMA_PX",
           "affine_image_motion", "phase_gradient", "reference_direction", "rigid_motion",
           "stabilise_frames", "texture_phase_error"]

#: Band-pass of the texture images, σ of the difference of Gaussians, camera px: keeps the
#: ridges (7–16 px per period from half to full resolution on the thesis rig), leaves out the
#: shading
STABILISE_BAND_PX = (1.0, 4.0)
#: Radius of the notches at the fringe frequency and its harmonics, cycles per px
NOTCH_RADIUS = 0.015
#: Gauss–Newton iterations of each image's affine registration
ITERATIONS = 12
#: Smallest normalised correlation of a texture image with the anchor once registered: below
#: it the skin shows too little texture (no ridges, noise alone) for its motion to be
#: measured, and the frames are returned as they are (``info["skipped"]``)
MIN_TEXTURE_CORRELATION = 0.5


def _phase_groups(pattern_set: PatternSet) -> list[tuple[str, list[int]]]:
    table = frame_table(pattern_set)
    return [(label, idx) for label, idx in dc_groups(pattern_set)
            if table[idx[0]].kind == "phase"]


def reference_direction(pattern_set: PatternSet, direction: str | None = None) -> str:
    """The direction (``"x"`` or ``"y"``) of the group the frames are stabilised to: `direction`
    when given (the phase the points will be triangulated from), else that of the last in time
    of the groups with the most fringe periods (``"y"`` for the default patterns).

    Raises
    ------
    ValueError
        If the pattern set has no phase-shift group, or none in `direction`.
    """
    return str(_reference_group(pattern_set, direction)[1])


def _reference_group(pattern_set: PatternSet, direction: str | None) -> tuple[str, str]:
    """``(label, direction)`` of the reference group: the last in time of the groups with the
    most fringe periods, among those of `direction` when given."""
    table = frame_table(pattern_set)
    groups = _phase_groups(pattern_set)
    if direction is not None:
        groups = [(label, idx) for label, idx in groups if table[idx[0]].direction == direction]
    if not groups:
        raise ValueError("stabilise_frames: the pattern set has no phase-shift group"
                         + (f" in direction {direction!r}" if direction is not None else ""))
    most = max(table[idx[0]].periods for _, idx in groups)
    label, idx = [(label, idx) for label, idx in groups if table[idx[0]].periods == most][-1]
    return label, str(table[idx[0]].direction)


def phase_gradient(c: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The fringe phase's gradient from a fit's ``C, S`` (:func:`~nail2nail.scan.motion.
    fit_pixel_shifts`, ``(H, W)`` each): ``∂φ/∂row, ∂φ/∂col`` of ``φ = atan2(S, C)``, rad per
    camera px, central differences of the wrapped phase (so a fringe's 2π jumps do not
    count); 0 on the image's outer rows and columns."""
    z = c + 1j * s
    gy, gx = np.zeros(c.shape), np.zeros(c.shape)
    gy[1:-1] = np.angle(z[2:] * np.conj(z[:-2])) / 2
    gx[:, 1:-1] = np.angle(z[:, 2:] * np.conj(z[:, :-2])) / 2
    return gy, gx


def _notch(shape, frequency, radius: float = NOTCH_RADIUS, harmonics: int = 3) -> np.ndarray:
    """Multiplicative notch filter (DFT layout) at ``± h · frequency`` (cycles per px, ``(fy,
    fx)``), ``h = 1 … harmonics``."""
    fy = np.fft.fftfreq(shape[0])[:, None]
    fx = np.fft.fftfreq(shape[1])[None, :]
    out = np.ones(shape)
    for h in range(1, harmonics + 1):
        for sign in (1, -1):
            out *= 1 - np.exp(-((fy - sign * h * frequency[0]) ** 2
                                + (fx - sign * h * frequency[1]) ** 2) / (2 * radius**2))
    return out


def _fringe_frequency(c: np.ndarray, valid: np.ndarray) -> tuple[float, float]:
    """The peak of the fringe image's spectrum, ``(fy, fx)`` cycles per px."""
    spectrum = np.abs(np.fft.fft2(np.where(valid, c, 0.0)))
    spectrum[0, 0] = 0
    row, col = np.unravel_index(int(np.argmax(spectrum)), spectrum.shape)
    return float(np.fft.fftfreq(c.shape[0])[row]), float(np.fft.fftfreq(c.shape[1])[col])


def _affine_basis_at(rows, cols, shape) -> np.ndarray:
    """``(3, …)``: the affine maps' basis ``(1, x̂, ŷ)`` at pixels ``rows, cols`` (any equal
    shapes) of an image of ``shape = (H, W)``: ``x̂ = (col − W/2) / W``, ``ŷ = (row − H/2) / H``
    (the module's convention; the compiled kernels take it from :func:`_basis_xy`)."""
    h, w = shape
    return np.stack([np.ones(np.shape(rows)), (cols - w / 2) / w, (rows - h / 2) / h])


@numba.njit(cache=cache_enabled(), nogil=True, error_model="numpy")
def _basis_xy(r, c, h, w):  # pragma: no cover - compiled
    """``(x̂, ŷ)`` of :func:`_affine_basis_at` at one pixel ``(r, c)`` of an ``(h, w)`` image."""
    return (c - w / 2) / w, (r - h / 2) / h


def _affine_basis(shape) -> np.ndarray:
    """``(3, H, W)``: :func:`_affine_basis_at` at every pixel."""
    h, w = shape
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float64)
    return _affine_basis_at(rows, cols, shape)


def _warp_affine(image: np.ndarray, params: np.ndarray) -> np.ndarray:
    """``image(x + P·b(x))``, `params` ``P`` ``(2, 3)`` (row 0 ``dy``, row 1 ``dx``) on the
    basis :func:`_affine_basis_at`: bilinear, positions beyond the image read its edge
    (``scipy.ndimage.map_coordinates(order=1, mode="nearest")``), float64, compiled without
    the displacement images."""
    out = np.empty(image.shape)
    _warp_affine_kernel(np.ascontiguousarray(image), np.ascontiguousarray(params, np.float64),
                        out)
    return out


@numba.njit(cache=cache_enabled(), nogil=True, error_model="numpy")
def _warp_affine_kernel(image, params, out):  # pragma: no cover - compiled
    h, w = image.shape
    for r in range(h):
        for c in range(w):
            xh, yh = _basis_xy(r, c, h, w)
            dy = params[0, 0] + params[0, 1] * xh + params[0, 2] * yh
            dx = params[1, 0] + params[1, 1] * xh + params[1, 2] * yh
            # mode "nearest" of the bilinear warp: the position clamped into the image
            out[r, c] = bilinear_value(image, min(max(r + dy, 0.0), h - 1.0),
                                       min(max(c + dx, 0.0), w - 1.0))


def _register_affine(image: np.ndarray, reference: np.ndarray, weight: np.ndarray,
                     iterations: int = ITERATIONS) -> np.ndarray:
    """``(2, 3)`` affine map ``P`` with ``image(x + P·b(x)) ≈ reference(x)`` (Gauss–Newton,
    weighted least squares over the pixels of positive `weight`, the moved image's gradient
    as :func:`numpy.gradient` takes it; row 0 ``dy``, row 1 ``dx``, basis
    :func:`_affine_basis_at`)."""
    params = np.zeros((2, 3))
    rows, cols = np.nonzero(weight > 0)
    reference = np.ascontiguousarray(reference, dtype=np.float64)
    weight = np.ascontiguousarray(weight, dtype=np.float64)
    normal, rhs = np.empty((6, 6)), np.empty(6)
    for _ in range(iterations):
        moved = _warp_affine(image, params)
        _normal_equations(moved, reference, weight, rows, cols, normal, rhs)
        normal += 1e-6 * np.trace(normal) / 6 * np.eye(6)
        step = np.linalg.solve(normal, rhs).reshape(2, 3)
        params += np.clip(step, -2.0, 2.0)
        if np.max(np.abs(step)) < 1e-4:
            break
    return params


@numba.njit(cache=cache_enabled(), nogil=True, error_model="numpy")
def _normal_equations(moved, reference, weight, rows, cols, normal, rhs):  # pragma: no cover
    """`normal` ``JᵀWJ`` and `rhs` ``JᵀW(reference − moved)`` of :func:`_register_affine`'s
    Gauss–Newton step over the pixels ``rows, cols``: ``J`` the moved image's gradient
    (central differences, one-sided at the image's edges) times the basis."""
    h, w = moved.shape
    normal[:] = 0.0
    rhs[:] = 0.0
    jac = np.empty(6)
    for k in range(rows.size):
        r, c = rows[k], cols[k]
        if r == 0:
            gy = moved[1, c] - moved[0, c]
        elif r == h - 1:
            gy = moved[h - 1, c] - moved[h - 2, c]
        else:
            gy = 0.5 * (moved[r + 1, c] - moved[r - 1, c])
        if c == 0:
            gx = moved[r, 1] - moved[r, 0]
        elif c == w - 1:
            gx = moved[r, w - 1] - moved[r, w - 2]
        else:
            gx = 0.5 * (moved[r, c + 1] - moved[r, c - 1])
        xh, yh = _basis_xy(r, c, h, w)
        jac[0], jac[1], jac[2] = gy, gy * xh, gy * yh
        jac[3], jac[4], jac[5] = gx, gx * xh, gx * yh
        wk = weight[r, c]
        e = wk * (reference[r, c] - moved[r, c])
        for i in range(6):
            rhs[i] += jac[i] * e
            a = wk * jac[i]
            for j in range(i, 6):
                normal[i, j] += a * jac[j]
    for i in range(6):
        for j in range(i):
            normal[i, j] = normal[j, i]


def _fringe_free_sets(idx: list[int]) -> list[list[int]]:
    """The sets of a group's frames (`idx`, ``N`` equally spaced steps) whose mean has no
    fringe: the whole group if ``N = 3``; every pair of opposite steps ``k, k + N/2`` (the
    first harmonic and every odd one cancel) and, if 3 divides ``N``, every triple
    ``k, k + N/3, k + 2N/3`` (the first two harmonics cancel)."""
    n = len(idx)
    if n == 3:
        return [list(idx)]
    sets = [[idx[k], idx[k + n // 2]] for k in range(n // 2)]
    if n % 3 == 0:
        sets += [[idx[k], idx[k + n // 3], idx[k + 2 * n // 3]] for k in range(n // 3)]
    return sets


#: Weight of the trajectory's curvature against its fit to the images' displacements
#: (:func:`_trajectory`): small, so that the images' averages are met and the curvature only
#: fills in what they leave open
SMOOTHING = 1e-3


def _trajectory(n_frames: int, members: list[list[int]], observed: np.ndarray) -> np.ndarray:
    """Per-frame values ``(n_frames, …)`` whose averages over each image's frames (`members`)
    are `observed` ``(n_images, …)``, of least curvature (second differences) in between: the
    minimum-curvature interpolation of averages, which extrapolates linearly past the last
    image (a cubic spline through the images' mean times would not honour that an image of
    two opposite steps three frames apart is their average, not the motion at their mean
    time)."""
    design = np.zeros((len(members), n_frames))
    for row, frames in enumerate(members):
        design[row, frames] = 1.0 / len(frames)
    curvature = np.diff(np.eye(n_frames), n=2, axis=0)
    flat = observed.reshape(len(members), -1)
    normal = design.T @ design + SMOOTHING * curvature.T @ curvature
    solved = np.linalg.solve(normal, design.T @ flat)
    return solved.reshape((n_frames, *observed.shape[1:]))


#: σ of the Gaussian whose low-pass is taken out of the phase and of its error's pattern
#: (:func:`texture_phase_error`), camera px: below the ridges' and fringes' periods, so the
#: surface's smooth phase is left out of the fit and their beat is kept
TEXTURE_PHASE_SIGMA_PX = 1.5


def texture_phase_error(a: np.ndarray, c: np.ndarray, s: np.ndarray, weight: np.ndarray, *,
                        sigma_px: float = TEXTURE_PHASE_SIGMA_PX) -> tuple[np.ndarray, dict]:
    """The phase error that the skin's motion within a phase-shift group leaves through its
    texture, fitted over one camera's image.

    Within a group of ``N`` steps, a texture ``a`` displaced by ``e_k`` at step ``k`` adds
    ``∇a · e_k`` to that frame. The part of ``e_k`` along the steps' first harmonic,
    ``E_c cos δ_k + E_s sin δ_k``, is what a per-pixel fit takes for fringe: ``C`` gains
    ``∇a · E_c``, ``S`` loses ``∇a · E_s``, and the phase errs by

        ``Δφ = −[(∇a · E_c) sin φ + (∇a · E_s) cos φ] / B``.

    It is also the part of the motion that the fringe-free texture images cannot see (a mean
    of opposite steps, or of a step triple, cancels it along with the fringe), so the
    stabiliser's trajectory only interpolates it. With ``E_c, E_s`` affine over the image (as
    the frames' motion is, :func:`stabilise_frames`), ``Δφ`` is linear in their twelve
    coefficients, and its pattern (the texture's gradient beating with the fringe) is unlike
    the surface's smooth phase and unlike the relief, whose ridges are in phase with the
    texture (the print reads them; they are kept): the coefficients are fitted by least
    squares to the phase's high-pass.

    Parameters
    ----------
    a, c, s : (H, W) float
        A group's per-pixel fit ``a + C cos δ − S sin δ``
        (:func:`~nail2nail.scan.motion.fit_pixel_shifts`).
    weight : (H, W) float
        Pixels that take part (> 0): lit skin, away from the silhouette.
    sigma_px : float
        The high-pass's Gaussian σ, px.

    Returns
    -------
    error : (H, W) float64
        ``Δφ``, rad (0 where `weight` is 0); the phase is ``atan2(S, C) − error``.
    figures : dict
        ``"rms_rad"`` (of the error over the pixels that took part) and ``"explained"`` (the
        fraction of the high-passed phase's variance it accounts for).

    Notes
    -----
    Beyond the thesis (a still finger). The error of motion-induced texture changes in phase
    shifting: Lu, Yin, Zhang and Wang, Opt. Lasers Eng. 141, 106573 (2021).
    """
    sel = weight > 0
    error = np.zeros(a.shape)
    if sel.sum() < 1000:
        return error, {"rms_rad": 0.0, "explained": 0.0}
    b = np.maximum(np.hypot(c, s), 1e-9)
    sin_phi, cos_phi = s / b, c / b
    grad = np.gradient(ndi.gaussian_filter(a, 0.7))  # the texture's, not its noise's
    basis = _affine_basis(a.shape)
    patterns = np.stack([g * trig / b * q for g in grad for trig in (sin_phi, cos_phi)
                         for q in basis])  # (12, H, W)

    def high_pass(image):
        return image - ndi.gaussian_filter(image, sigma_px)

    z = cos_phi + 1j * sin_phi
    smooth = ndi.gaussian_filter(z.real, sigma_px) + 1j * ndi.gaussian_filter(z.imag, sigma_px)
    target = np.angle(z * np.conj(smooth))[sel]
    design = np.stack([high_pass(p)[sel] for p in patterns], axis=1)
    fit = np.abs(target) < 1.0  # a fringe's or an edge's jump is not this small error
    coef, *_ = np.linalg.lstsq(design[fit], target[fit], rcond=None)
    error[sel] = np.tensordot(coef, patterns[:, sel], axes=1)
    explained = 1.0 - np.var(target[fit] - design[fit] @ coef) / max(np.var(target[fit]),
                                                                      1e-30)
    return error, {"rms_rad": round(float(np.sqrt(np.mean(error[sel] ** 2))), 4),
                   "explained": round(float(explained), 4)}


def _motion_jacobian(xyz: np.ndarray, matrix: np.ndarray, center: np.ndarray) -> np.ndarray:
    """``(P, 2, 6)``: the image motion ``(d row, d col)`` of points `xyz` ``(P, 3)`` (mm) seen
    through the 3 × 4 projection `matrix` (eq. 3.1–3.2) per small rigid motion ``(ω, t)`` about
    `center`: ``X → X + ω × (X − c) + t``."""
    m = np.asarray(matrix, dtype=np.float64)
    h = xyz @ m[:, :3].T + m[:, 3]
    col, row = h[:, 0] / h[:, 2], h[:, 1] / h[:, 2]
    d_col = (m[0, :3] - col[:, None] * m[2, :3]) / h[:, 2:3]  # (P, 3)
    d_row = (m[1, :3] - row[:, None] * m[2, :3]) / h[:, 2:3]
    a = xyz - center
    # ω × a = −[a]× ω: the rows of [a]× with the sign turned
    turn = np.stack([np.stack([np.zeros(len(a)), a[:, 2], -a[:, 1]], -1),
                     np.stack([-a[:, 2], np.zeros(len(a)), a[:, 0]], -1),
                     np.stack([a[:, 1], -a[:, 0], np.zeros(len(a))], -1)], axis=1)  # (P, 3, 3)
    motion = np.concatenate([turn, np.broadcast_to(np.eye(3), turn.shape)], axis=2)  # (P, 3, 6)
    return np.stack([np.einsum("pi,pij->pj", d_row, motion),
                     np.einsum("pi,pij->pj", d_col, motion)], axis=1)


def rigid_motion(views, center) -> np.ndarray:
    """The finger's small rigid motion per frame from cameras whose image motion is known.

    A rigid finger moves every camera's image alike: each camera's per-frame affine maps
    (:func:`stabilise_frames`'s ``info["frames_affine"]``) at its scan's points are the image
    motion of one 3D motion ``X → X + ω × (X − c) + t`` per frame (small, linearised), solved
    for by least squares over every camera given. Two cameras 45° apart fix all six numbers;
    one alone leaves its viewing direction weak (a little ridge damping keeps it bounded).

    Parameters
    ----------
    views : sequence of (maps, xyz, rows, cols, matrix, shape)
        Per camera: its ``(n_frames, 2, 3)`` affine maps, ``(P, 3)`` points (mm, world frame,
        at the reference time) seen at pixels ``rows, cols`` ``(P,)`` (row and column
        indices), its 3 × 4 projection `matrix` (world mm to pixels) and its image's
        ``(H, W)`` (the maps' coordinates, :func:`stabilise_frames`).
    center : (3,) array
        The rotation's centre, mm (the points' mean is a good one).

    Returns
    -------
    (n_frames, 6) float64
        ``ω`` (rad) and ``t`` (mm) per frame.

    Notes
    -----
    Beyond the thesis (a still finger). A point's image motion is the derivative of the DLT
    projection (thesis eq. 3.1–3.2, ``u = (m₁·X̃)/(m₃·X̃)``, ``v = (m₂·X̃)/(m₃·X̃)``):
    ``∂u/∂X = (m₁ − u m₃)/(m₃·X̃)`` (lens distortion left out: it bends the motion by less
    than the fit's noise), times the small rigid motion's ``∂X = −[X − c]× ω + t``.
    """
    center = np.asarray(center, dtype=np.float64)
    jac, obs = [], []
    for maps, xyz, rows, cols, matrix, shape in views:
        b = _affine_basis_at(rows, cols, shape)  # (3, P)
        d = np.einsum("kjb,bp->kpj", np.asarray(maps, float), b)  # (n_frames, P, 2)
        jac.append(_motion_jacobian(np.asarray(xyz, float), matrix, center).reshape(-1, 6))
        obs.append(d.reshape(len(d), -1))
    g = np.concatenate(jac)
    normal = g.T @ g
    normal += 1e-6 * np.trace(normal) / 6 * np.eye(6)
    return np.linalg.solve(normal, g.T @ np.concatenate(obs, axis=1).T).T


def affine_image_motion(rigid: np.ndarray, xyz: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                        matrix: np.ndarray, shape, center) -> np.ndarray:
    """One camera's per-frame affine maps of a rigid motion: what its frames would have
    measured of it.

    Parameters
    ----------
    rigid : (n_frames, 6) array
        ``ω`` (rad) and ``t`` (mm) per frame (:func:`rigid_motion`).
    xyz : (P, 3) array
        The camera's points, mm, world frame (its scan's, stabilised or not: they only place
        the image motion).
    rows, cols : (P,) array
        Their pixels (row and column indices).
    matrix : (3, 4) array
        The camera's projection, world mm to pixels (eq. 3.1–3.2).
    shape : (int, int)
        The image's ``(H, W)``.
    center : (3,) array
        The rotation's centre, mm, as given to :func:`rigid_motion`.

    Returns
    -------
    (n_frames, 2, 3) float64
        Per frame the least-squares affine map ``(dy, dx) = P · (1, x̂, ŷ)`` of the points'
        image motion, px (:func:`stabilise_frames`'s `motion` and ``info["frames_affine"]``).
    """
    d = np.einsum("pjs,ks->kpj", _motion_jacobian(np.asarray(xyz, float), matrix,
                                                  np.asarray(center, float)), rigid)
    b = _affine_basis_at(rows, cols, shape).T  # (P, 3)
    coef, *_ = np.linalg.lstsq(b, d.transpose(1, 0, 2).reshape(len(rows), -1), rcond=None)
    return coef.reshape(3, len(rigid), 2).transpose(1, 2, 0)


def _texture_motion(textures, fits, reference, table, weight, basis, n_frames: int,
                    info: dict) -> np.ndarray | None:
    """Steps 2–3 of :func:`stabilise_frames`: every texture image's affine motion against one
    anchor, then every frame's (``(n_frames, 2, 3)``); None (and ``info["skipped"]``) when the
    texture does not register."""
    # every image is registered to one anchor, then the reference group's mean is made 0. The
    # anchor is a 3-step group's mean, whose fringes are coarse: an opposite-step pair of a
    # fine group keeps a little of its fringe where the finger moved between the two steps,
    # and two pairs of one group (or an average holding the image itself) would pull each
    # other's displacement across the fringes towards their own
    in_reference = [i for i, (_, _, label, _) in enumerate(textures) if label == reference]
    t_ref = float(np.mean([textures[i][0] for i in in_reference]))
    direction = info["direction"]
    candidates = ([i for i, (_, _, label, _) in enumerate(textures) if len(fits[label][0]) == 3]
                  or [i for i, (_, _, label, _) in enumerate(textures)
                      if table[fits[label][0][0]].direction != direction]
                  or in_reference)
    anchor = textures[min(candidates, key=lambda i: abs(textures[i][0] - t_ref))][1]
    times = np.array([t for t, _, _, _ in textures])
    params = np.stack([_register_affine(image, anchor, weight)
                       for _, image, _, _ in textures])  # (n_images, 2, 3)
    # how well each image matches the anchor once moved: skin without ridges (or noise
    # alone) gives a "motion" that is anywhere, and no image is resampled with it
    sel = weight > 0
    correlation = []
    for (_, image, _, _), p in zip(textures, params, strict=True):
        moved = _warp_affine(image, p)[sel]
        correlation.append(float(np.dot(moved, anchor[sel]) / max(
            np.linalg.norm(moved) * np.linalg.norm(anchor[sel]), 1e-12)))
    info["correlation"] = [round(c, 3) for c in correlation]
    if min(correlation) < MIN_TEXTURE_CORRELATION:
        info["skipped"] = (f"the skin's texture does not register (correlation "
                           f"{min(correlation):.2f} < {MIN_TEXTURE_CORRELATION})")
        return None
    params -= params[in_reference].mean(axis=0)

    # 3. every frame's motion: the smoothest trajectory whose averages are the images'
    info["samples"] = [{"time": round(float(t), 2),
                        "mean_px": [round(float(v), 3)
                                    for v in p @ basis[:, sel].mean(axis=1)]}
                       for t, p in zip(times, params, strict=True)]
    return _trajectory(n_frames, [members for _, _, _, members in textures], params)


def stabilise_frames(frames, pattern_set: PatternSet, *, saturation: float | None = None,
                     direction: str | None = None,
                     motion: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    """Frames of a moving finger resampled so that every pixel shows one point of skin.

    Parameters
    ----------
    frames : (n_frames, H, W) array
        One camera's frames (integer values or floats), in the order shown; not modified.
    pattern_set : PatternSet
        A PMP pattern set whose phase-shift groups have 3 steps or an even number ≥ 4 (other
        sets, and sets without such a group, are returned as they are).
    saturation : float, optional
        Frame value at or above which a pixel counts as unlit (it takes no part in the
        registration; a pixel whose skin is there in any frame is left dark).
    direction : {"x", "y"}, optional
        The direction whose phase the points will be triangulated from: the reference group
        is that direction's finest (its last in time if several); by default the last group
        with the most fringe periods, whatever its direction.
    motion : (n_frames, 2, 3) array, optional
        Every frame's affine map (``info["frames_affine"]``'s convention), when known from
        elsewhere (the other cameras' motion, :func:`rigid_motion` and
        :func:`affine_image_motion`): the frames are resampled with it and their own texture
        is not registered (``info["correlation"]`` is empty).

    Returns
    -------
    frames : (n_frames, H, W) array of the input's dtype
        Resampled at the skin's position at the reference group's mean time, each group
        re-synthesised with its nominal shifts; 0 at pixels whose skin is outside the lit,
        unsaturated pixels (every group's fringe amplitude and mean at least 2 % of the
        frames' largest value) or the image in any frame.
    info : dict
        ``"reference"`` (the group's label), ``"direction"`` (its direction: triangulate from
        that direction's phase), ``"correlation"``: per texture image its normalised
        correlation with the anchor once registered, ``"samples"``: per texture image its time
        (frame index) and mean displacement ``(dy, dx)`` px over the valid pixels;
        ``"frames_px"``: per frame the mean displacement; ``"spread_px"``: the largest
        distance between two frames' mean displacements; ``"texture_phase"``: per group with
        the most fringe periods, the phase error taken out (:func:`texture_phase_error`'s
        figures); ``"skipped"`` (only when the frames
        are returned as they are because the texture does not register: why). The reference
        is None, and the frames returned as they are, for pattern sets it cannot stabilise.

    Notes
    -----
    The thesis decodes a still finger (PMP, its chapter two; the fit here is that model with
    per-pixel shifts, :func:`~nail2nail.scan.motion.fit_pixel_shifts`); the stabilisation is
    beyond it (module docstring, references).
    """
    frames = np.asarray(frames)
    info: dict = {"reference": None, "direction": None, "samples": [], "frames_px": [],
                  "spread_px": 0.0}
    groups = _phase_groups(pattern_set) if pattern_set.scheme == "pmp" else []
    if not groups or any(len(idx) != 3 and (len(idx) < 4 or len(idx) % 2) for _, idx in groups):
        return frames.copy(), info
    table = frame_table(pattern_set)
    n_frames, height, width = frames.shape
    values = frames.astype(np.float64)
    full = float(values.max()) if values.size else 1.0
    band = STABILISE_BAND_PX

    # 1. each group's fit, its valid pixels and texture images
    fits, textures = {}, []  # textures: (time, image, group label, frames averaged)
    valid_all = np.ones((height, width), bool)
    for label, idx in groups:
        nominal = np.array([table[i].shift for i in idx])[:, None, None]
        a, c, s = fit_pixel_shifts(values[idx], nominal)
        valid = (np.hypot(c, s) >= 0.02 * full) & (a >= 0.02 * full)
        if saturation is not None:
            valid &= (values[idx] < saturation).all(axis=0)
        valid_all &= valid
        fits[label] = (idx, nominal, c, s, valid)
        notch = _notch((height, width), _fringe_frequency(c, valid))

        def clean(image, notch=notch):
            return np.real(np.fft.ifft2(np.fft.fft2(_band(image, band)) * notch))

        for members in _fringe_free_sets(idx):
            textures.append((float(np.mean(members)), clean(values[members].mean(axis=0)),
                             label, members))
    weight = ndi.binary_erosion(valid_all, iterations=8).astype(np.float64)
    if weight.sum() < 1000:
        return frames.copy(), info
    reference, info["direction"] = _reference_group(pattern_set, direction)
    most = max(table[idx[0]].periods for _, idx in groups)
    info["reference"] = reference

    # 2-3. every frame's affine motion, from the skin's texture unless given
    basis = _affine_basis((height, width))
    sel = weight > 0
    if motion is None:
        per_frame = _texture_motion(textures, fits, reference, table, weight, basis, n_frames,
                                    info)
        if per_frame is None:
            return frames.copy(), info
    else:
        per_frame = np.asarray(motion, dtype=np.float64)
        if per_frame.shape != (n_frames, 2, 3):
            raise ValueError(f"motion: expected ({n_frames}, 2, 3) affine maps, got "
                             f"{per_frame.shape}")
        info["correlation"] = []
    mean_d = np.einsum("kjb,b->kj", per_frame, basis[:, sel].mean(axis=1))  # (n_frames, 2)
    info["frames_px"] = [[round(float(v), 3) for v in row] for row in mean_d]
    info["frames_affine"] = np.round(per_frame, 5).tolist()
    info["spread_px"] = round(float(np.max(np.linalg.norm(
        mean_d[:, None] - mean_d[None], axis=-1))), 3)

    # 4. resample, fit each group with the resampling's fringe shift, re-synthesise; a pixel
    # whose skin lies outside the lit, unsaturated pixels in any frame (the moving silhouette,
    # the image's border) is left dark: the decoder drops it rather than read a mixture
    out = values.copy()
    inside = np.ones((height, width), bool)
    lit = valid_all.astype(np.float64)
    for k in range(n_frames):
        d = np.einsum("jb,bhw->jhw", per_frame[k], basis)
        rows_k = np.arange(height)[:, None] + d[0]
        cols_k = np.arange(width)[None, :] + d[1]
        inside &= (rows_k >= 0) & (rows_k <= height - 1) & (cols_k >= 0) & (cols_k <= width - 1)
        inside &= _warp_affine(lit, per_frame[k]) >= 1.0 - 1e-9
    info["texture_phase"] = {}
    for label, (idx, nominal, c, s, _) in fits.items():
        d = np.einsum("kjb,bhw->kjhw", per_frame[idx], basis)  # (N, 2, H, W)
        moved = np.stack([_warp_affine(values[k], per_frame[k]) for k in idx])
        gy, gx = phase_gradient(c, s)
        dev = d - d.mean(axis=0, keepdims=True)
        a2, c2, s2 = fit_pixel_shifts(moved, nominal + gy * dev[:, 0] + gx * dev[:, 1])
        if table[idx[0]].periods == most:  # the geometry's phase: what the texture left
            error, info["texture_phase"][label] = texture_phase_error(
                a2, c2, s2, weight * inside)
            turned = (c2 + 1j * s2) * np.exp(-1j * error)
            c2, s2 = turned.real, turned.imag
        synthetic = a2 + c2 * np.cos(nominal) - s2 * np.sin(nominal)
        out[idx] = np.where(inside, synthetic, 0.0)
    if np.issubdtype(frames.dtype, np.integer):
        out = np.clip(np.rint(out), 0, np.iinfo(frames.dtype).max)
    return out.astype(frames.dtype), info
