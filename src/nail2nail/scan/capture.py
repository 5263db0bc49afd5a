"""From a capture to 3D scans: decode each camera's frames and reconstruct its points.

This is the glue of the pipeline's first three stages (capture → decode → reconstruct); the
work itself is done by :mod:`nail2nail.scan.decoding` and :mod:`nail2nail.scan.triangulation`. A
scan runs
the fused numba kernel (:func:`nail2nail.scan.kernels.decode_fast` with a
:func:`~nail2nail.scan.triangulation.ray_table`: decoding, neighbourhood checks and float64
triangulation in one pass over the integer frames) for every option; ``method="numpy"`` runs
the reference instead (:func:`nail2nail.scan.decoding.decode` and
:func:`~nail2nail.scan.triangulation.reconstruct_image`, in bands of rows). The two agree within
float32 rounding (``tests/test_scan_kernels.py``).
"""

from __future__ import annotations

import os
import warnings

import numpy as np

from nail2nail._progress import progress_bar
from nail2nail._timing import StepClock
from nail2nail.calibration.camera_models import Pinhole, projection_matrix
from nail2nail.calibration.distortion import ProjectorDistortion
from nail2nail.calibration.files import CameraCalibration, RigCalibration, check_handedness
from nail2nail.io.masks import check_mask_names, read_mask
from nail2nail.scan.decoding import decode
from nail2nail.scan.inputs import (
    SATURATION,
    _check_erode,
    _check_frames,
    frame_intensities,
)
from nail2nail.scan.kernels import decode_fast
from nail2nail.scan.motion import (
    MOTION_WARN_MM,
    compensate_phase_steps,
    estimate_motion,
    mm_per_pixel,
)
from nail2nail.scan.patterns import fringe_periods
from nail2nail.scan.results import (
    NO_POINT,
    Scan,
)
from nail2nail.scan.stabilise import (
    affine_image_motion,
    reference_direction,
    rigid_motion,
    stabilise_frames,
)
from nail2nail.scan.triangulation import (
    _check_use,
    _reconstruct_into,
    band_rows,
    model_matrix,
    one_coordinate_conditioning,
    ray_table,
    reconstruct_points_one_coordinate,
)

__all__ = [
    "BAND_PIXELS",
    "MAX_GRADIENT",
    "MIN_KEPT_FRACTION",
    "MIN_PLANE_ANGLE_DEG",
    "REFERENCE_PIXELS",
    "camera_center",
    "decode_camera",
    "decode_cameras",
    "gradient_limit",
    "kept_fraction",
    "motion_summary",
    "scan_capture",
    "scan_frames",
]


#: Pixels per band of rows that the NumPy reference of :func:`scan_frames` (``method="numpy"``)
#: decodes and triangulates at a time (the fused kernel needs no bands).
BAND_PIXELS = 1 << 18


_METHODS = ("numba", "numpy")


#: Camera size (pixels) at which ``max_gradient`` is stated: the thesis's 1024 × 1280 cameras.
REFERENCE_PIXELS = 1024 * 1280


#: Default ``max_gradient`` of :func:`scan_capture`, panel px per camera px at the
#: :data:`REFERENCE_PIXELS` size (scaled by :func:`gradient_limit`).
MAX_GRADIENT = 2.0

#: A camera whose valid points cover less than this fraction of its lit pixels gets a warning.
MIN_KEPT_FRACTION = 0.2


def gradient_limit(max_gradient: float | None, shape) -> float | None:
    """The steep-pixel limit in projector px per camera px for camera images of `shape`.

    `max_gradient` is stated for a camera of :data:`REFERENCE_PIXELS` (1024 × 1280): a camera
    with ``s`` times the linear resolution sees every gradient ``1/s`` times as large at the
    same viewing obliquity, so the limit is ``max_gradient · sqrt(1024 · 1280 / (W · H))``.
    The pixels kept then depend on the viewing obliquity, not on the resolution.

    Examples
    --------
    >>> gradient_limit(2.0, (320, 256))
    8.0
    >>> gradient_limit(None, (320, 256)) is None
    True
    """
    if max_gradient is None:
        return None
    height, width = shape[-2:]
    return float(max_gradient) * float(np.sqrt(REFERENCE_PIXELS / (height * width)))


def kept_fraction(scan, min_modulation: float = 0.03) -> tuple[int, int]:
    """``(valid points, lit pixels)`` of a scan; lit: finest fringe amplitude ≥ `min_modulation`."""
    modulation = np.asarray(scan.modulation)
    lit = np.isfinite(modulation) & (modulation >= min_modulation)
    return int(np.count_nonzero(scan.mask)), int(np.count_nonzero(lit))


def camera_center(model) -> np.ndarray:
    """Optical centre (3,) in world mm of a DLT matrix or pinhole model (null space of M)."""
    M = model_matrix(model)
    return -np.linalg.solve(M[:, :3], M[:, 3])


def scan_frames(
    frames,
    pattern_set,
    camera: CameraCalibration,
    *,
    projector_distortion: ProjectorDistortion | dict | None = None,
    use: str = "xpyp",
    method: str = "numba",
    **decode_options,
) -> Scan:
    """One camera's scan from its frames.

    ``method="numba"`` decodes, checks and triangulates in one pass of the fused kernel
    (:func:`nail2nail.scan.kernels.decode_fast` with
    :func:`~nail2nail.scan.triangulation.ray_table`): the
    frames are read as they are (no float copy), and the only other full-size arrays are the
    outputs. ``method="numpy"``, the reference, decodes (:func:`nail2nail.scan.decoding.decode`) and
    triangulates (:func:`~nail2nail.scan.triangulation.reconstruct_image`) in bands of rows of
    about :data:`BAND_PIXELS` pixels, each with the rows around it that the neighbourhood
    checks read (``erode`` rows, one for ``max_gradient``): the result is the one of the whole
    image, with the temporaries of a band in memory. The two agree within float32 rounding
    (``tests/test_scan_kernels.py``): the mask but for pixels within rounding of a threshold,
    ``xp``, ``yp`` within 1e-4 px (one float32 step, 1.2e-4 px, beyond 1024 px), ``xyz`` within
    1e-4 mm of the reference triangulation of the same coordinates (with ``use="xp"`` and
    column planes that nearly contain the camera rays, the one-step difference of ``xp`` moves
    a point by up to 0.02 mm, as float32 rounding moves the reference's own points).

    Parameters
    ----------
    frames : (n_frames, H, W) uint8/uint16/float
        The camera's capture, in the pattern set's frame order.
    pattern_set : PatternSet
        What the projector showed.
    camera : CameraCalibration
        The camera's model and the projector model calibrated with it.
    projector_distortion : ProjectorDistortion or dict, optional
        Projector radial distortion to compensate in the model (``{"center", "rho"}``); leave
        out when the patterns were pre-distorted.
    use : {"xpyp", "yp", "xp"}
        Projector coordinates used for triangulation
        (:func:`~nail2nail.scan.triangulation.reconstruct_image`). A pattern set of one direction
        takes ``use`` of that direction; with a projector distortion model or lens distortion
        its points are solved on the camera ray
        (:func:`~nail2nail.scan.triangulation.reconstruct_points_one_coordinate`), by both methods.
    method : {"numba", "numpy"}
        The fused kernel, or the NumPy reference. The kernel decodes PMP only: the Gray-code
        schemes (:mod:`nail2nail.scan.gray`) are scanned by the NumPy reference either way.
    **decode_options
        Passed to :func:`nail2nail.scan.decoding.decode` (``min_modulation``, ``cue_modulation``,
        ``min_albedo``, ``saturation``, ``unwrap_tolerance``, ``erode``, ``max_gradient``).

    Returns
    -------
    Scan
        float32 images; ``xyz``, ``xp``, ``yp`` NaN, ``intensity`` 0 and ``mask`` False where
        decoding or triangulation failed.

    Raises
    ------
    ValueError
        Naming the camera: one projector direction with ``use="xpyp"`` or a `use` of the other
        direction, or no valid pixel; an unknown `use` or `method`, a bad decode option.
    """
    frames = _check_frames(frames, pattern_set)
    return _scan(frames, pattern_set, camera, projector_distortion=projector_distortion, use=use,
                 method=method, decode_options=decode_options)


def _check_method(method) -> str:
    if method not in _METHODS:
        raise ValueError(f"method: expected 'numba' or 'numpy', got {method!r}")
    return method


def _scan(frames, pattern_set, camera: CameraCalibration, *, projector_distortion, use, method,
          decode_options, bit_depth: int | None = None) -> Scan:
    """:func:`scan_frames` of checked frames; integer values of `bit_depth` bits if given
    (``raw=True``), else frames of their dtype's full scale."""
    _check_method(method)
    _check_use(use)
    if method == "numba" and pattern_set.scheme == "pmp":  # the kernel decodes PMP only
        return _scan_fast(frames, pattern_set, camera, projector_distortion=projector_distortion,
                          use=use, decode_options=decode_options,
                          full_scale=None if bit_depth is None else 2**bit_depth - 1)
    if bit_depth is None:
        band = lambda a, b: frames[:, a:b]  # noqa: E731
    else:  # made float band by band
        band = lambda a, b: frame_intensities(frames[:, a:b], bit_depth)  # noqa: E731
    return _scan_bands(band, frames.shape[1:], pattern_set, camera,
                       projector_distortion=projector_distortion, use=use,
                       decode_options=decode_options)


def _check_directions(pattern_set, camera: CameraCalibration, use, projector_distortion):
    """Refuse a pattern set with one projector direction where triangulation needs both
    (``use="xpyp"``) or lacks the one asked for."""
    if "x" in pattern_set.directions and "y" in pattern_set.directions:
        return
    if use == "xpyp":
        raise ValueError(
            f"camera {camera.name!r}: the pattern set has one projector direction "
            f"({pattern_set.directions[0]!r}), but use='xpyp' needs both (every point would "
            f"be lost); use '{pattern_set.directions[0]}p'")
    if use[0] not in pattern_set.directions:
        raise ValueError(
            f"camera {camera.name!r}: use={use!r}, but the pattern set decodes only "
            f"{pattern_set.directions[0]!r}; use '{pattern_set.directions[0]}p'")


def _one_coordinate(pattern_set, camera: CameraCalibration, use, projector_distortion) -> bool:
    """Whether points come from one decoded coordinate of a distorted projector (radial model
    or lens): :func:`~nail2nail.scan.triangulation.reconstruct_points_one_coordinate`, an iterative
    solve on the camera ray, instead of the ray table (which needs both coordinates then)."""
    if use == "xpyp" or ("x" in pattern_set.directions and "y" in pattern_set.directions):
        return False
    lens = isinstance(camera.projector, Pinhole) and np.any(camera.projector.dist != 0)
    return projector_distortion is not None or bool(lens)


def _points_one_coordinate(camera: CameraCalibration, p, valid, row0: int, *,
                           projector_distortion, use) -> np.ndarray:
    """Points ``(h, W, 3)`` float64 of rows ``row0 …`` from one coordinate `p` ``(h, W)`` at the
    `valid` pixels (NaN elsewhere)."""
    out = np.full((*p.shape, 3), np.nan)
    rows, cols = np.nonzero(valid)
    out[rows, cols] = reconstruct_points_one_coordinate(
        camera.camera, camera.projector, cols.astype(float), (rows + row0).astype(float),
        np.asarray(p, float)[rows, cols], axis=use[0],
        projector_distortion=projector_distortion)
    return out


def _no_valid_pixel(camera: CameraCalibration, min_modulation, lit: int, decoded_valid: int):
    """The error of a scan that keeps no pixel, with the reason."""
    why = (f"no pixel has a fringe amplitude ≥ min_modulation {min_modulation:g}"
           if lit == 0 else
           f"none of its {lit} lit pixels decoded validly" if decoded_valid == 0 else
           f"triangulation failed at all {decoded_valid} decoded pixels")
    return ValueError(f"camera {camera.name!r}: the scan keeps 0 valid pixels ({why})")


def _scan_fast(frames, pattern_set, camera: CameraCalibration, *, projector_distortion, use,
               decode_options, full_scale) -> Scan:
    """:func:`scan_frames` by the fused kernel: one pass, outputs and frames in memory."""
    _check_directions(pattern_set, camera, use, projector_distortion)
    options = dict(decode_options)
    options.pop("keep_invalid", None)  # a scan's xp, yp are NaN where invalid regardless
    height, width = frames.shape[1:]
    if _one_coordinate(pattern_set, camera, use, projector_distortion):
        decoded = decode_fast(frames, pattern_set, full_scale=full_scale, **options)
        p = decoded.xp if use == "xp" else decoded.yp
        assert p is not None  # _check_directions: the pattern set decodes `use`
        points = _points_one_coordinate(camera, p, decoded.mask, 0,
                                        projector_distortion=projector_distortion, use=use)
        lost = decoded.mask & ~np.all(np.isfinite(points), axis=-1)
        decoded.reason[lost] |= NO_POINT
        decoded.mask &= ~lost
        p[lost] = np.nan
        decoded.intensity[lost] = 0
        decoded.xyz = points.astype(np.float32)
    else:
        table = ray_table(camera.camera, camera.projector, (height, width),
                          projector_distortion=projector_distortion, use=use)
        decoded = decode_fast(frames, pattern_set, table=table, full_scale=full_scale, **options)
    if not decoded.mask.any():
        min_modulation = options.get("min_modulation", 0.03)
        lit = int(np.count_nonzero(decoded.modulation >= min_modulation))
        decoded_valid = int(np.count_nonzero((decoded.reason & ~np.uint8(NO_POINT)) == 0))
        raise _no_valid_pixel(camera, min_modulation, lit, decoded_valid)
    assert decoded.xyz is not None  # triangulated above or by the kernel
    return Scan(
        name=camera.name,
        xyz=decoded.xyz,
        xp=decoded.xp if decoded.xp is not None else np.full((height, width), np.nan, np.float32),
        yp=decoded.yp if decoded.yp is not None else np.full((height, width), np.nan, np.float32),
        albedo=decoded.albedo,
        intensity=decoded.intensity,
        modulation=decoded.modulation,
        mask=decoded.mask,
        camera_center=camera_center(camera.camera),
        projector_center=camera_center(camera.projector),
        reason=decoded.reason,
        triangulated_from=use,
    )


def _halo(decode_options: dict) -> int:
    """Rows beyond a band that the decoder's neighbourhood checks read (bad options: 0, and
    :func:`~nail2nail.scan.decoding.decode` raises)."""
    erode = decode_options.get("erode", 1)
    halo = (int(erode) if isinstance(erode, (int, np.integer)) and not isinstance(erode, bool)
            and erode > 0 else 0)
    if decode_options.get("max_gradient") is not None:
        halo = max(halo, 1)
    return halo


def _scan_bands(band_frames, shape, pattern_set, camera: CameraCalibration, *,
                projector_distortion, use, decode_options) -> Scan:
    """The NumPy reference of :func:`scan_frames`, ``band_frames(a, b)`` giving the frames of
    rows ``a … b - 1``."""
    height, width = shape
    halo = _halo(decode_options)
    step = band_rows(width, BAND_PIXELS)
    f32 = np.float32
    xyz = np.empty((height, width, 3), f32)
    xp_out, yp_out, albedo, intensity, modulation = (np.empty((height, width), f32)
                                                     for _ in range(5))
    mask = np.empty((height, width), bool)
    reason = np.empty((height, width), np.uint8)
    min_modulation = decode_options.get("min_modulation", 0.03)
    lit = decoded_valid = 0
    one_coordinate = _one_coordinate(pattern_set, camera, use, projector_distortion)
    for a in range(0, height, step):
        b = min(a + step, height)
        lo, hi = max(a - halo, 0), min(b + halo, height)
        decoded = decode(band_frames(lo, hi), pattern_set, **decode_options)
        if a == 0:
            _check_directions(pattern_set, camera, use, projector_distortion)
        rows = slice(a - lo, b - lo)
        nan = np.full((b - a, width), np.nan, f32)
        xp = decoded.xp[rows] if decoded.xp is not None else nan
        yp = decoded.yp[rows] if decoded.yp is not None else nan
        band_mask = decoded.mask[rows]
        if one_coordinate:
            points = _points_one_coordinate(camera, xp if use == "xp" else yp, band_mask, a,
                                            projector_distortion=projector_distortion, use=use)
        else:
            points = _reconstruct_into(camera.camera, camera.projector, xp, yp,
                                       np.empty((b - a, width, 3)), row0=a,
                                       projector_distortion=projector_distortion, use=use)
        lit += int(np.count_nonzero(decoded.modulation[rows] >= min_modulation))
        decoded_valid += int(np.count_nonzero(band_mask))
        lost = band_mask & ~np.all(np.isfinite(points), axis=-1)
        band_mask = band_mask & ~lost
        reason[a:b] = decoded.reason[rows] | np.where(lost, np.uint8(NO_POINT), np.uint8(0))
        points[~band_mask] = np.nan
        xyz[a:b] = points
        xp_out[a:b] = np.where(band_mask, xp, np.nan)
        yp_out[a:b] = np.where(band_mask, yp, np.nan)
        albedo[a:b] = decoded.albedo[rows]
        intensity[a:b] = np.where(band_mask, decoded.intensity[rows], 0)
        modulation[a:b] = decoded.modulation[rows]
        mask[a:b] = band_mask
        del decoded, points
    if not mask.any():
        raise _no_valid_pixel(camera, min_modulation, lit, decoded_valid)
    return Scan(
        name=camera.name,
        xyz=xyz,
        xp=xp_out,
        yp=yp_out,
        albedo=albedo,
        intensity=intensity,
        modulation=modulation,
        mask=mask,
        camera_center=camera_center(camera.camera),
        projector_center=camera_center(camera.projector),
        reason=reason,
        triangulated_from=use,
    )


def scan_capture(
    capture,
    calibration: RigCalibration,
    *,
    use: str = "xpyp",
    progress: bool = False,
    max_gradient: float | None = MAX_GRADIENT,
    allow_mirrored: bool = False,
    calibration_name: str = "calibration",
    method: str = "numba",
    timings: dict | None = None,
    masks=None,
    detect_motion: bool = True,
    max_motion_mm: float | None = None,
    compensate_motion: bool = False,
    stabilise_motion: bool = False,
    **decode_options,
) -> list[Scan]:
    """Scan every camera of a capture that the calibration knows.

    Pixels where the decoded projector coordinates change faster than the gradient limit are
    dropped (``phase.STEEP``): there, at grazing view, a camera pixel spans more than 1/8 of the
    finest fringe period (16 px) and blur biases the phase; on the virtual scanner at full scale
    they held every decoding error above 1 px. `max_gradient` is stated in projector px per
    camera px of a 1024 × 1280 camera and scaled to the capture's camera size
    (:func:`gradient_limit`), so that it limits the viewing obliquity at any resolution.

    Checked first: every calibrated camera's image size (when the calibration states it)
    against the capture's, and the handedness of every camera (a mirrored one is refused
    unless `allow_mirrored`). A camera keeping 0 valid pixels is an error; one keeping less
    than :data:`MIN_KEPT_FRACTION` of its lit pixels a warning (``UserWarning``) with the figure.

    Motion: every camera's frames are checked for a finger that moved while they were shown
    (:func:`nail2nail.scan.motion.estimate_motion`, recorded as ``Scan.motion``); above
    :data:`~nail2nail.scan.motion.MOTION_WARN_MM` a warning (``UserWarning``) says by how much,
    above `max_motion_mm` the capture is refused.

    Memory: one camera's frames at a time, as their integer values (read with ``raw=True``
    and not cached, unless the capture holds them already), decoded and triangulated by the
    fused kernel straight from them (:func:`scan_frames`; with ``method="numpy"``, in bands of
    rows made float); the scans themselves take 33 bytes per pixel.

    Parameters
    ----------
    capture : Capture
        From :func:`nail2nail.io.capture.read_capture` (``load=False`` saves memory).
    calibration : RigCalibration
        Camera names must match the capture's.
    use : {"xpyp", "yp", "xp"}
        Projector coordinates used for triangulation (:func:`scan_frames`).
    progress : bool
        Show a progress bar on stderr (a terminal only: :mod:`nail2nail._progress`).
    max_gradient : float or None
        Steep-pixel limit stated for a 1024 × 1280 camera (:func:`gradient_limit`).
    allow_mirrored : bool
        Scan with mirrored cameras (:func:`nail2nail.calibration.files.check_handedness`).
    calibration_name : str
        How errors name the calibration (its file).
    method : {"numba", "numpy"}
        The fused kernel, or the NumPy reference (:func:`scan_frames`).
    timings : dict, optional
        Receives the seconds spent reading frames (``"read_frames"``: PNG decoding and the
        size checks) and decoding and triangulating them (``"decode"``), added to what it
        holds.
    masks : mapping of str to (H, W) bool array or path-like, optional
        User-given validity masks by camera name (:mod:`nail2nail.io.masks`: an image file is
        read, non-zero = keep): pixels outside a camera's mask are dropped from its scan after
        decoding (the decoder's edge check does not erode from the mask's border). Cameras
        without a mask keep every pixel the decoder accepts.
    detect_motion : bool
        Measure the motion the frames show (``Scan.motion``).
    max_motion_mm : float, optional
        Refuse a capture whose measured motion (the largest of its cameras') is above this,
        mm; None: warn only.
    compensate_motion : bool
        Correct the phase offsets that motion puts between the steps of each phase-shift
        group of 4 or more steps, and register the coarser frequencies to the finest, before
        decoding (:func:`nail2nail.scan.motion.compensate_phase_steps`; recorded in
        ``Scan.motion["compensation"]``). The motion check reads the frames as captured.
    stabilise_motion : bool
        First resample every frame so that each pixel shows one point of skin, at the time of
        the reference group (the last with the most fringe periods), from the skin's texture
        (:func:`nail2nail.scan.stabilise.stabilise_frames`; recorded in
        ``Scan.motion["stabilisation"]``), then compensate as `compensate_motion` does, and
        triangulate from the reference direction's phase alone: `use` ``"xp"`` or ``"yp"``
        chooses it (the finest group of that direction is the reference), ``"xpyp"`` gives
        way to the last finest group's (``"yp"`` for the default patterns). A
        camera whose frames are not resampled (too little texture to register) is triangulated
        with `use` as given; ``Scan.motion["stabilisation"]["use"]`` says which.
    **decode_options
        Passed to :func:`scan_frames` (``min_modulation`` …).

    Returns
    -------
    list of Scan
        One per camera of the capture, in its order.

    Raises
    ------
    ValueError
        Naming the calibration, capture and camera: sizes that differ, a mirrored camera, a
        camera with no valid pixel; an unknown `use` or `method`; a mask of another size or
        for an unknown camera; motion above `max_motion_mm`.
    """
    if max_motion_mm is not None and not (np.isfinite(max_motion_mm) and max_motion_mm > 0):
        raise ValueError(f"max_motion_mm: expected a positive number of mm, got {max_motion_mm!r}")
    # as given, before the per-camera scaling (gradient_limit): the user's value in the message
    if max_gradient is not None and (isinstance(max_gradient, bool) or not (
            isinstance(max_gradient, int | float | np.number) and max_gradient > 0)):
        raise ValueError(f"max_gradient: expected a positive number of projector px per camera "
                         f"px (or None), got {max_gradient!r}")
    if "erode" in decode_options:  # before any frame is read
        _check_erode(decode_options["erode"])

    _check_method(method)
    _check_use(use)
    if stabilise_motion:  # refused before any frame is read
        _require_pattern_set(capture)
        _stabilised_use(use, capture.pattern_set)
    clock = StepClock()
    clock.seconds.update(read_frames=0.0, decode=0.0)
    names = capture.camera_names
    masks = dict(masks or {})
    check_mask_names(masks, names, "masks")
    calibrated = [cam.name for cam in calibration.cameras]
    missing = [name for name in names if name not in calibrated]
    if missing:  # said here, naming both files and both lists, before any frame is read
        raise ValueError(
            f"{calibration_name}: calibrates cameras {calibrated}, but "
            f"{capture.path / 'capture.json'} has cameras {names} (none for "
            f"{', '.join(map(repr, missing))}): use a calibration of this capture's cameras")
    if not allow_mirrored:
        check_handedness(calibration, calibration_name)
    for name in names:
        cam = calibration.camera(name)
        size = capture.frame_shape(name)[::-1]  # the first frame, checked against the manifest
        if cam.size is not None and tuple(cam.size) != tuple(size):
            raise ValueError(
                f"{calibration_name}: camera {name!r} was calibrated for {cam.size[0]} x "
                f"{cam.size[1]} px images, but {capture.path} has {size[0]} x {size[1]} px "
                "frames: use a calibration made with this capture's cameras")
        if name in masks:
            masks[name] = _user_mask(masks[name], name, size[::-1])
    clock("read_frames")
    def one(name: str, motion=None) -> Scan:
        scan = _scan_camera(capture, name, calibration, use=use, max_gradient=max_gradient,
                            method=method, decode_options=decode_options, clock=clock,
                            detect_motion=detect_motion or max_motion_mm is not None,
                            compensate_motion=compensate_motion,
                            stabilise_motion=stabilise_motion, motion=motion)
        if name in masks:
            _apply_user_mask(scan, masks[name])
        used = _stabilisation(scan).get("use", use)
        if used in ("xp", "yp"):
            _warn_ill_conditioned(scan, calibration.camera(name), used)
        kept, lit = kept_fraction(scan, decode_options.get("min_modulation", 0.03))
        if lit and kept < MIN_KEPT_FRACTION * lit:
            warnings.warn(
                f"{capture.path}: camera {name!r} keeps {kept} of {lit} lit pixels "
                f"({100 * kept / lit:.1f} %, less than {100 * MIN_KEPT_FRACTION:.0f} %)",
                UserWarning, stacklevel=3)
        return scan

    scans = [one(name) for name in progress_bar(names, desc="scan", unit="camera",
                                                enabled=progress)]
    if stabilise_motion:
        # a camera whose own texture did not register takes the motion the others measured
        for k, maps, sources in _motion_from_other_cameras(scans, calibration):
            reason = _stabilisation(scans[k])["skipped"]
            scans[k] = one(names[k], motion=maps)
            _stabilisation(scans[k]).update(motion_from=sources, texture=reason)
    _check_motion(scans, capture.path, max_motion_mm)
    if timings is not None:
        for key, seconds in clock.seconds.items():
            timings[key] = timings.get(key, 0.0) + seconds
    return scans


def motion_summary(scans) -> dict | None:
    """The capture's motion from its scans' (``Scan.motion``): ``{"motion_mm", "camera",
    "moving", "threshold_mm"}`` for the camera that saw the most; None when not measured."""
    seen = [(s.motion["motion_mm"], s.name) for s in scans
            if s.motion is not None and s.motion.get("motion_mm") is not None]
    if not seen:
        return None
    mm, name = max(seen)
    return {"motion_mm": mm, "camera": name, "moving": bool(mm > MOTION_WARN_MM),
            "threshold_mm": MOTION_WARN_MM}


def _check_motion(scans, where, max_motion_mm: float | None) -> None:
    summary = motion_summary(scans)
    if summary is None:
        return
    mm, name = summary["motion_mm"], summary["camera"]
    if max_motion_mm is not None and mm > max_motion_mm:
        raise ValueError(
            f"{where}: the finger moved during the capture: camera {name!r} saw its frames "
            f"shift by {1000 * mm:.0f} µm (more than the {1000 * max_motion_mm:.0f} µm "
            "allowed); capture again with the finger still, or with fewer frames")
    if summary["moving"]:
        warnings.warn(
            f"{where}: the finger moved during the capture: camera {name!r} saw its frames "
            f"shift by {1000 * mm:.0f} µm (above {1000 * MOTION_WARN_MM:.0f} µm); the scans "
            "carry errors of about that size (docs/motion.md)", UserWarning, stacklevel=3)


#: Smallest median angle between camera rays and the projector's planes of constant ``xp``
#: (``yp``) below which one-coordinate triangulation gets a warning: at 3° a point moves 19×
#: the coordinate's error along its ray (1 / sin 3°) instead of 1-2× in a well-built rig.
MIN_PLANE_ANGLE_DEG = 3.0


def _warn_ill_conditioned(scan: Scan, camera: CameraCalibration, use: str) -> None:
    """Warn when the camera's rays nearly lie in the planes of the one coordinate used."""

    points = scan.xyz[scan.mask][::97]  # a sample is enough for a median
    if len(points) == 0:
        return
    angle, mm_per_px = one_coordinate_conditioning(camera.camera, camera.projector, points, use)
    angle, mm_per_px = float(np.nanmedian(angle)), float(np.nanmedian(mm_per_px))
    if angle < MIN_PLANE_ANGLE_DEG:
        other = "yp" if use == "xp" else "xp"
        warnings.warn(
            f"camera {scan.name!r}: triangulating from {use} alone is ill-conditioned: its rays "
            f"lie within {angle:.2f}° of the projector's planes of constant {use} (median), so "
            f"0.1 px of error in {use} moves a point by {0.1 * mm_per_px:.3g} mm; use {other} "
            "or both", UserWarning, stacklevel=3)


def _user_mask(mask, name: str, shape) -> np.ndarray:
    """A user mask (array or image file) checked against the camera's ``(H, W)``."""

    if isinstance(mask, (str, os.PathLike)):
        return read_mask(mask, shape=tuple(shape))
    mask = np.asarray(mask)
    if mask.shape != tuple(shape):
        raise ValueError(f"masks: the mask of camera {name!r} has shape {mask.shape}, but its "
                         f"frames are {tuple(shape)} (H, W)")
    if mask.dtype != bool:
        if not np.issubdtype(mask.dtype, np.number):
            raise ValueError(f"masks: the mask of camera {name!r} must be boolean or numeric")
        mask = mask != 0
    return mask


def _apply_user_mask(scan: Scan, mask: np.ndarray) -> None:
    """Drop the pixels of `scan` outside the user's `mask`, in place."""
    drop = scan.mask & ~mask
    if not drop.any():
        return
    scan.mask &= mask
    if not scan.mask.any():
        raise ValueError(f"camera {scan.name!r}: the scan keeps 0 valid pixels inside the "
                         "given mask (the mask and the decoded pixels do not overlap)")
    scan.xyz[drop] = np.nan
    scan.xp[drop] = np.nan
    scan.yp[drop] = np.nan
    scan.intensity[drop] = 0


def _scan_camera(capture, name: str, calibration: RigCalibration, *, use, max_gradient, method,
                 decode_options, clock: StepClock, detect_motion: bool = True,
                 compensate_motion: bool = False, stabilise_motion: bool = False,
                 motion=None) -> Scan:
    """One camera of :func:`scan_capture`: its frames' integer values in memory (not cached),
    decoded as they are (``method="numba"``) or made float band by band
    (:func:`~nail2nail.io.capture.frame_intensities`); frames the capture has cached are used
    as they are."""
    clock.restart()
    cached = name in capture.frames
    frames = capture.frames[name] if cached else capture.load_frames(name, raw=True)
    _require_pattern_set(capture)  # after the frames: a file's own error comes first
    try:
        frames = _check_frames(frames, capture.pattern_set)
    except ValueError as exc:  # say whose frames
        raise ValueError(f"{capture.path / 'capture.json'}: camera {name!r}: {exc}") from exc
    clock("read_frames")
    options = dict(decode_options, max_gradient=gradient_limit(max_gradient, frames.shape))
    measured = frames
    compensation = stabilisation = None
    saturation = options.get("saturation", SATURATION)
    top = (2 ** capture.bit_depth - 1) if not cached and capture.bit_depth else 1.0
    if stabilise_motion:
        stabilised_use = _stabilised_use(use, capture.pattern_set)
        frames, stabilisation = stabilise_frames(
            frames, capture.pattern_set, saturation=saturation * top,
            direction=stabilised_use[0], motion=motion)
        # resampled: one time, the reference direction's phase; not resampled (no texture to
        # register): the frames as captured, triangulated as asked
        if stabilisation["reference"] is not None and "skipped" not in stabilisation:
            use = stabilised_use
        stabilisation["use"] = use
        clock("stabilise")
    if compensate_motion or stabilise_motion:
        frames, compensation = compensate_phase_steps(frames, capture.pattern_set, None,
                                                      saturation=saturation * top)
        clock("compensate")
    scan = _scan(frames, capture.pattern_set, calibration.camera(name),
                 projector_distortion=calibration.projector_distortion, use=use, method=method,
                 decode_options=options, bit_depth=None if cached else capture.bit_depth)
    clock("decode")
    if detect_motion:
        estimate = estimate_motion(measured, capture.pattern_set, scan.mask,
                                   mm_per_px=mm_per_pixel(scan.xyz, scan.mask))
        scan.motion = None if estimate is None else estimate.to_dict()
        clock("motion")
    if compensation is not None:
        scan.motion = {**(scan.motion or {}), "compensation": compensation}
    if stabilisation is not None:
        scan.motion = {**(scan.motion or {}), "stabilisation": stabilisation}
    scan.fringe_periods = fringe_periods(capture.pattern_set)
    return scan


def _stabilisation(scan: Scan) -> dict:
    """The scan's ``motion["stabilisation"]`` record, itself (empty when not stabilised)."""
    return (scan.motion or {}).get("stabilisation") or {}


def _stabilised_use(use: str, pattern_set) -> str:
    """The projector coordinate a stabilised capture is triangulated from, the direction of the
    group its frames are stabilised to (:func:`~nail2nail.scan.stabilise.reference_direction`):
    ``"xp"`` or ``"yp"`` as asked, ``"xpyp"`` gives way to the default reference's (the other
    direction's phase is the skin at another time)."""
    if use in ("xp", "yp"):
        try:
            return reference_direction(pattern_set, use[0]) + "p"
        except ValueError:
            raise ValueError(f"use={use!r}: the capture's patterns have no phase-shift group in "
                             f"direction {use[0]!r} to stabilise to") from None
    return reference_direction(pattern_set) + "p"


#: Every how many valid pixels of a camera take part in :func:`_motion_from_other_cameras`
MOTION_SAMPLE_STRIDE = 16


def _motion_from_other_cameras(scans, calibration) -> list[tuple[int, np.ndarray, list[str]]]:
    """For each stabilised scan whose own texture did not register (``skipped``), its frames'
    affine maps from the rigid motion that the registered cameras' maps and points give
    (:func:`~nail2nail.scan.stabilise.rigid_motion`): ``[(index, maps, source cameras)]``;
    empty when no camera registered."""
    views, points, skipped = [], [], []
    for k, scan in enumerate(scans):
        info = _stabilisation(scan)
        if info.get("reference") is None:
            continue
        rows, cols = np.nonzero(scan.mask)
        rows, cols = rows[::MOTION_SAMPLE_STRIDE], cols[::MOTION_SAMPLE_STRIDE]
        if not len(rows):
            continue
        view = (np.asarray(info.get("frames_affine", ()), dtype=np.float64),
                scan.xyz[rows, cols].astype(np.float64), rows, cols,
                projection_matrix(calibration.camera(scan.name).camera), scan.mask.shape)
        if "skipped" in info:
            skipped.append((k, view))
        else:
            views.append((scan.name, view))
            points.append(view[1])
    if not views or not skipped:
        return []
    center = np.concatenate(points).mean(axis=0)
    rigid = rigid_motion([view for _, view in views], center)
    sources = [name for name, _ in views]
    return [(k, affine_image_motion(rigid, *view[1:], center=center), sources)
            for k, view in skipped]


def _require_pattern_set(capture) -> None:
    """A capture without a pattern set cannot be decoded: say so, naming its manifest."""
    if capture.pattern_set is None:
        raise ValueError(
            f"{capture.path / 'capture.json'}: \"pattern_set\" is null or missing: the "
            "manifest does not say which patterns were projected, so the frames cannot be "
            "decoded; describe them there (docs/capture-format.md, \"pattern_set\")")


def decode_cameras(capture, *, progress: bool = False, desc: str = "decode", **decode_options):
    """Decode every camera of a capture in turn, one camera's frames in memory at a time.

    Parameters
    ----------
    capture : Capture
        From :func:`nail2nail.io.capture.read_capture` (``load=False`` is fine).
    progress : bool
        Show a progress bar labelled `desc` on stderr (a terminal only).
    **decode_options
        Passed to :func:`nail2nail.scan.decoding.decode`; ``method`` is ``"numba"`` (the fused
        kernel
        the scan runs) unless given.

    Yields
    ------
    name : str
        Camera name.
    decoded : Decoded
        Its projector coordinates and quality images.

    Raises
    ------
    ValueError
        If the capture's manifest names no pattern set.
    """

    _require_pattern_set(capture)
    for name in progress_bar(capture.camera_names, desc=desc, unit="camera", enabled=progress):
        yield name, decode_camera(capture, name, **decode_options)


def decode_camera(capture, name: str, **decode_options):
    """Decode one camera of a capture (:func:`decode_cameras`' step): its frames as cached
    (then released from the cache) or read as integers.

    Parameters
    ----------
    capture : Capture
        From :func:`nail2nail.io.capture.read_capture` (``load=False`` is fine).
    name : str
        One of ``capture.camera_names``.
    **decode_options
        Passed to :func:`nail2nail.scan.decoding.decode` (``method="numba"`` unless given).

    Returns
    -------
    Decoded
        Projector panel coordinates ``xp, yp`` (H, W) in panel px (NaN where invalid), the
        quality images (``albedo``, ``modulation``: fractions of full scale), ``mask`` and
        ``reason``.

    Raises
    ------
    ValueError
        If the capture's manifest names no pattern set.
    """
    _require_pattern_set(capture)
    options = {"method": "numba", **decode_options}
    if name in capture.frames:  # cached as floats in [0, 1]
        return decode(capture.frames.pop(name), capture.pattern_set, **options)
    # the frames' integer values, not cached: a quarter of the floats' memory
    return decode(capture.load_frames(name, raw=True), capture.pattern_set,
                  full_scale=2**capture.bit_depth - 1, **options)

