"""Reconstruction of world points from camera pixels and projector coordinates.

The thesis's linear triangulation (eq. 3.12–3.14) intersects the two camera rays' planes with
one projector plane; :func:`reconstruct_points_lsq` uses both projector coordinates in a
least-squares sense; :func:`triangulation_table` precomputes, per camera pixel, the rational
function of the projector coordinate that eq. 3.14 reduces to, so a whole frame is triangulated
with a multiply-add and a division per coordinate (the look-up-table idea of Liu et al.,
Opt. Express 18(5), 2010, doi:10.1364/OE.18.005229).

:func:`reconstruct_image` (float64 NumPy, in bands of rows) is the reference of a scan's
triangulation. The scan's fast path (:func:`nail2nail.scan.kernels.decode_fast` with a
:class:`RayTable` from :func:`ray_table`) solves the same problem on the camera ray: with the
point ``X = C + t d`` on the ray of the (lens-undistorted) pixel, the projector planes give a
one-dimensional weighted least-squares problem in ``t`` (:func:`reconstruct_points_ray`), solved
per pixel in float64 inside the decoding kernel; the projector's radial distortion model and
lens distortion are compensated there with the reference's formulas.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nail2nail._validation import as_matrix
from nail2nail.calibration.camera_models import Pinhole, projection_matrix
from nail2nail.calibration.distortion import (
    ProjectorDistortion,
    as_projector_distortion,
)
from nail2nail.scan.rays import _pack_ray, _ray_points_flat

__all__ = [
    "BAND_PIXELS",
    "USES",
    "RayTable",
    "TriangulationTable",
    "band_rows",
    "model_matrix",
    "one_coordinate_conditioning",
    "pixel_grid",
    "ray_table",
    "reconstruct_image",
    "reconstruct_points",
    "reconstruct_points_lsq",
    "reconstruct_points_one_coordinate",
    "reconstruct_points_ray",
    "triangulate",
    "triangulation_table",
    "undistorted_pixels",
]


_AXES = {"x": 0, "y": 1}


#: Pixels per band of rows in :func:`reconstruct_image` (its float64 temporaries take about
#: 0.6 kB per pixel: some 80 MB a band) and in the undistorted pixel centres of :func:`ray_table`.
BAND_PIXELS = 1 << 17


#: The projector coordinates a point can be triangulated from (``use``; :attr:`Scan.
#: triangulated_from <nail2nail.scan.results.Scan.triangulated_from>`)
USES = ("xpyp", "yp", "xp")


def _axis_row(axis: str) -> int:
    if axis not in _AXES:
        raise ValueError(f"axis: expected 'x' or 'y', got {axis!r}")
    return _AXES[axis]


def pixel_grid(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates ``(xc, yc)``, each ``(H, W)`` float64, for an image of `shape`."""
    H, W = shape
    yc, xc = np.mgrid[0:H, 0:W].astype(np.float64)
    return xc, yc


def _camera_rows(M_c: np.ndarray, xc, yc):
    """Rows 1–2 of C (eq. 3.12) and D (eq. 3.13) for camera coordinates."""
    xc = np.asarray(xc, dtype=float)[..., None]
    yc = np.asarray(yc, dtype=float)[..., None]
    r0 = M_c[0, :3] - M_c[2, :3] * xc
    r1 = M_c[1, :3] - M_c[2, :3] * yc
    d0 = M_c[2, 3] * xc[..., 0] - M_c[0, 3]
    d1 = M_c[2, 3] * yc[..., 0] - M_c[1, 3]
    return r0, r1, d0, d1


def reconstruct_points(
    camera_matrix, projector_matrix, xc, yc, p, *, axis: str = "y"
) -> np.ndarray:
    """World points from camera coordinates and one projector coordinate (eq. 3.12–3.14).

    Parameters
    ----------
    camera_matrix, projector_matrix : (3, 4) float
        DLT matrices ``M_wc``, ``M_wp`` (eq. 3.3, 3.6).
    xc, yc : (...) float
        Camera coordinates, px; any shape, broadcast together with `p`.
    p : (...) float
        Projector coordinate ``yp`` (``axis="y"``, the thesis's choice) or ``xp`` (``axis="x"``).
    axis : {"y", "x"}
        Which projector coordinate `p` is.

    Returns
    -------
    (..., 3) float64
        ``(Xw, Yw, Zw)`` in mm; NaN where any input is NaN or the system is singular.

    Examples
    --------
    >>> Mc = np.array([[900., 0, 0, 500], [0, 900, 0, 600], [0, 0, 0.01, 1]])
    >>> Mp = np.array([[800., 0, 300, 600], [0, 800, 300, 500], [0, 0, 0.01, 1]])
    >>> X = np.array([1.0, 2.0, 3.0])
    >>> from nail2nail.calibration.camera_models import project_dlt
    >>> (xc, yc), (xp, yp) = project_dlt(Mc, X), project_dlt(Mp, X)
    >>> reconstruct_points(Mc, Mp, xc, yc, yp).round(9).tolist()
    [1.0, 2.0, 3.0]
    """
    M_c = as_matrix(camera_matrix, "camera_matrix", (3, 4))
    M_p = as_matrix(projector_matrix, "projector_matrix", (3, 4))
    k = _axis_row(axis)
    xc, yc, p = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (xc, yc, p)))
    r0, r1, d0, d1 = _camera_rows(M_c, xc, yc)
    r2 = M_p[k, :3] - M_p[2, :3] * p[..., None]
    d2 = M_p[2, 3] * p - M_p[k, 3]
    # C⁻¹ D by the adjugate: the columns of C⁻¹ are r1×r2, r2×r0, r0×r1 over det C.
    c12, c20, c01 = np.cross(r1, r2), np.cross(r2, r0), np.cross(r0, r1)
    with np.errstate(divide="ignore", invalid="ignore"):
        det = np.sum(r0 * c12, axis=-1)
        num = d0[..., None] * c12 + d1[..., None] * c20 + d2[..., None] * c01
        return num / det[..., None]


def _solve_symmetric3(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve batched 3×3 systems by the adjugate; NaN where singular or NaN (no warnings)."""
    r0, r1, r2 = A[..., 0, :], A[..., 1, :], A[..., 2, :]
    c12, c20, c01 = np.cross(r1, r2), np.cross(r2, r0), np.cross(r0, r1)
    with np.errstate(divide="ignore", invalid="ignore"):
        det = np.sum(r0 * c12, axis=-1)
        num = b[..., 0:1] * c12 + b[..., 1:2] * c20 + b[..., 2:3] * c01
        return num / det[..., None]


def reconstruct_points_lsq(
    camera_matrix, projector_matrix, xc, yc, xp, yp, *, camera_weight: float = 1.0
) -> np.ndarray:
    """World points from camera coordinates and both projector coordinates (least squares).

    The four linear equations of eq. 3.12–3.13 with the rows of both ``xp`` and ``yp`` form an
    over-determined system ``C P = D`` (4×3); each row is divided by the norm of its ``C`` row so
    that it measures a distance to its plane, and the system is solved by normal equations.

    Parameters
    ----------
    camera_matrix, projector_matrix : (3, 4) float
        DLT matrices.
    xc, yc, xp, yp : (...) float
        Camera px and projector coordinates; broadcast together.
    camera_weight : float
        Weight of the two camera equations relative to the projector ones. ``1`` treats all
        four alike (right for measured points tables, where ``xc, yc`` are noisy too); a large
        value (e.g. ``1e3``) keeps the point on the camera ray, which is right for scans, where
        ``xc, yc`` are exact pixel centres and only the decoded projector coordinates are noisy.

    Returns
    -------
    (..., 3) float64
        World points, mm; NaN where any input is NaN.
    """
    M_c = as_matrix(camera_matrix, "camera_matrix", (3, 4))
    M_p = as_matrix(projector_matrix, "projector_matrix", (3, 4))
    xc, yc, xp, yp = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (xc, yc, xp, yp)))
    r0, r1, d0, d1 = _camera_rows(M_c, xc, yc)
    r2 = M_p[0, :3] - M_p[2, :3] * xp[..., None]
    r3 = M_p[1, :3] - M_p[2, :3] * yp[..., None]
    d2 = M_p[2, 3] * xp - M_p[0, 3]
    d3 = M_p[2, 3] * yp - M_p[1, 3]
    C = np.stack([r0, r1, r2, r3], axis=-2)
    D = np.stack([d0, d1, d2, d3], axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = 1.0 / np.linalg.norm(C, axis=-1)
    w[..., :2] *= camera_weight
    C = C * w[..., None]
    D = D * w
    CtC = np.einsum("...ki,...kj->...ij", C, C)
    CtD = np.einsum("...ki,...k->...i", C, D)
    return _solve_symmetric3(CtC, CtD)


@dataclass
class TriangulationTable:
    """Per-pixel rational form of eq. 3.14: ``X_k = (n_k0 + n_k1 p) / (d_0 + d_1 p)``.

    Attributes
    ----------
    numerator : (H, W, 3, 2) float32
        ``n_k0, n_k1`` for ``k`` = X, Y, Z.
    denominator : (H, W, 2) float32
        ``d_0, d_1``.
    axis : {"y", "x"}
        Projector coordinate the table expects.
    """

    numerator: np.ndarray
    denominator: np.ndarray
    axis: str = "y"


def triangulation_table(
    camera_matrix,
    projector_matrix,
    shape: tuple[int, int],
    *,
    axis: str = "y",
    dtype=np.float32,
) -> TriangulationTable:
    """Precompute :class:`TriangulationTable` for every pixel of an ``(H, W)`` camera image.

    With ``r2 = a + b p`` and ``d2 = e + f p`` (the projector row of eq. 3.12–3.13), Cramer's
    rule makes numerator and determinant of eq. 3.14 linear in ``p``.

    Examples
    --------
    >>> Mc = np.array([[900., 0, 0, 500], [0, 900, 0, 600], [0, 0, 0.01, 1]])
    >>> Mp = np.array([[800., 0, 300, 600], [0, 800, 300, 500], [0, 0, 0.01, 1]])
    >>> table = triangulation_table(Mc, Mp, (4, 5), dtype=np.float64)
    >>> xc, yc = pixel_grid((4, 5)); yp = np.full((4, 5), 700.0)
    >>> bool(np.allclose(triangulate(table, yp), reconstruct_points(Mc, Mp, xc, yc, yp)))
    True
    """
    M_c = as_matrix(camera_matrix, "camera_matrix", (3, 4))
    M_p = as_matrix(projector_matrix, "projector_matrix", (3, 4))
    k = _axis_row(axis)
    xc, yc = pixel_grid(shape)
    r0, r1, d0, d1 = _camera_rows(M_c, xc, yc)
    a, b = M_p[k, :3], -M_p[2, :3]
    e, f = -M_p[k, 3], M_p[2, 3]
    c01 = np.cross(r0, r1)
    n0 = d0[..., None] * np.cross(r1, a) + d1[..., None] * np.cross(a, r0) + e * c01
    n1 = d0[..., None] * np.cross(r1, b) + d1[..., None] * np.cross(b, r0) + f * c01
    den = np.stack([np.sum(r0 * np.cross(r1, a), -1), np.sum(r0 * np.cross(r1, b), -1)], -1)
    # Scale each pixel's coefficients to a unit denominator norm: float32 keeps full precision.
    scale = 1.0 / np.linalg.norm(den, axis=-1)
    numerator = np.stack([n0, n1], axis=-1) * scale[..., None, None]
    return TriangulationTable(
        numerator=numerator.astype(dtype),
        denominator=(den * scale[..., None]).astype(dtype),
        axis=axis,
    )


def triangulate(table: TriangulationTable, p) -> np.ndarray:
    """World points ``(H, W, 3)``, mm, from a projector-coordinate image `p` ``(H, W)`` (eq. 3.14).

    In the table's dtype; NaN where `p` is NaN, non-finite where the denominator vanishes.
    """
    p = np.asarray(p)
    if p.shape != table.denominator.shape[:2]:
        raise ValueError(f"p: expected shape {table.denominator.shape[:2]}, got {p.shape}")
    p = p.astype(table.numerator.dtype, copy=False)[..., None]
    num = table.numerator[..., 0] + table.numerator[..., 1] * p
    with np.errstate(divide="ignore", invalid="ignore"):
        den = table.denominator[..., 0:1] + table.denominator[..., 1:2] * p
        return num / den


def undistorted_pixels(model, xy) -> np.ndarray:
    """Pixel coordinates ``(..., 2)`` with a pinhole model's lens distortion removed.

    A DLT matrix (3×4 array) has no distortion: `xy` is returned as float64. For a
    :class:`~nail2nail.calibration.camera_models.Pinhole` the OpenCV distortion is inverted
    (``K · undistort(K⁻¹ x)``), so that the model's projection matrix
    (:func:`model_matrix`) applies.
    """

    xy = np.asarray(xy, dtype=float)
    if not isinstance(model, Pinhole) or not np.any(model.dist):
        return xy
    Kinv = np.linalg.inv(model.K)
    normalized = model.undistort(xy @ Kinv[:2, :2].T + Kinv[:2, 2])
    return normalized @ model.K[:2, :2].T + model.K[:2, 2]


def model_matrix(model) -> np.ndarray:
    """The 3×4 projection matrix of a model: a DLT matrix itself, or a pinhole's ``K [R | t]``
    scaled so that ``w`` is the depth in mm
    (:func:`~nail2nail.calibration.camera_models.projection_matrix`; any world frame, the camera's
    own
    included: no ``m34 = 1`` normalisation). Every triangulation here is invariant to the
    matrices' scale."""

    if isinstance(model, Pinhole):
        return projection_matrix(model)
    return as_matrix(model, "model", (3, 4))


def one_coordinate_conditioning(camera, projector, xyz, use: str):
    """How well one projector coordinate fixes points along their camera rays.

    Triangulating from ``xp`` (or ``yp``) alone intersects each camera ray with the plane of
    constant ``xp`` (``yp``) through the point. When the ray nearly lies in that plane, a
    small error of the coordinate moves the point far along the ray: on the default rig the
    centre camera's rays lie within a fraction of a degree of the projector's column planes.

    Parameters
    ----------
    camera, projector : (3, 4) float or Pinhole
        Models of one camera's calibration (lens distortion ignored: a local estimate).
    xyz : (N, 3) float
        Points on the surface, world mm.
    use : {"xp", "yp"}
        The coordinate triangulated from.

    Returns
    -------
    angle_deg : (N,) float64
        Angle between each camera ray and the plane of constant coordinate through its point,
        degrees (90: the best case).
    mm_per_px : (N,) float64
        Displacement of the point along its ray per projector pixel of the coordinate, mm.
    """
    if use not in ("xp", "yp"):
        raise ValueError(f"use: expected 'xp' or 'yp', got {use!r}")
    M = model_matrix(camera)
    centre = -np.linalg.solve(M[:, :3], M[:, 3])
    P = model_matrix(projector)
    X = np.asarray(xyz, dtype=float).reshape(-1, 3)
    d = X - centre
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    row = P[0] if use == "xp" else P[1]
    w = X @ P[2, :3] + P[2, 3]
    c = (X @ row[:3] + row[3]) / w
    grad = (row[:3][None, :] - c[:, None] * P[2, :3][None, :]) / w[:, None]  # dc/dX, px / mm
    along = np.abs(np.sum(grad * d, axis=1))  # dc/dt along the ray
    with np.errstate(divide="ignore", invalid="ignore"):
        sine = along / np.linalg.norm(grad, axis=1)
        return np.degrees(np.arcsin(np.clip(sine, 0.0, 1.0))), 1.0 / along


def reconstruct_image(
    camera,
    projector,
    xp,
    yp,
    *,
    projector_distortion: ProjectorDistortion | dict | None = None,
    use: str = "xpyp",
) -> np.ndarray:
    """World points for every pixel of a camera image from its decoded projector coordinates.

    Parameters
    ----------
    camera, projector : (3, 4) array or Pinhole
        Camera model and the projector model calibrated with it (DLT or OpenCV pinhole, with
        its lens distortion if any).
    xp, yp : (H, W) float
        Decoded projector panel coordinates; NaN where invalid.
    projector_distortion : ProjectorDistortion or dict, optional
        The thesis's projector radial distortion (eq. 3.34;
        :class:`~nail2nail.calibration.distortion.ProjectorDistortion` or its JSON form
        ``{"center": (x, y), "rho": ρ}``), removed from the decoded coordinates before
        triangulation ("compensation in the model").
        Leave it out when the patterns were pre-distorted with the look-up table.
    use : {"xpyp", "yp", "xp"}
        ``"yp"``/``"xp"``: eq. 3.12–3.14 with one projector coordinate (the ray meets the
        projector's row/column plane). ``"xpyp"``: least squares on the camera ray
        (:func:`reconstruct_points_lsq` with a large camera weight, since pixel centres are
        exact). A radial distortion needs both coordinates.

    Returns
    -------
    (H, W, 3) float64
        World points, mm; NaN where the input is NaN. Computed in bands of rows of about
        :data:`BAND_PIXELS` pixels (the temporaries of a band, not of the image, are in
        memory); every pixel's point depends on that pixel alone.
    """
    xp = np.asarray(xp)  # made float64 band by band
    yp = np.asarray(yp)
    if xp.shape != yp.shape or xp.ndim != 2:
        raise ValueError(f"xp, yp: expected two (H, W) arrays, got {xp.shape} and {yp.shape}")
    _check_use(use)
    return _reconstruct_into(camera, projector, xp, yp, np.empty((*xp.shape, 3)), row0=0,
                             projector_distortion=projector_distortion, use=use)


def band_rows(width: int, pixels: int | None = None) -> int:
    """Rows of a band of about `pixels` pixels (:data:`BAND_PIXELS` by default) in an image
    `width` pixels wide; at least 1.

    Examples
    --------
    >>> band_rows(1024), band_rows(2048), band_rows(10**6), band_rows(100, 250)
    (128, 64, 1, 2)
    """
    pixels = BAND_PIXELS if pixels is None else pixels
    return max(1, int(pixels) // max(int(width), 1))


def _reconstruct_into(camera, projector, xp, yp, out, *, row0: int, projector_distortion, use):
    """Points of image rows ``row0 …`` (`xp`, `yp` ``(h, W)``, checked) into `out` ``(h, W, 3)``.

    In bands of :func:`band_rows` rows: bounded temporaries, and every pixel's point depends on
    that pixel alone, so the result does not depend on the banding. Returns `out`.
    """
    step = band_rows(xp.shape[1])
    for a in range(0, xp.shape[0], step):
        b = min(a + step, xp.shape[0])
        out[a:b] = _reconstruct_rows(camera, projector, xp[a:b], yp[a:b], row0 + a,
                                     projector_distortion=projector_distortion, use=use)
    return out


def _reconstruct_rows(camera, projector, xp, yp, row0: int, *, projector_distortion, use):
    """:func:`reconstruct_image` of the image rows ``row0 … row0 + len(xp) - 1`` (checked input)."""

    xp = np.asarray(xp, dtype=float)
    yp = np.asarray(yp, dtype=float)
    panel = np.stack([xp, yp], axis=-1)
    dist = as_projector_distortion(projector_distortion)
    if dist is not None:
        panel = dist.ideal_from_panel(panel)
    panel = undistorted_pixels(projector, panel)
    xc, yc = pixel_grid(xp.shape)
    yc += row0
    cam_xy = undistorted_pixels(camera, np.stack([xc, yc], axis=-1))
    M_c, M_p = model_matrix(camera), model_matrix(projector)
    if use == "xpyp":
        return reconstruct_points_lsq(
            M_c,
            M_p,
            cam_xy[..., 0],
            cam_xy[..., 1],
            panel[..., 0],
            panel[..., 1],
            camera_weight=1e3,
        )
    p = panel[..., 1] if use == "yp" else panel[..., 0]
    return reconstruct_points(M_c, M_p, cam_xy[..., 0], cam_xy[..., 1], p, axis=use[0])


def _check_use(use) -> str:
    if use not in USES:
        raise ValueError(f"use: expected 'xpyp', 'yp' or 'xp', got {use!r}")
    return use


@dataclass
class RayTable:
    """A camera's triangulation on its pixel rays, precomputed once per calibration and size.

    :func:`nail2nail.scan.kernels.decode_fast` (``table=``) triangulates every valid pixel with it,
    in float64, as :func:`reconstruct_image` does (:func:`reconstruct_points_ray` per pixel).
    Built by :func:`ray_table`.

    Attributes
    ----------
    shape : (int, int)
        Camera image ``(H, W)``.
    use : {"xpyp", "yp", "xp"}
        Projector coordinates used (:func:`reconstruct_image`).
    camera_inverse : (3, 3) float64
        ``M_c[:, :3]⁻¹`` of the camera's DLT matrix: the ray of the pixel at ``(x, y)`` runs
        along ``camera_inverse @ (x, y, 1)``.
    camera_center : (3,) float64
        Optical centre, world mm.
    projector_matrix : (3, 4) float64
        Projector DLT matrix.
    panel_distortion : (3,) float64 or None
        ``(cx, cy, rho**3)``: the projector radial distortion (eq. 3.34) compensated in the
        model (:func:`~nail2nail.calibration.distortion.ideal_from_panel`), px.
    projector_intrinsics : (3, 3) float64 or None
        ``K`` of a pinhole projector with lens distortion `projector_dist`.
    projector_dist : (5,) float64 or None
        Its OpenCV ``(k1, k2, p1, p2, k3)``.
    pixel_offsets : (2, H, W) float32 or None
        Lens-undistorted minus actual pixel centres ``(dx, dy)`` of a pinhole camera with
        lens distortion, px (shared between the tables of one camera model: not to be
        changed).
    lens_iterations : int
        Fixed-point iterations inverting the projector's lens distortion
        (:meth:`~nail2nail.calibration.camera_models.Pinhole.undistort`).
    """

    shape: tuple[int, int]
    use: str
    camera_inverse: np.ndarray
    camera_center: np.ndarray
    projector_matrix: np.ndarray
    panel_distortion: np.ndarray | None = None
    projector_intrinsics: np.ndarray | None = None
    projector_dist: np.ndarray | None = None
    pixel_offsets: np.ndarray | None = None
    lens_iterations: int = 20

    @property
    def needs_both(self) -> bool:
        """Whether it reads both projector coordinates (``use="xpyp"`` or a distortion)."""
        return (self.use == "xpyp" or self.panel_distortion is not None
                or self.projector_intrinsics is not None)


def _ray_geometry(camera, projector, *, projector_distortion, use) -> dict:
    """The fields of a :class:`RayTable` but its shape and pixel offsets."""

    _check_use(use)
    M_c, M_p = model_matrix(camera), model_matrix(projector)
    try:
        inverse = np.linalg.inv(M_c[:, :3])
    except np.linalg.LinAlgError:  # no rays: every point is NaN, as in the reference
        inverse = np.full((3, 3), np.nan)
    fields = dict(use=use, camera_inverse=inverse, camera_center=-inverse @ M_c[:, 3],
                  projector_matrix=M_p)
    dist = as_projector_distortion(projector_distortion)
    if dist is not None:
        cx, cy = np.asarray(dist.center, dtype=float)
        fields["panel_distortion"] = np.array([cx, cy, dist.rho ** 3], float)
    if isinstance(projector, Pinhole) and np.any(projector.dist):
        fields["projector_intrinsics"] = projector.K.copy()
        fields["projector_dist"] = projector.dist.astype(float)
    return fields


#: Pixel offsets of recent pinhole cameras with lens distortion: ``(K, dist, shape) -> (2, H, W)``.
_OFFSETS: dict = {}


_OFFSETS_KEPT = 4


def _pixel_offsets(camera, shape: tuple[int, int]) -> np.ndarray:
    """Undistorted minus actual pixel centres ``(2, H, W)`` float32 of a pinhole camera with
    lens distortion; computed in bands of rows (bounded float64 temporaries) and kept for the
    last few camera models."""
    key = (camera.K.tobytes(), camera.dist.tobytes(), tuple(shape))
    if key in _OFFSETS:
        _OFFSETS[key] = _OFFSETS.pop(key)  # most recently used last
        return _OFFSETS[key]
    height, width = shape
    offsets = np.empty((2, height, width), np.float32)
    columns = np.arange(width, dtype=float)
    step = band_rows(width)
    for a in range(0, height, step):
        rows = np.arange(a, min(a + step, height), dtype=float)
        grid = np.stack(np.broadcast_arrays(columns[None, :], rows[:, None]), axis=-1)
        offsets[:, a:a + len(rows)] = np.moveaxis(undistorted_pixels(camera, grid) - grid, -1, 0)
    _OFFSETS[key] = offsets
    while len(_OFFSETS) > _OFFSETS_KEPT:
        del _OFFSETS[next(iter(_OFFSETS))]
    return offsets


def ray_table(camera, projector, shape, *,
              projector_distortion: ProjectorDistortion | dict | None = None,
              use: str = "xpyp") -> RayTable:
    """Precompute the triangulation of a camera's ``(H, W)`` pixels for the fused kernel.

    Thesis eq. 3.12–3.14 solved on the camera ray: the two camera rows of eq. 3.12–3.13 fix
    the ray of each pixel centre (``(x, y) = (column, row)``, px), the projector rows the
    plane(s) it meets (:func:`reconstruct_points_ray`).

    Parameters
    ----------
    camera, projector : (3, 4) array or Pinhole
        As for :func:`reconstruct_image`.
    shape : (int, int)
        Camera image ``(H, W)``.
    projector_distortion : ProjectorDistortion or dict, optional
        ``{"center": (x, y), "rho": ρ}`` compensated in the model (:func:`reconstruct_image`).
    use : {"xpyp", "yp", "xp"}
        Projector coordinates used (:func:`reconstruct_image`).

    Returns
    -------
    RayTable
        Small constants, and for a pinhole camera with lens distortion its undistorted pixel
        centres (8 bytes per pixel, computed once per camera model and size).

    Examples
    --------
    >>> Mc = np.array([[900., 0, 0, 500], [0, 900, 0, 600], [0, 0, 0.01, 1]])
    >>> Mp = np.array([[800., 0, 300, 600], [0, 800, 300, 500], [0, 0, 0.01, 1]])
    >>> table = ray_table(Mc, Mp, (4, 5))
    >>> table.needs_both, table.pixel_offsets is None
    (True, True)
    """

    height, width = (int(v) for v in shape)
    fields = _ray_geometry(camera, projector, projector_distortion=projector_distortion,
                           use=use)
    if isinstance(camera, Pinhole) and np.any(camera.dist):
        fields["pixel_offsets"] = _pixel_offsets(camera, (height, width))
    return RayTable(shape=(height, width), **fields)


def reconstruct_points_ray(camera, projector, xc, yc, xp, yp, *,
                           projector_distortion: ProjectorDistortion | dict | None = None,
                           use: str = "xpyp") -> np.ndarray:
    """World points on the camera rays of pixels ``(xc, yc)``: the fused kernel's triangulation
    (thesis eq. 3.12–3.14 with the camera equations exact).

    The point ``X = C + t d`` lies on the ray of the (lens-undistorted) camera pixel. Each
    projector coordinate ``p`` (``xp`` or ``yp``, ideal after the projector's distortion is
    removed, :func:`reconstruct_image`) gives the plane ``r · X = e`` with
    ``r = P_k - p P_2``; its residual divided by ``|r|`` (a distance) is ``(a t - b) / |r|``,
    and ``t`` is the one projector plane's solution or, for ``use="xpyp"``, the weighted least
    squares ``t = Σ a b / |r|² / Σ a² / |r|²``: :func:`reconstruct_points_lsq` with the camera
    equations' weight taken to infinity (the reference's 1e3 puts points within 1e-8 mm of it).
    Computed in float64 by the compiled code of :func:`nail2nail.scan.kernels.decode_fast`.

    Parameters
    ----------
    camera, projector : (3, 4) array or Pinhole
        As for :func:`reconstruct_image`.
    xc, yc, xp, yp : (...) float
        Camera pixel coordinates and decoded projector panel coordinates, px; broadcast
        together.
    projector_distortion : ProjectorDistortion or dict, optional
        ``{"center", "rho"}`` compensated in the model.
    use : {"xpyp", "yp", "xp"}

    Returns
    -------
    (..., 3) float64
        World points, mm; NaN where any coordinate used is NaN or the ray is parallel to the
        projector planes.

    Examples
    --------
    >>> Mc = np.array([[900., 0, 0, 500], [0, 900, 0, 600], [0, 0, 0.01, 1]])
    >>> Mp = np.array([[800., 0, 300, 600], [0, 800, 300, 500], [0, 0, 0.01, 1]])
    >>> from nail2nail.calibration.camera_models import project_dlt
    >>> X = np.array([1.0, 2.0, 3.0])
    >>> (xc, yc), (xp, yp) = project_dlt(Mc, X), project_dlt(Mp, X)
    >>> reconstruct_points_ray(Mc, Mp, xc, yc, xp, yp).round(9).tolist()
    [1.0, 2.0, 3.0]
    """

    fields = _ray_geometry(camera, projector, projector_distortion=projector_distortion,
                           use=use)
    xc, yc, xp, yp = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (xc, yc, xp, yp)))
    shape = xc.shape
    cam = undistorted_pixels(camera, np.stack([xc, yc], axis=-1)).reshape(-1, 2)
    ray_f, ray_i = _pack_ray(RayTable(shape=(1, 1), **fields))
    points = _ray_points_flat(np.ascontiguousarray(cam[:, 0]), np.ascontiguousarray(cam[:, 1]),
                              xp.ravel().copy(), yp.ravel().copy(), ray_f, ray_i)
    return points.reshape(*shape, 3)


def _panel_of_points(projector, projector_distortion, xyz) -> np.ndarray:
    """Panel coordinates ``(n, 2)`` where the projector shows world points `xyz` ``(n, 3)``:
    the pinhole or DLT projection, the lens distortion of a pinhole projector, then the radial
    distortion model (:func:`~nail2nail.calibration.distortion.panel_from_ideal`); NaN behind it."""

    if isinstance(projector, Pinhole):
        xy = projector.project(xyz)
    else:
        M = model_matrix(projector)
        h = xyz @ M[:, :3].T + M[:, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = h[:, :2] / np.where(h[:, 2:3] != 0, h[:, 2:3], np.nan)
    dist = as_projector_distortion(projector_distortion)
    if dist is not None:
        xy = dist.panel_from_ideal(xy)
    return xy


def reconstruct_points_one_coordinate(camera, projector, xc, yc, p, *, axis: str,
                                      projector_distortion: ProjectorDistortion | dict
                                      | None = None,
                                      tolerance: float = 1e-6,
                                      max_iterations: int = 30) -> np.ndarray:
    """World points from one decoded projector coordinate of a distorted projector.

    With one projector coordinate (a pattern set of one direction) the panel column (row) of
    a distorted projector is a curved surface, not a plane, and its ideal coordinate needs the
    other coordinate (:func:`~nail2nail.calibration.distortion.ideal_from_panel`), which was not
    decoded.
    The point is found on the camera ray instead: ``X(t) = C + t d`` for the lens-undistorted
    pixel (thesis eq. 3.12–3.13 exact), and ``t`` solves ``panel_k(X(t)) = p`` (``k`` the
    `axis`), where ``panel`` is the projector's forward model (projection, lens distortion of a
    pinhole projector, then the radial model ``{center, rho}`` of eq. 3.34). Secant iterations
    on ``t`` from the plane solution that takes `p` as ideal (eq. 3.14), all pixels at once;
    the distortion is smooth, so it converges in a few steps.

    Parameters
    ----------
    camera, projector : (3, 4) array or Pinhole
        As for :func:`reconstruct_image`.
    xc, yc : (...) float
        Camera pixel coordinates, px (pixel centres, ``docs/conventions.md``).
    p : (...) float
        Decoded panel coordinate ``xp`` (``axis="x"``) or ``yp`` (``axis="y"``), px.
    axis : {"x", "y"}
        Which projector coordinate `p` is.
    projector_distortion : ProjectorDistortion or dict, optional
        ``{"center": (x, y), "rho": ρ}``, the radial model; none for pre-distorted patterns.
    tolerance : float
        Convergence: ``|panel_k(X) - p|`` below this, projector px.
    max_iterations : int
        Secant steps at most; pixels not converged by then are NaN.

    Returns
    -------
    (..., 3) float64
        World points, mm; NaN where `p` is NaN, the ray misses the projector or the iteration
        did not converge.

    Raises
    ------
    ValueError
        On an `axis` other than ``"x"`` or ``"y"``.

    Examples
    --------
    >>> Mc = np.array([[900., 0, 0, 500], [0, 900, 0, 600], [0, 0, 0.01, 1]])
    >>> Mp = np.array([[800., 0, 300, 600], [0, 800, 300, 500], [0, 0, 0.01, 1]])
    >>> from nail2nail.calibration.camera_models import project_dlt
    >>> from nail2nail.calibration.distortion import panel_from_ideal
    >>> X = np.array([1.0, 2.0, 3.0])
    >>> (xc, yc), ideal = project_dlt(Mc, X), project_dlt(Mp, X)
    >>> dist = {"center": (2000.0, 2500.0), "rho": -0.004}
    >>> xp = panel_from_ideal(ideal, dist["center"], dist["rho"])[0]
    >>> reconstruct_points_one_coordinate(Mc, Mp, xc, yc, xp, axis="x",
    ...                                   projector_distortion=dist).round(6).tolist()
    [1.0, 2.0, 3.0]
    """
    k = _axis_row(axis)
    xc, yc, p = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (xc, yc, p)))
    shape = xc.shape
    p = p.ravel()
    cam = undistorted_pixels(camera, np.stack([xc.ravel(), yc.ravel()], axis=-1))
    M_c, M_p = model_matrix(camera), model_matrix(projector)
    try:
        inverse = np.linalg.inv(M_c[:, :3])
    except np.linalg.LinAlgError:
        return np.full((*shape, 3), np.nan)
    center = -inverse @ M_c[:, 3]
    rays = np.column_stack([cam, np.ones(len(cam))]) @ inverse.T  # (n, 3)
    # start: the plane of p taken as an ideal coordinate (eq. 3.14 on the ray)
    r = M_p[k, :3][None, :] - p[:, None] * M_p[2, :3][None, :]
    e = M_p[k, 3] - p * M_p[2, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = -(r @ center + e) / np.sum(r * rays, axis=1)

    def residual(t, idx):
        xyz = center + t[:, None] * rays[idx]
        return _panel_of_points(projector, projector_distortion, xyz)[:, k] - p[idx]

    t_out = np.full(len(p), np.nan)
    idx = np.flatnonzero(np.isfinite(t0) & np.isfinite(p))
    t_prev = t0[idx]
    g_prev = residual(t_prev, idx)
    t_cur = t_prev * (1.0 + 1e-4) + 1e-4
    g_cur = residual(t_cur, idx)
    for _ in range(max_iterations):
        done = np.abs(g_cur) < tolerance
        t_out[idx[done]] = t_cur[done]
        keep = ~done & np.isfinite(g_cur) & np.isfinite(g_prev)
        idx, t_prev, g_prev, t_cur, g_cur = (idx[keep], t_prev[keep], g_prev[keep], t_cur[keep],
                                             g_cur[keep])
        if idx.size == 0:
            break
        with np.errstate(divide="ignore", invalid="ignore"):
            t_new = t_cur - g_cur * (t_cur - t_prev) / (g_cur - g_prev)
        t_prev, g_prev = t_cur, g_cur
        t_cur = t_new
        g_cur = residual(t_cur, idx)
    else:
        done = np.abs(g_cur) < tolerance
        t_out[idx[done]] = t_cur[done]
    points = center + t_out[:, None] * rays
    return points.reshape(*shape, 3)

