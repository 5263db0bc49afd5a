"""Projection models of cameras and projectors: the OpenCV pinhole model and its DLT matrix.

The DLT matrix of the thesis (eq. 3.1–3.6) is a 3×4 array; this module holds the physical
pinhole model (intrinsics ``K``, OpenCV distortion, pose ``R``, ``t``) that the virtual scanner
renders with and that calibrations made with OpenCV are read into. Conventions:
``docs/conventions.md``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from nail2nail._validation import as_float_array, as_int_pair, as_matrix

__all__ = [
    "Pinhole",
    "check_rank",
    "dlt_from_pinhole",
    "handedness",
    "look_at",
    "nearest_rotation",
    "pinhole_from_dlt",
    "project_dlt",
    "projection_matrix",
]

#: Largest ``max |R Rᵀ − I|`` of a rotation accepted as it is (float64 rounding).
ROTATION_EXACT = 1e-9
#: Largest ``max |R Rᵀ − I|`` of a rotation re-orthonormalised with a warning (a rotation stored
#: as float32 is orthonormal to some 1e-7); beyond it a matrix is refused.
ROTATION_TOLERANCE = 1e-5


def nearest_rotation(R, name: str = "R") -> np.ndarray:
    """`R` itself if orthonormal to float64 rounding, else the nearest orthogonal matrix.

    A matrix with ``max |R Rᵀ − I| ≤`` :data:`ROTATION_TOLERANCE` (a rotation stored as
    float32, orthonormal to about 1e-7) is replaced by the orthogonal matrix nearest to it in
    the Frobenius norm, ``U Vᵀ`` of its SVD ``U S Vᵀ`` (its determinant keeps its sign: a
    left-handed matrix stays left-handed, and :func:`handedness` refuses it), with a
    ``UserWarning`` giving the deviation and how much the entries changed.

    Parameters
    ----------
    R : (3, 3) float
        A rotation matrix.
    name : str
        How messages name it.

    Returns
    -------
    (3, 3) float64

    Raises
    ------
    ValueError
        If ``max |R Rᵀ − I|`` exceeds :data:`ROTATION_TOLERANCE` (the measured deviation is
        in the message), or an entry's magnitude exceeds ``1 + ROTATION_TOLERANCE``.

    Examples
    --------
    >>> R = nearest_rotation(np.eye(3, dtype=np.float32))
    >>> R.dtype, bool(np.array_equal(R, np.eye(3)))
    (dtype('float64'), True)
    """
    R = as_matrix(R, name, (3, 3))
    # a rotation's entries lie in [-1, 1]: checked first, so R @ R.T cannot overflow
    largest = float(np.max(np.abs(R)))
    if largest > 1 + ROTATION_TOLERANCE:
        raise ValueError(f"{name}: not a rotation matrix (an entry of magnitude {largest:.6g} "
                         "> 1)")
    deviation = float(np.max(np.abs(R @ R.T - np.eye(3))))
    if deviation <= ROTATION_EXACT:
        return R
    if deviation > ROTATION_TOLERANCE:
        raise ValueError(f"{name}: not a rotation matrix (max |R R^T - I| = {deviation:.3g}, "
                         f"more than the {ROTATION_TOLERANCE:g} accepted)")
    U, _, Vt = np.linalg.svd(R)
    nearest = U @ Vt
    change = float(np.max(np.abs(nearest - R)))
    warnings.warn(f"{name}: not orthonormal to float64 precision (max |R R^T - I| = "
                  f"{deviation:.3g}, a rotation stored as float32?); replaced by the nearest "
                  f"rotation, entries changed by up to {change:.3g}", UserWarning, stacklevel=3)
    return nearest


def look_at(eye, target, up) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and translation of a camera at `eye` looking at `target`.

    Parameters
    ----------
    eye, target : (3,) float
        Camera centre and the point on its optical axis, world mm.
    up : (3,) float
        World direction that should appear *up* in the image (towards row 0).

    Returns
    -------
    R : (3, 3) float64
        Rotation of ``T_cam_world``: ``x_cam = R @ x_world + t``.
    t : (3,) float64
        Translation of ``T_cam_world``, mm.

    Examples
    --------
    >>> R, t = look_at([0, 0, 100], [0, 0, 0], [0, 1, 0])
    >>> np.round(R @ np.array([0, 0, 0]) + t, 6).tolist()
    [0.0, 0.0, 100.0]
    """
    eye = np.asarray(eye, dtype=float)
    z = np.asarray(target, dtype=float) - eye
    z /= np.linalg.norm(z)
    y = -np.asarray(up, dtype=float)  # image y runs down
    y = y - z * (y @ z)
    norm = np.linalg.norm(y)
    if norm < 1e-12:
        raise ValueError("look_at: `up` is parallel to the viewing direction")
    y /= norm
    x = np.cross(y, z)
    R = np.stack([x, y, z])
    return R, -R @ eye


@dataclass
class Pinhole:
    """OpenCV pinhole model of a camera or of a projector.

    Parameters
    ----------
    K : (3, 3) float
        Intrinsic matrix in pixels; ``(K[0, 2], K[1, 2])`` is the principal point with the
        pixel-centre convention (``(0, 0)`` is the centre of the top-left pixel).
    R : (3, 3) float
        Rotation of ``T_cam_world``. One orthonormal only to float32 precision
        (``max |R Rᵀ − I| ≤ 1e-5``) is re-orthonormalised with a ``UserWarning``
        (:func:`nearest_rotation`); a matrix farther from a rotation is refused.
    t : (3,) float
        Translation of ``T_cam_world``, mm.
    dist : (5,) float
        OpenCV distortion ``(k1, k2, p1, p2, k3)``; zeros for none.
    size : (2,) int
        Image size ``(width, height)`` in pixels.
    """

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    size: tuple[int, int] = (1024, 1280)

    def __post_init__(self):
        self.K = as_matrix(self.K, "K", (3, 3))
        self.R = as_matrix(self.R, "R", (3, 3))
        t = as_float_array(self.t, "t")
        if t.size != 3:
            raise ValueError(f"t: expected 3 values, got shape {t.shape}")
        self.t = as_matrix(t.reshape(3, 1), "t", (3, 1)).reshape(3)
        dist = as_float_array(self.dist, "dist").ravel()
        if dist.size > 5:
            raise ValueError(
                f"dist: expected at most 5 coefficients (k1, k2, p1, p2, k3), got {dist.size}"
            )
        if not np.all(np.isfinite(dist)):
            raise ValueError("dist: contains NaN or infinity")
        self.dist = np.pad(dist, (0, 5 - dist.size))
        self.size = as_int_pair(self.size, "size", "(width, height) in pixels", minimum=1)
        self.R = nearest_rotation(self.R, "R")

    # -- frames ---------------------------------------------------------------------------
    @property
    def center(self) -> np.ndarray:
        """(3,) optical centre in world mm."""
        return -self.R.T @ self.t

    def to_camera(self, xyz_world) -> np.ndarray:
        """World points ``(..., 3)`` into the camera frame ``(..., 3)``."""
        xyz = np.asarray(xyz_world, dtype=float)
        return xyz @ self.R.T + self.t

    # -- projection -----------------------------------------------------------------------
    def distort(self, xy_normalized) -> np.ndarray:
        """Apply the OpenCV distortion to normalised coordinates ``(..., 2)``."""
        k1, k2, p1, p2, k3 = self.dist
        if not np.any(self.dist):
            return np.asarray(xy_normalized, dtype=float)
        x, y = np.moveaxis(np.asarray(xy_normalized, dtype=float), -1, 0)
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return np.stack([xd, yd], axis=-1)

    def undistort(self, xy_distorted, *, iterations: int = 20) -> np.ndarray:
        """Invert :meth:`distort` by fixed-point iteration (as OpenCV's ``undistortPoints``)."""
        xy_d = np.asarray(xy_distorted, dtype=float)
        if not np.any(self.dist):
            return xy_d
        k1, k2, p1, p2, k3 = self.dist
        xd, yd = np.moveaxis(xy_d, -1, 0)
        x, y = xd.copy(), yd.copy()
        for _ in range(iterations):
            r2 = x * x + y * y
            radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
            dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
            x = (xd - dx) / radial
            y = (yd - dy) / radial
        return np.stack([x, y], axis=-1)

    def project(self, xyz_world) -> np.ndarray:
        """Pixel coordinates ``(..., 2)`` of world points ``(..., 3)`` (NaN behind the camera)."""
        p = self.to_camera(xyz_world)
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(p[..., 2] > 0, p[..., 2], np.nan)
            xy = self.distort(p[..., :2] / z[..., None])
        return xy @ self.K[:2, :2].T + self.K[:2, 2]

    def rays(self, xy_pixels) -> tuple[np.ndarray, np.ndarray]:
        """World rays through pixel coordinates ``(..., 2)``.

        Returns
        -------
        origin : (3,) float64
            Optical centre, world mm.
        direction : (..., 3) float64
            Unit direction of each ray in the world frame.
        """
        xy = np.asarray(xy_pixels, dtype=float)
        Kinv = np.linalg.inv(self.K)
        normalized = xy @ Kinv[:2, :2].T + Kinv[:2, 2]
        normalized = self.undistort(normalized)
        d_cam = np.concatenate([normalized, np.ones((*normalized.shape[:-1], 1))], axis=-1)
        d = d_cam @ self.R  # R.T @ d for each row
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        return self.center, d

    # -- serialisation --------------------------------------------------------------------
    def to_dict(self) -> dict:
        """JSON-ready dict (``model: "pinhole"``)."""
        return {
            "model": "pinhole",
            "K": self.K.tolist(),
            "dist": self.dist.tolist(),
            "R": self.R.tolist(),
            "t": self.t.tolist(),
            "size": list(self.size),
        }

    @classmethod
    def from_dict(cls, data: dict) -> Pinhole:
        """Inverse of :meth:`to_dict`; raises ``ValueError`` naming a missing key."""
        missing = [k for k in ("K", "R", "t") if k not in data]
        if missing:
            raise ValueError(f"pinhole model: missing key(s) {missing}")
        return cls(
            K=data["K"],
            R=data["R"],
            t=data["t"],
            dist=data.get("dist", np.zeros(5)),
            size=tuple(data.get("size", (1024, 1280))),
        )


def _normalized(matrix) -> np.ndarray:
    """`matrix` divided by its largest absolute entry (all zero stays zero): the same projection
    (a DLT matrix is defined up to a positive scale) without overflow in products of entries."""
    scale = np.max(np.abs(matrix))
    return matrix / scale if scale > 0 else matrix


def projection_matrix(model) -> np.ndarray:
    """The 3×4 projection matrix of a model, scaled so that ``w`` is the depth in mm.

    ``P = λ K [R | t]`` (a pinhole model) or ``λ M`` (a DLT matrix) with ``λ`` chosen so that
    the left 3-vector of the third row has unit norm and ``det P[:, :3] > 0``: then
    ``w = P[2] · (X, 1)`` is the signed depth of ``X`` along the principal axis, mm, positive
    in front of a camera that is not mirrored. Unlike :func:`dlt_from_pinhole` (``m34 = 1``,
    the thesis's form) it exists for every world frame, the camera's own included (where
    ``m34 = 0``). The internal model of every reconstruction (``reconstruction.model_matrix``);
    ignores lens distortion.

    Parameters
    ----------
    model : Pinhole or (3, 4) float
        A pinhole model or a DLT matrix (any scale, either sign).

    Returns
    -------
    (3, 4) float64

    Raises
    ------
    ValueError
        If the left 3×3 block is singular (no camera).

    Examples
    --------
    >>> cam = Pinhole(K=np.diag([1000., 1000, 1]), R=np.eye(3), t=np.zeros(3))
    >>> P = projection_matrix(cam)  # world frame = camera frame: m34 = 0
    >>> P[2].tolist(), float(P[2] @ [1.0, 2.0, 30.0, 1.0])
    ([0.0, 0.0, 1.0, 0.0], 30.0)
    """
    if isinstance(model, Pinhole):
        M = model.K @ np.hstack([model.R, model.t[:, None]])
    else:
        M = as_matrix(model, "model", (3, 4))
    M = _normalized(M)
    det = np.linalg.det(M[:, :3])
    norm = np.linalg.norm(M[2, :3])
    if not (np.isfinite(det) and det != 0 and norm > 0):
        raise ValueError("projection matrix: its left 3x3 block is singular (not a camera)")
    return M * (np.sign(det) / norm)


def dlt_from_pinhole(model: Pinhole) -> np.ndarray:
    """DLT matrix ``K [R | t]`` scaled to ``m34 = 1`` (thesis eq. 3.3); ignores distortion.

    The thesis's form, for its tables and the DLT calibration files; it does not exist when
    the world origin lies on the principal plane (a camera-centred world frame, ``m34 = 0``):
    everything else uses :func:`projection_matrix`.

    Examples
    --------
    >>> R, t = look_at([0, 0, 100], [0, 0, 0], [0, 1, 0])
    >>> M = dlt_from_pinhole(Pinhole(K=np.diag([1000., 1000, 1]), R=R, t=t))
    >>> float(M[2, 3])
    1.0
    """
    M = model.K @ np.hstack([model.R, model.t[:, None]])
    if abs(M[2, 3]) < 1e-12:
        raise ValueError("pinhole model: m34 is zero (world origin on the principal plane, "
                         "e.g. a camera-centred world frame): the thesis's DLT form (m34 = 1) "
                         "does not exist; use projection_matrix")
    return M / M[2, 3]


def pinhole_from_dlt(matrix, *, size=(1024, 1280)) -> Pinhole:
    """Decompose a 3×4 DLT matrix into ``K``, ``R``, ``t`` (RQ decomposition, no distortion).

    Any scale and sign of the matrix: the sign is taken with ``det M[:, :3] > 0``, so that
    ``det R = +1`` and ``K`` has a positive diagonal; ``K[2, 2] = 1``. ``R``, ``t`` are those
    of ``T_cam_world`` (``x_cam = R x_world + t``, mm).
    """
    M = as_matrix(matrix, "matrix", (3, 4))
    if np.linalg.det(M[:, :3]) < 0:  # M is defined up to scale: pick the sign with det(R) = +1
        M = -M
    K, R = scipy.linalg.rq(M[:, :3])
    signs = np.diag(np.sign(np.diag(K)))
    K, R = K @ signs, signs @ R
    t = np.linalg.solve(K, M[:, 3])
    scale = K[2, 2]
    return Pinhole(K=K / scale, R=R, t=t, size=size)


def project_dlt(matrix, xyz_world) -> np.ndarray:
    """Image coordinates ``(..., 2)`` of world points ``(..., 3)`` by eq. 3.1–3.2."""
    M = np.asarray(matrix, dtype=float)
    xyz = np.asarray(xyz_world, dtype=float)
    h = xyz @ M[:, :3].T + M[:, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        return h[..., :2] / h[..., 2:3]


def _as_dlt(model) -> np.ndarray:
    if isinstance(model, Pinhole):
        return model.K @ np.hstack([model.R, model.t[:, None]])
    return as_matrix(model, "model", (3, 4))


def check_rank(model, name: str) -> None:
    """Refuse a projection model that cannot project: an all-zero or rank-deficient matrix.

    Raises
    ------
    ValueError
        Naming `name`, if the left 3×3 block of the model's matrix (``K R``) is zero or
        singular (relative condition below 1e-12): such a "camera" maps the whole world onto
        a line or a point, and every reconstruction with it is NaN or wrong.
    """
    if isinstance(model, Pinhole):  # K R, scaled first: rank(K R) = rank(K), no overflow
        M = _normalized(model.K) @ model.R
    else:
        M = as_matrix(model, "model", (3, 4))[:, :3]
    M = _normalized(M)
    if not np.any(M):
        raise ValueError(f"{name}: the projection matrix is all zero")
    try:
        s = np.linalg.svd(M, compute_uv=False)
    except np.linalg.LinAlgError as exc:
        raise ValueError(f"{name}: the projection matrix cannot be used ({exc})") from exc
    if s[2] < 1e-12 * s[0]:
        relative = ", ".join(f"{v:.3g}" for v in s / s[0])
        raise ValueError(f"{name}: the projection matrix is rank-deficient (its left 3x3 block "
                         f"is singular, relative singular values {relative})")


def handedness(model, *, scene_point=None) -> int:
    """+1 for a camera (or projector) whose image is seen as is, -1 for a mirrored one.

    0 when undetermined (`scene_point` on the principal plane of a DLT matrix).

    A model is mirrored when its image is a mirror image of the scene: a horizontal (or
    vertical) flip in the camera driver, a projector set to rear projection, or a left-handed
    pose (``det(R) < 0``). For a pinhole model that is ``det(R) · fx · fy < 0``. A DLT matrix
    ``M = λ K [R | t]`` is defined up to a scale of either sign, so its handedness is
    ``sign(det M[:, :3]) · sign(w)``, with ``w = M[2] · (X, 1)`` the homogeneous depth of a
    point ``X`` in front of the camera (`scene_point`; by default the world origin).

    Parameters
    ----------
    model : (3, 4) float or Pinhole
        DLT matrix or pinhole model.
    scene_point : (3,) float, optional
        A point of the scene, in front of the camera, world mm.

    Examples
    --------
    >>> R, t = look_at([0, 0, 100], [0, 0, 0], [0, 1, 0])
    >>> cam = Pinhole(K=np.diag([1000., 1000, 1]), R=R, t=t)
    >>> handedness(cam), handedness(-dlt_from_pinhole(cam))
    (1, 1)
    >>> flip = np.array([[-1., 0, 1023], [0, 1, 0], [0, 0, 1]])  # x' = W - 1 - x
    >>> handedness(flip @ dlt_from_pinhole(cam))
    -1
    """
    if isinstance(model, Pinhole):  # signs only: no overflow with huge focal lengths
        sign = np.sign(np.linalg.det(model.R)) * np.sign(model.K[0, 0]) * np.sign(model.K[1, 1])
        return 1 if sign > 0 else -1
    M = _normalized(_as_dlt(model))  # a positive scale changes neither sign
    point = np.zeros(3) if scene_point is None else np.asarray(scene_point, dtype=float)
    point = _normalized(np.append(point, 1.0))  # (X, 1) up to a positive scale
    with np.errstate(all="ignore"):
        w = M[2] @ point
        if not abs(w) > 1e-12 * np.linalg.norm(M[2]) * np.linalg.norm(point):
            return 0  # the point lies on the principal plane (or is not finite): undetermined
        sign = np.sign(np.linalg.det(M[:, :3])) * np.sign(w)
    return 1 if sign > 0 else -1
