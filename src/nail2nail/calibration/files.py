"""Calibration files (JSON): per camera a camera model and the projector model seen from it.

Format (``docs/capture-format.md``)::

    {"format": "nail2nail-calibration", "version": 1,
     "cameras": [{"name": "cam0", "camera": MODEL, "projector": MODEL}, ...],
     "projector_distortion": {"center": [x, y], "rho": r} | null}

``MODEL`` is ``{"model": "dlt", "matrix": [[...] x3], "size": [W, H]}`` (thesis eq. 3.3/3.6) or
``{"model": "pinhole", "K": ..., "dist": [k1, k2, p1, p2, k3], "R": ..., "t": ..., "size": ...}``
(OpenCV). With DLT models each camera carries its own projector matrix, as in the thesis.
The world frame is the file's own, any rigid frame (a camera's own included: pinhole models
are used through :func:`nail2nail.calibration.camera_models.projection_matrix`, never normalised to
``m34 = 1``). OpenCV ``FileStorage`` files (SLStudio, ``stereo_calib``) are read and written by
:mod:`nail2nail.calibration.opencv_files`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nail2nail._validation import as_float_array, as_name, check_format, check_unique
from nail2nail.calibration.camera_models import Pinhole, check_rank, handedness
from nail2nail.calibration.distortion import ProjectorDistortion, as_projector_distortion
from nail2nail.io._json import read_json, write_json

__all__ = [
    "MAX_INTRINSIC_PX",
    "MAX_SIZE_PX",
    "MAX_TRANSLATION_MM",
    "CameraCalibration",
    "RigCalibration",
    "check_handedness",
    "check_intrinsics",
    "check_pinhole_values",
    "check_size",
    "load_calibration",
    "model_from_dict",
    "model_to_dict",
    "save_calibration",
]

FORMAT = "nail2nail-calibration"

Model = np.ndarray | Pinhole

#: Largest image or panel side accepted, px. The largest sensors and projector panels have
#: about 16 000 px a side; 100 000 leaves room and refuses numbers that are not sizes (a width
#: of 1e10 px, which OpenCV's 32-bit integers wrap to 1 410 065 408, made a rig that cannot be
#: used).
MAX_SIZE_PX = 100_000
#: Largest |fx|, |fy|, |skew|, |cx|, |cy| of a pinhole model accepted, px. A 16 000 px sensor
#: of 3 µm pixels behind a 1000 mm lens has f ≈ 3.3e5 px, and an off-axis projector's principal
#: point lies within a few panel sizes of the panel; 1e6 px leaves room.
MAX_INTRINSIC_PX = 1e6
#: Largest |t| of a pinhole model accepted, mm (100 m). The scanner's cameras and projector
#: stand within a metre of the finger and of each other; a larger |t| is a unit error (m, µm)
#: or not a number of this rig (1e308 was accepted, and written back by export-calibration).
MAX_TRANSLATION_MM = 1e5


def check_size(size, name: str) -> tuple[int, int]:
    """`size` as ``(W, H)``, each an integer in ``1 … MAX_SIZE_PX``; ``ValueError`` naming
    `name` otherwise.

    Examples
    --------
    >>> check_size((1280, 1024.0), "size")
    (1280, 1024)
    """
    try:
        w, h = size
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected [W, H] in pixels, got {size!r}") from None
    for v in (w, h):
        ok = (not isinstance(v, bool) and isinstance(v, int | float | np.integer | np.floating)
              and np.isfinite(v) and v == int(v) and 1 <= v <= MAX_SIZE_PX)
        if not ok:
            shown = [v.item() if isinstance(v, np.generic) else v for v in (w, h)]
            raise ValueError(f"{name}: expected [W, H], integers in 1 … {MAX_SIZE_PX} px, "
                             f"got {shown}")
    return int(w), int(h)


def check_intrinsics(K, name: str) -> None:
    """Refuse an intrinsic matrix whose ``fx, fy, skew, cx, cy`` are beyond
    ``MAX_INTRINSIC_PX`` px in magnitude (``ValueError`` naming `name`, the entry and its
    value): checked before the matrix's rank, so that a focal length of 1e308 px is called
    what it is rather than a rank-deficient matrix."""
    K = np.asarray(K, dtype=float)
    for label, value in (("fx", K[0, 0]), ("fy", K[1, 1]), ("skew", K[0, 1]), ("cx", K[0, 2]),
                         ("cy", K[1, 2])):
        if not abs(value) <= MAX_INTRINSIC_PX:
            raise ValueError(f"{name}: {label} = {value:.6g} px, beyond "
                             f"{MAX_INTRINSIC_PX:g} px: not an intrinsic matrix in pixels")


def check_pinhole_values(model: Pinhole, name: str, *,
                         keys: dict[str, str] | None = None) -> None:
    """Refuse a pinhole model whose numbers are not those of a camera or projector.

    Its image size must be integers in ``1 … MAX_SIZE_PX`` px, ``fx, fy, skew, cx, cy`` at
    most ``MAX_INTRINSIC_PX`` px in magnitude and ``|t|`` below ``MAX_TRANSLATION_MM`` mm
    (every number is already finite: :class:`Pinhole`). `keys` renames the fields in the
    message (``{"K": "Kc", "t": "Tp"}`` for a file's own keys).

    Raises
    ------
    ValueError
        Naming `name`, the field and its value.
    """
    keys = {"K": "K", "t": "t", "size": "size", **(keys or {})}
    check_size(model.size, f"{name}: {keys['size']}")
    check_intrinsics(model.K, f"{name}: {keys['K']}")
    largest = float(np.max(np.abs(model.t)))
    # scaled first: no overflow in the norm (a Python float product gives inf, no warning)
    norm = largest * float(np.linalg.norm(model.t / largest)) if largest else 0.0
    if not norm < MAX_TRANSLATION_MM:
        shown = ", ".join(f"{v:.6g}" for v in model.t)
        raise ValueError(f"{name}: {keys['t']}: translation [{shown}] mm, |t| = {norm:.6g} mm "
                         f"is not below {MAX_TRANSLATION_MM:g} mm (100 m): not a translation of "
                         "this rig in mm")


def model_to_dict(model: Model, *, size=None) -> dict:
    """JSON-ready dict of a DLT matrix (3×4 array) or a :class:`Pinhole`."""
    if isinstance(model, Pinhole):
        return model.to_dict()
    matrix = np.asarray(model, dtype=float)
    if matrix.shape != (3, 4):
        raise ValueError(f"model: expected a 3x4 DLT matrix or a Pinhole, got shape {matrix.shape}")
    out: dict[str, Any] = {"model": "dlt", "matrix": matrix.tolist()}
    if size is not None:
        out["size"] = [int(s) for s in size]
    return out


def model_from_dict(data: Any, *, where: str = "model") -> Model:
    """Inverse of :func:`model_to_dict`; raises ``ValueError`` naming `where` on bad input."""
    if not isinstance(data, dict) or "model" not in data:
        raise ValueError(f"{where}: expected an object with a 'model' key")
    kind = data["model"]
    if kind == "dlt":
        try:  # numbers only: strings such as "1e3" are refused, not parsed
            matrix = as_float_array(data.get("matrix"), "matrix")
        except (TypeError, ValueError, OverflowError):
            matrix = np.empty(0)
        if matrix.shape != (3, 4) or not np.all(np.isfinite(matrix)):
            raise ValueError(f"{where}: 'matrix' must be a finite 3x4 array of numbers")
        check_rank(matrix, where)
        return matrix
    if kind == "pinhole":
        try:
            model = Pinhole.from_dict(data)
        except (ValueError, TypeError, KeyError, IndexError, OverflowError) as exc:
            raise ValueError(f"{where}: {exc}") from exc
        check_intrinsics(model.K, f"{where}: K")
        check_rank(model, where)
        return model
    raise ValueError(f"{where}: unknown model {kind!r} (expected 'dlt' or 'pinhole')")


@dataclass
class CameraCalibration:
    """One camera's calibration: its model and the projector model calibrated with it."""

    name: str
    camera: Model
    projector: Model
    size: tuple[int, int] | None = None


@dataclass
class RigCalibration:
    """All cameras of a rig, plus the projector's radial distortion if it is modelled."""

    cameras: list[CameraCalibration]
    projector_distortion: ProjectorDistortion | None = None
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        # one form of the model: a JSON dict given here becomes a ProjectorDistortion
        self.projector_distortion = as_projector_distortion(self.projector_distortion)

    def camera(self, name: str) -> CameraCalibration:
        """The calibration of camera `name`; ``KeyError`` listing the known names."""
        for cam in self.cameras:
            if cam.name == name:
                return cam
        raise KeyError(f"calibration has no camera {name!r} (has {[c.name for c in self.cameras]})")

    def to_dict(self) -> dict:
        """JSON-ready dict in the calibration-file format (module docstring)."""
        return {
            "format": FORMAT,
            "version": 1,
            "cameras": [
                {
                    "name": c.name,
                    "camera": model_to_dict(c.camera, size=c.size),
                    "projector": model_to_dict(c.projector),
                }
                for c in self.cameras
            ],
            "projector_distortion": (None if self.projector_distortion is None
                                     else self.projector_distortion.to_dict()),
            **self.extra,
        }

    @classmethod
    def from_dict(
        cls, data: dict, *, where: str = "calibration", allow_mirrored: bool = False
    ) -> RigCalibration:
        """Inverse of :meth:`to_dict`; ``ValueError`` naming `where` on bad content.

        A mirrored camera or projector is refused (:func:`check_handedness`) unless
        `allow_mirrored`.
        """
        check_format(data, fmt=FORMAT, where=where)
        cams = data.get("cameras")
        if not isinstance(cams, list) or not cams:
            raise ValueError(f"{where}: 'cameras' must be a non-empty list")
        cameras = []
        for i, c in enumerate(cams):
            if not isinstance(c, dict):
                raise ValueError(f"{where}: cameras[{i}] must be an object")
            name = as_name(c.get("name", f"cam{i}"), f"{where}: cameras[{i}].name")
            camera = model_from_dict(c.get("camera"), where=f"{where}: cameras[{i}].camera")
            projector = model_from_dict(
                c.get("projector"), where=f"{where}: cameras[{i}].projector"
            )
            for role, model in (("camera", camera), ("projector", projector)):
                if isinstance(model, Pinhole):  # DLT matrices: any scale, no ranges
                    check_pinhole_values(model, f"{where}: cameras[{i}] ({name!r}).{role}")
            size = c["camera"].get("size")
            if size is not None and not (
                isinstance(size, list) and len(size) == 2
                and all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)
            ):
                raise ValueError(f"{where}: cameras[{i}].camera.size must be [W, H] in pixels, "
                                 f"got {size!r}")
            if size is not None:
                check_size(size, f"{where}: cameras[{i}] ({name!r}).camera.size")
            cameras.append(
                CameraCalibration(name, camera, projector, tuple(size) if size else None)
            )
        check_unique([c.name for c in cameras], where)
        dist = data.get("projector_distortion")
        if dist is not None:
            if not isinstance(dist, dict) or not ({"center", "rho"} <= set(dist)):
                raise ValueError(f"{where}: projector_distortion needs 'center' and 'rho'")
            try:
                center = as_float_array(dist["center"], "center")
            except (TypeError, ValueError, OverflowError):
                center = np.empty(0)
            if center.shape != (2,) or not np.all(np.isfinite(center)):
                raise ValueError(f"{where}: projector_distortion.center must be [x, y] (numbers)")
            rho = dist["rho"]
            if isinstance(rho, bool) or not isinstance(rho, int | float) or not np.isfinite(rho):
                raise ValueError(f"{where}: projector_distortion.rho must be a finite number")
            dist = ProjectorDistortion(center=(float(center[0]), float(center[1])),
                                       rho=float(rho))
        extra = {
            k: v
            for k, v in data.items()
            if k not in ("format", "version", "cameras", "projector_distortion")
        }
        calibration = cls(cameras=cameras, projector_distortion=dist, extra=extra)
        if not allow_mirrored:
            check_handedness(calibration, where)
        return calibration


def _scene_point(camera: Model, projector: Model) -> np.ndarray:
    """A point in front of both models: where their principal axes pass closest (world mm).

    The world origin when the axes are (nearly) parallel; NaN when the numbers are out of
    range (a centre beyond 1e308 mm). Raises ``numpy.linalg.LinAlgError`` for a singular
    matrix (:func:`check_rank` refuses those first).
    """
    centres, axes = [], []
    with np.errstate(all="ignore"):
        for model in (camera, projector):
            if isinstance(model, Pinhole):  # centre and axis exactly, without K [R | t]
                centres.append(model.center)
                axes.append(model.R[2])
                continue
            M = np.asarray(model, dtype=float)
            M = M / np.max(np.abs(M))  # the same projection; no overflow in the solve
            centres.append(-np.linalg.solve(M[:, :3], M[:, 3]))
            axes.append(M[2, :3] / np.linalg.norm(M[2, :3]))
        (c1, c2), (d1, d2) = centres, axes
        b = d1 @ d2
        if not np.all(np.isfinite([*c1, *c2, *d1, *d2])):
            return np.full(3, np.nan)
        if 1 - b * b < 1e-6:
            return np.zeros(3)
        r = c1 - c2
        s1 = (b * (d2 @ r) - d1 @ r) / (1 - b * b)
        s2 = (d2 @ r - b * (d1 @ r)) / (1 - b * b)
        return 0.5 * (c1 + s1 * d1 + c2 + s2 * d2)


def check_handedness(calibration: RigCalibration, where: str, *, scene_point=None) -> None:
    """Refuse a calibration with a mirrored camera or projector (issue 10).

    A mirrored model (a horizontal flip in the camera driver, a projector in rear-projection
    mode, a left-handed pose: :func:`nail2nail.calibration.camera_models.handedness`) gives a
    mirrored
    surface, and a mirrored fingerprint matches nobody. The homogeneous depth of a DLT matrix is
    taken at `scene_point` (world mm), by default where the camera's and the projector's
    principal axes pass closest. Projectors are checked when they are pinhole models (panel px,
    x right, y down); a DLT projector matrix is fitted to projector coordinates in the
    points table's own convention, whose axes may be flipped without mirroring the scan (the
    thesis's tables give projector matrices of negative handedness and correct scans).

    Raises
    ------
    ValueError
        Naming `where` and the camera.
    """
    for cam in calibration.cameras:
        point = scene_point
        if point is None:
            try:
                point = _scene_point(cam.camera, cam.projector)
            except np.linalg.LinAlgError as exc:
                raise ValueError(f"{where}: camera {cam.name!r}: its camera or projector "
                                 f"matrix is singular ({exc})") from exc
            if not np.all(np.isfinite(point)):
                raise ValueError(
                    f"{where}: camera {cam.name!r}: its camera and projector models place the "
                    "scene beyond 1e308 mm (numbers out of range); check the matrices")
        for role, model in (("camera", cam.camera), ("projector", cam.projector)):
            if role == "projector" and not isinstance(model, Pinhole):
                continue  # a DLT projector's panel axes are the user's (the thesis's: mirrored)
            if handedness(model, scene_point=point) < 0:
                what = (f"camera {cam.name!r}" if role == "camera"
                        else f"the projector (as calibrated with camera {cam.name!r})")
                raise ValueError(
                    f"{where}: {what} is mirrored (its image is a mirror image of the scene: a "
                    "flip in the driver or a left-handed pose); its scans would be mirrored and "
                    "a mirrored fingerprint matches nobody. Remove the flip and recalibrate, or "
                    "give --allow-mirrored (allow_mirrored=True) if this is intended")


def save_calibration(path: str | os.PathLike, calibration: RigCalibration) -> None:
    """Write `calibration` as JSON (atomically)."""
    write_json(path, calibration.to_dict())


def load_calibration(path: str | os.PathLike, *, allow_mirrored: bool = False) -> RigCalibration:
    """Read a calibration file; ``ValueError`` naming the file on bad content.

    Refused: an all-zero or rank-deficient matrix, and (unless `allow_mirrored`) a mirrored
    camera or projector (:func:`check_handedness`).
    """
    return RigCalibration.from_dict(read_json(path), where=os.fspath(path),
                                    allow_mirrored=allow_mirrored)
