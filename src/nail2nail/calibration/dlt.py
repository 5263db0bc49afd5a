"""Least-squares (DLT) calibration of cameras and of the projector (thesis eq. 3.1–3.11).

A projection matrix ``M`` (3×4) maps world points (mm) to image coordinates: camera pixels
``(xc, yc)`` or projector coordinates ``(xp, yp)`` alike. Two estimators:

``method="thesis"``
    eq. 3.9–3.11: ``m34 = 1`` and the 11 remaining entries by linear least squares
    ``m = (AᵀA)⁻¹ Aᵀ B`` (solved with ``lstsq`` for numerical safety).
``method="normalized"``
    Hartley normalisation (centroid at the origin, mean distance √3 in 3D, √2 in 2D) and the
    homogeneous solution ``A m = 0`` with ``‖m‖ = 1`` from the SVD (Hartley & Zisserman,
    *Multiple View Geometry*, 2nd ed., alg. 7.1), rescaled to ``m34 = 1`` for reporting.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nail2nail._validation import as_points
from nail2nail.calibration.camera_models import project_dlt
from nail2nail.scan.triangulation import reconstruct_points, reconstruct_points_lsq

__all__ = [
    "CalibrationReport",
    "CrossCheck",
    "calibrate_points",
    "check_calibration_points",
    "crosscheck",
    "fit_projection_matrix",
    "reprojection_errors",
]

MIN_POINTS = 6
METHODS = ("thesis", "normalized")


def check_calibration_points(xyz_world, xy_image, *, name: str = "points"):
    """Validate a calibration point set and return it as float64 arrays.

    Raises
    ------
    ValueError
        Fewer than 6 points, NaN/inf, mismatched lengths, or world points that are collinear or
        coplanar (the DLT needs a non-planar target: eq. 3.9 is then rank deficient).
    """
    xyz = as_points(xyz_world, f"{name}: xyz_world", 3, min_points=MIN_POINTS)
    xy = as_points(xy_image, f"{name}: xy_image", 2, min_points=MIN_POINTS)
    if xyz.shape[0] != xy.shape[0]:
        raise ValueError(f"{name}: {xyz.shape[0]} world points but {xy.shape[0]} image points")
    centred = xyz - xyz.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    if s[0] == 0 or s[1] / s[0] < 1e-9:
        raise ValueError(f"{name}: the world points are collinear (or identical); need a 3D target")
    if s[2] / s[0] < 1e-6:
        raise ValueError(
            f"{name}: the world points are coplanar; the DLT needs a non-planar target"
        )
    return xyz, xy


def _normalizing_transform(points: np.ndarray) -> np.ndarray:
    """Similarity that moves the centroid to 0 and scales the mean distance to √dim."""
    dim = points.shape[1]
    centroid = points.mean(axis=0)
    mean_dist = np.mean(np.linalg.norm(points - centroid, axis=1))
    scale = np.sqrt(dim) / mean_dist
    T = np.eye(dim + 1)
    T[:dim, :dim] *= scale
    T[:dim, dim] = -scale * centroid
    return T


def fit_projection_matrix(xyz_world, xy_image, *, method: str = "thesis") -> np.ndarray:
    """Fit a 3×4 projection matrix with ``m34 = 1`` to world ↔ image correspondences.

    Parameters
    ----------
    xyz_world : (N, 3) float
        Reference points, world mm; N ≥ 6, not coplanar.
    xy_image : (N, 2) float
        Their image coordinates: camera px ``(xc, yc)`` or projector ``(xp, yp)``.
    method : {"thesis", "normalized"}
        ``"thesis"``: eq. 3.9–3.11 (inhomogeneous least squares with m34 = 1).
        ``"normalized"``: Hartley-normalised homogeneous DLT (SVD, ‖m‖ = 1).

    Returns
    -------
    M : (3, 4) float64
        Projection matrix scaled so that ``M[2, 3] == 1`` (eq. 3.3/3.6).

    Raises
    ------
    ValueError
        Degenerate input (see :func:`check_calibration_points`) or an unknown method.

    References
    ----------
    Thesis eq. 3.1–3.11; R. Hartley, A. Zisserman, *Multiple View Geometry in Computer Vision*,
    2nd ed. (2004), §7.1.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> M = np.array([[900., 10, 300, 5000], [5, 950, 200, 4000], [0.01, 0.02, 0.5, 1]])
    >>> xyz = rng.uniform(-10, 10, (20, 3))
    >>> from nail2nail.calibration.camera_models import project_dlt
    >>> bool(np.allclose(fit_projection_matrix(xyz, project_dlt(M, xyz)), M))
    True
    """
    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    xyz, xy = check_calibration_points(xyz_world, xy_image)
    n = xyz.shape[0]
    if method == "thesis":
        A = np.zeros((2 * n, 11))
        A[0::2, 0:3], A[0::2, 3] = xyz, 1.0
        A[1::2, 4:7], A[1::2, 7] = xyz, 1.0
        A[0::2, 8:11] = -xy[:, :1] * xyz
        A[1::2, 8:11] = -xy[:, 1:] * xyz
        B = xy.reshape(-1)
        m, _, rank, _ = np.linalg.lstsq(A, B, rcond=None)
        if rank < 11:
            raise ValueError("points: the calibration system (eq. 3.9) is rank deficient")
        return np.append(m, 1.0).reshape(3, 4)

    T3 = _normalizing_transform(xyz)
    T2 = _normalizing_transform(xy)
    X = np.c_[xyz, np.ones(n)] @ T3.T
    x = np.c_[xy, np.ones(n)] @ T2.T
    A = np.zeros((2 * n, 12))
    A[0::2, 0:4] = X
    A[0::2, 8:12] = -x[:, :1] * X
    A[1::2, 4:8] = X
    A[1::2, 8:12] = -x[:, 1:2] * X
    _, s, vt = np.linalg.svd(A)
    if s[-2] < 1e-12 * s[0]:
        raise ValueError("points: the calibration system is rank deficient")
    M_norm = vt[-1].reshape(3, 4)
    M = np.linalg.inv(T2) @ M_norm @ T3
    if abs(M[2, 3]) < 1e-12 * np.abs(M).max():
        raise ValueError("points: m34 is zero; cannot scale the matrix to m34 = 1")
    return M / M[2, 3]


def reprojection_errors(matrix, xyz_world, xy_image) -> np.ndarray:
    """Per-point reprojection error ``(N, 2)`` in image units: projected minus observed."""
    xyz = as_points(xyz_world, "xyz_world", 3)
    xy = as_points(xy_image, "xy_image", 2)
    return project_dlt(matrix, xyz) - xy


@dataclass
class CalibrationReport:
    """Result of :func:`calibrate_points` for one camera and the projector.

    Attributes
    ----------
    camera_matrix, projector_matrix : (3, 4) float64
        DLT matrices (m34 = 1).
    reconstructed : (N, 3) float64
        Reference points reconstructed from ``(xc, yc)`` and the projector coordinate(s), mm.
    error_mm : (N, 3) float64
        ``reconstructed − xyz_world`` (the thesis's "Error in Xw, Yw, Zw" columns), mm.
    camera_residual_px, projector_residual : (N, 2) float64
        Reprojection errors of the camera (px) and the projector (projector units).
    """

    camera_matrix: np.ndarray
    projector_matrix: np.ndarray
    reconstructed: np.ndarray
    error_mm: np.ndarray
    camera_residual_px: np.ndarray
    projector_residual: np.ndarray
    method: str
    use: str

    @property
    def rms_mm(self) -> np.ndarray:
        """(3,) RMS reconstruction error per coordinate, mm."""
        return np.sqrt(np.mean(self.error_mm**2, axis=0))


def calibrate_points(
    xyz_world, xy_camera, xy_projector, *, method: str = "thesis", use: str = "yp"
) -> CalibrationReport:
    """Calibrate a camera and the projector from one points table and reconstruct its points.

    Parameters
    ----------
    xyz_world : (N, 3) float
        Reference points, mm.
    xy_camera : (N, 2) float
        ``(xc, yc)``, camera px.
    xy_projector : (N, 2) float
        ``(xp, yp)``, projector units.
    method : {"thesis", "normalized"}
        Estimator, see :func:`fit_projection_matrix`.
    use : {"yp", "xp", "xpyp"}
        Projector coordinate(s) used for reconstruction: ``"yp"`` is eq. 3.12–3.14 exactly,
        ``"xpyp"`` the over-determined least-squares variant.
    """

    if use not in ("yp", "xp", "xpyp"):
        raise ValueError(f"use: expected 'yp', 'xp' or 'xpyp', got {use!r}")
    M_c = fit_projection_matrix(xyz_world, xy_camera, method=method)
    M_p = fit_projection_matrix(xyz_world, xy_projector, method=method)
    xyz = np.asarray(xyz_world, dtype=float)
    xc, yc = np.asarray(xy_camera, dtype=float).T
    xp, yp = np.asarray(xy_projector, dtype=float).T
    if use == "xpyp":
        rec = reconstruct_points_lsq(M_c, M_p, xc, yc, xp, yp)
    else:
        rec = reconstruct_points(M_c, M_p, xc, yc, yp if use == "yp" else xp, axis=use[0])
    return CalibrationReport(
        camera_matrix=M_c,
        projector_matrix=M_p,
        reconstructed=rec,
        error_mm=rec - xyz,
        camera_residual_px=reprojection_errors(M_c, xyz, xy_camera),
        projector_residual=reprojection_errors(M_p, xyz, xy_projector),
        method=method,
        use=use,
    )


@dataclass
class CrossCheck:
    """Two cameras' reconstructions of their common reference points (thesis Figure 22).

    Attributes
    ----------
    index_a, index_b : (P,) int
        Rows of the two tables that share ideal world coordinates.
    xyz_world : (P, 3) float64
        The ideal world coordinates, mm.
    distance_mm : (P,) float64
        Euclidean distance between the two reconstructions, mm.
    """

    index_a: np.ndarray
    index_b: np.ndarray
    xyz_world: np.ndarray
    distance_mm: np.ndarray

    @property
    def squared_mm2(self) -> np.ndarray:
        """The thesis's figure: the *squared* distance, mm² (Figure 22, ``p_world_dist``)."""
        return self.distance_mm**2


def crosscheck(
    report_a: CalibrationReport,
    xyz_a,
    report_b: CalibrationReport,
    xyz_b,
    *,
    tolerance_mm: float = 0.01,
) -> CrossCheck:
    """Pair reference points of two cameras with the same ideal world coordinates and measure
    the distance between their reconstructions.

    Parameters
    ----------
    report_a, report_b : CalibrationReport
        Each camera calibrated from its own table (:func:`calibrate_points`).
    xyz_a, xyz_b : (N, 3), (M, 3) float
        Ideal world coordinates of the two tables, mm.
    tolerance_mm : float
        Largest distance between ideal coordinates that counts as the same point.

    Raises
    ------
    ValueError
        If the tables share no point.
    """
    xyz_a = as_points(xyz_a, "xyz_a", 3)
    xyz_b = as_points(xyz_b, "xyz_b", 3)
    d = np.linalg.norm(xyz_a[:, None] - xyz_b[None], axis=-1)
    ia, ib = np.nonzero(d <= tolerance_mm)
    if ia.size == 0:
        raise ValueError(f"the two tables share no reference point (within {tolerance_mm} mm)")
    dist = np.linalg.norm(report_a.reconstructed[ia] - report_b.reconstructed[ib], axis=1)
    return CrossCheck(index_a=ia, index_b=ib, xyz_world=xyz_a[ia], distance_mm=dist)
