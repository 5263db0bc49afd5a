"""Coordinate frames of written results: the world frame, or a camera's own frame.

Scanning, merging, fusion and unrolling compute in the calibration's world frame; what is
written (the scans' ``.npz``, PLY and mat5, the super scan's PLY and mat5) may be expressed in
another frame, chosen by name (``--frame`` of ``nail2nail scan`` and ``nail2nail process``):

- ``"world"``: the calibration's world frame (nothing changes);
- a camera name (``"cam0"`` …): that camera's frame, ``x_cam = R x_world + t`` (OpenCV: ``x``
  right, ``y`` down, ``z`` forward, mm) with ``R``, ``t`` of its pinhole model; a DLT matrix is
  decomposed first (:func:`nail2nail.calibration.camera_models.pinhole_from_dlt`: RQ decomposition,
  ``det R = +1``).

The transform is recorded as ``T_frame_world`` (4×4, mm) in ``scan.json`` and
``process.json``; :func:`nail2nail.io.scans.load_scans` maps the points back to the world frame
with it, so that ``merge`` and ``unroll`` compute in the world frame whatever the scans' frame.
Conventions: ``docs/conventions.md`` ("World and sensor frames").
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from nail2nail._validation import as_matrix
from nail2nail.calibration.camera_models import Pinhole, pinhole_from_dlt

__all__ = [
    "WORLD",
    "frame_transform",
    "invert_transform",
    "points_in_frame",
    "scan_in_frame",
    "superscan_in_frame",
    "vectors_in_frame",
]

#: Name of the calibration's world frame.
WORLD = "world"


def frame_transform(calibration, frame: str = WORLD) -> np.ndarray:
    """``T_frame_world``: the 4×4 rigid transform from world mm to the frame named `frame`.

    Parameters
    ----------
    calibration : RigCalibration
        The rig's calibration (:mod:`nail2nail.calibration.files`).
    frame : str
        ``"world"`` or the name of one of its cameras.

    Returns
    -------
    (4, 4) float64
        ``[[R, t], [0, 0, 0, 1]]`` with ``x_frame = R x_world + t``; the identity for
        ``"world"``.

    Raises
    ------
    ValueError
        If `frame` is neither ``"world"`` nor a camera of the calibration.

    Examples
    --------
    >>> from nail2nail.simulation import default_rig, ideal_calibration
    >>> from nail2nail.calibration.files import RigCalibration
    >>> calib = RigCalibration.from_dict(ideal_calibration(default_rig(0.25)))
    >>> T = frame_transform(calib, "cam1")
    >>> np.round(points_in_frame(calib.cameras[1].camera.center, T), 9).tolist()
    [0.0, 0.0, 0.0]
    """

    if not isinstance(frame, str):
        raise ValueError(f"frame: expected 'world' or a camera name, got {frame!r}")
    if frame == WORLD:
        return np.eye(4)
    names = [cam.name for cam in calibration.cameras]
    if frame not in names:
        raise ValueError(f"frame: expected 'world' or a camera of the calibration "
                         f"({', '.join(names)}), got {frame!r}")
    model = calibration.cameras[names.index(frame)].camera
    if not isinstance(model, Pinhole):  # a DLT matrix: its pose by RQ decomposition
        model = pinhole_from_dlt(model)
    T = np.eye(4)
    T[:3, :3] = model.R
    T[:3, 3] = model.t
    return T


def _check_transform(transform) -> np.ndarray:
    T = as_matrix(transform, "transform", (4, 4))
    if not np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0]):
        raise ValueError("transform: the last row of a rigid 4x4 transform must be (0, 0, 0, 1)")
    R = T[:3, :3]
    deviation = float(np.max(np.abs(R @ R.T - np.eye(3))))
    if not deviation <= 1e-6 or np.linalg.det(R) < 0:
        raise ValueError(f"transform: the 3x3 block is not a rotation (max |R R^T - I| = "
                         f"{deviation:.3g}, det {np.linalg.det(R):.3g})")
    return T


def invert_transform(transform) -> np.ndarray:
    """The inverse of a rigid 4×4 transform: ``[[Rᵀ, −Rᵀ t], [0, 1]]``.

    Examples
    --------
    >>> T = np.eye(4); T[:3, 3] = (1, 2, 3)
    >>> invert_transform(T)[:3, 3].tolist()
    [-1.0, -2.0, -3.0]
    """
    T = _check_transform(transform)
    inverse = np.eye(4)
    inverse[:3, :3] = T[:3, :3].T
    inverse[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return inverse


def points_in_frame(points, transform) -> np.ndarray:
    """Points ``(..., 3)`` mapped by a rigid 4×4 transform: ``R x + t`` (NaN stays NaN).

    Computed in float64; the result has the input's float dtype (float32 points stay float32,
    rounded once).

    Parameters
    ----------
    points : (..., 3) float
        Points, mm.
    transform : (4, 4) float
        ``T_frame_world`` (:func:`frame_transform`) or its inverse.

    Returns
    -------
    (..., 3) float
    """
    T = _check_transform(transform)
    points = np.asarray(points)
    dtype = points.dtype if points.dtype.kind == "f" else np.float64
    out = np.asarray(points, dtype=np.float64) @ T[:3, :3].T + T[:3, 3]
    return out.astype(dtype, copy=False)


def vectors_in_frame(vectors, transform) -> np.ndarray:
    """Directions ``(..., 3)`` (normals) rotated by a rigid transform's ``R`` (no translation)."""
    T = _check_transform(transform)
    vectors = np.asarray(vectors)
    dtype = vectors.dtype if vectors.dtype.kind == "f" else np.float64
    return (np.asarray(vectors, dtype=np.float64) @ T[:3, :3].T).astype(dtype, copy=False)


def scan_in_frame(scan, transform):
    """A :class:`~nail2nail.scan.results.Scan` with ``xyz``, ``camera_center`` and
    ``projector_center`` mapped by `transform` (the other images are frame-free); the identity
    returns `scan` itself."""
    T = _check_transform(transform)
    if np.array_equal(T, np.eye(4)):
        return scan

    def moved(point):
        return None if point is None else points_in_frame(np.asarray(point, dtype=float), T)

    return replace(scan, xyz=points_in_frame(scan.xyz, T), camera_center=moved(scan.camera_center),
                   projector_center=moved(scan.projector_center))


def superscan_in_frame(superscan, transform):
    """A :class:`~nail2nail.merge.fusion.SuperScan` with its points and normals (per camera
    grid and per vertex) mapped by `transform`; the identity returns `superscan` itself."""
    T = _check_transform(transform)
    if np.array_equal(T, np.eye(4)):
        return superscan
    return replace(
        superscan,
        scans=[scan_in_frame(s, T) for s in superscan.scans],
        normals=[vectors_in_frame(n, T) for n in superscan.normals],
        vertices=points_in_frame(superscan.vertices, T),
        vertex_normals=vectors_in_frame(superscan.vertex_normals, T),
    )
