"""Flattening maps: from the finger's 3D surface to the plane of the rolled print.

Every map takes world points ``(N, 3)`` in mm and returns print-plane coordinates ``(N, 2)``
in mm, ``(s, t)``: ``s`` runs around the finger, increasing towards ``axis × pad`` (to the right
as seen looking at the pad with the tip up), ``t`` runs along the finger towards the tip. The
rolled print itself is the left-right mirror of that view (:mod:`nail2nail.unroll.render`).

Methods
-------
``cylinder``
    The thesis's unrolling (chapter five): a least-squares circular cylinder; ``s = R θ``,
    ``t`` the position along its axis.
``sphere``
    Fit-sphere unwrapping (Wang, Lau and Hassebrook, *Fit-sphere unwrapping and performance
    analysis of 3D fingerprints*, Appl. Opt. 49(4), 592–600, 2010, doi:10.1364/AO.49.000592):
    a least-squares sphere; longitude around the finger axis and latitude towards the tip,
    both as arc lengths on the sphere.
``rolled``
    Non-parametric, the rolling of a finger on a plane: each cross-section perpendicular to the
    finger's axis is laid down by its arc length from the pad's centre line (``s``), and the
    pad's centre profile along the finger by its arc length (``t``). Lengths around the finger
    are kept exactly, and lengths along it on the pad's centre line; the measured surface
    gives both (radius on a coarse grid of cylinder coordinates, :func:`surface_mesh`). This is
    what rolling the finger on a card does to the skin (without the skin's compression).
``isometric``
    Non-parametric and distance-preserving: the scan is resampled on a coarse mesh
    (:func:`surface_mesh`) and flattened by as-rigid-as-possible parameterisation (Liu et al.,
    *A local/global approach to mesh parameterization*, SGP 2008, doi:10.1111/j.1467-8659.2008.
    01290.x) with libigl, started from the cylinder's coordinates; every point then follows by
    bilinear interpolation of the displacement from the cylinder coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.ndimage
import scipy.optimize
import scipy.sparse
import scipy.sparse.csgraph

from nail2nail._interpolate import bilinear
from nail2nail._quantile import weighted_quantiles
from nail2nail.unroll._kernels import axis_distance

__all__ = [
    "MAX_EXTENT_MM",
    "MAX_MESH_CELLS",
    "METHODS",
    "OUTLIER_FACTOR",
    "OUTLIER_PERCENTILE",
    "CylinderMap",
    "IsometricMap",
    "RolledMap",
    "SphereMap",
    "bulk_sphere",
    "fingertip",
    "fit_cylinder",
    "fit_flattening",
    "fit_sphere",
    "map_distortion",
    "section_pad",
    "surface_mesh",
    "within_sphere",
]

#: Unrolling methods, in the order the docs list them.
_SMOOTH = 0.5  # σ (grid nodes) of the smoothing of the section radii
METHODS = ("cylinder", "sphere", "rolled", "isometric")


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _frame(axis, pad) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orthonormal ``(axis, pad, across = axis × pad)``, `pad` made perpendicular to `axis`."""
    a = _unit(axis)
    n = np.asarray(pad, dtype=np.float64) - np.dot(pad, a) * a
    if np.linalg.norm(n) < 1e-6:
        raise ValueError("pad_direction: parallel to the finger axis")
    n = _unit(n)
    return a, n, np.cross(a, n)


@dataclass
class _AxisMap:
    """Shared part of the parametric maps: an axis, the pad direction and a radius.

    Attributes
    ----------
    center : (3,) float
        A point on the axis (cylinder) or the centre (sphere), world mm.
    axis : (3,) float
        Unit axis direction, towards the fingertip.
    pad : (3,) float
        Unit direction from the axis to the pad centre (``θ = 0``), perpendicular to `axis`.
    radius : float
        Radius, mm.
    """

    center: np.ndarray
    axis: np.ndarray
    pad: np.ndarray
    radius: float
    name = ""

    def _local(self, xyz) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Coordinates of points along ``axis × pad``, ``pad`` and ``axis`` from `center`."""
        return self._local_offsets(np.asarray(xyz, dtype=np.float64) - self.center)

    def _local_offsets(self, d) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`_local` of points given as offsets ``(N, 3) float64`` from `center`."""
        a, n, e = _frame(self.axis, self.pad)
        return d @ e, d @ n, d @ a

    def describe(self) -> dict:
        """JSON-ready parameters."""
        return {"method": self.name, "center_mm": np.round(self.center, 4).tolist(),
                "axis": np.round(self.axis, 6).tolist(), "pad": np.round(self.pad, 6).tolist(),
                "radius_mm": round(float(self.radius), 4)}


@dataclass
class CylinderMap(_AxisMap):
    """Unrolling on a circular cylinder: ``s = R θ``, ``t`` along the axis (thesis, chapter five).

    `center` is a point on the axis (the origin of ``t``); see :class:`_AxisMap`. `taper` is
    the fitted cone's ``dR/dt`` (the radius at ``t`` is ``radius + taper · t``,
    :func:`fit_cylinder`); the thesis's map itself uses the constant `radius`.
    """

    taper: float = 0.0
    #: how `pad` was found (:func:`section_pad`'s ``info``), empty when given
    pad_fit: dict = field(default_factory=dict)
    name = "cylinder"

    def describe(self) -> dict:
        """JSON-ready parameters."""
        out = {**super().describe(), "taper": round(float(self.taper), 6)}
        if self.pad_fit:
            out["pad_fit"] = dict(self.pad_fit)
        return out

    def angles(self, xyz) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``θ`` (rad, 0 on the pad), ``t`` (mm along the axis) and the radius (mm) of points."""
        x, z, t = self._local(xyz)
        return np.arctan2(x, z), t, np.hypot(x, z)

    def __call__(self, xyz) -> np.ndarray:
        """Print-plane ``(s, t)`` (N, 2), mm, of world points ``(N, 3)``."""
        x, z, t = self._local(xyz)
        return np.stack([self.radius * np.arctan2(x, z), t], axis=-1)


@dataclass
class SphereMap(_AxisMap):
    """Fit-sphere unwrapping: longitude and latitude as arc lengths (Wang et al. 2010).

    ``s = R λ`` with ``λ`` the longitude around the finger axis (0 on the pad) and ``t = R φ``
    with ``φ`` the latitude from the sphere's equator (perpendicular to the axis), positive
    towards the tip; `center` is the sphere's centre.
    """

    name = "sphere"

    def __call__(self, xyz) -> np.ndarray:
        """Print-plane ``(s, t)`` (N, 2), mm, of world points ``(N, 3)``."""
        x, z, along = self._local(xyz)
        lon = np.arctan2(x, z)
        lat = np.arctan2(along, np.hypot(x, z))
        return np.stack([self.radius * lon, self.radius * lat], axis=-1)


@dataclass
class IsometricMap:
    """A cylinder map plus a smooth displacement field found by ARAP flattening.

    ``(s, t) = cylinder(xyz) + D(cylinder(xyz))`` with ``D`` bilinear on a regular grid of the
    cylinder's ``(s, t)`` (pitch `grid_mm`, origin `grid_origin`).

    Attributes
    ----------
    cylinder : CylinderMap
    displacement : (Gt, Gs, 2) float64
        ``D`` at the grid nodes, mm (row: ``t``, column: ``s``).
    grid_origin : (2,) float
        Cylinder ``(s, t)`` of node ``[0, 0]``, mm.
    grid_mm : float
        Node spacing, mm.
    iterations : int
        ARAP iterations run.
    """

    cylinder: CylinderMap
    displacement: np.ndarray
    grid_origin: np.ndarray
    grid_mm: float
    iterations: int = 0
    name = "isometric"

    def __call__(self, xyz) -> np.ndarray:
        """Print-plane ``(s, t)`` (N, 2), mm, of world points ``(N, 3)``."""
        st = self.cylinder(xyz)
        c = (st[:, 0] - self.grid_origin[0]) / self.grid_mm
        r = (st[:, 1] - self.grid_origin[1]) / self.grid_mm
        h, w = self.displacement.shape[:2]
        d, _, _ = bilinear(self.displacement, np.clip(r, 0, h - 1), np.clip(c, 0, w - 1))
        return st + d

    def describe(self) -> dict:
        """JSON-ready parameters."""
        return {"method": self.name, "cylinder": self.cylinder.describe(),
                "grid_mm": self.grid_mm, "grid_shape": list(self.displacement.shape[:2]),
                "arap_iterations": self.iterations}


@dataclass
class RolledMap:
    """Rolling on a plane: arc length around each cross-section, and along the pad's profile.

    ``s(θ, z)`` is tabulated on a regular grid of cylinder coordinates (``Rθ`` and ``z``, pitch
    `grid_mm`) and interpolated bilinearly; ``t(z)`` is a 1D table.

    Attributes
    ----------
    cylinder : CylinderMap
        Axis, pad direction and the grid's coordinates.
    s_table : (Gz, Gθ) float64
        ``s`` at the grid nodes, mm.
    t_table : (Gz,) float64
        ``t`` at the grid rows, mm (0 where the pad profile crosses ``z = 0``).
    grid_origin : (2,) float
        Cylinder ``(Rθ, z)`` of node ``[0, 0]``, mm.
    grid_mm : float
    """

    cylinder: CylinderMap
    s_table: np.ndarray
    t_table: np.ndarray
    grid_origin: np.ndarray
    grid_mm: float
    name = "rolled"

    def __call__(self, xyz) -> np.ndarray:
        """Print-plane ``(s, t)`` (N, 2), mm, of world points ``(N, 3)``."""
        st = self.cylinder(xyz)
        c = (st[:, 0] - self.grid_origin[0]) / self.grid_mm
        r = (st[:, 1] - self.grid_origin[1]) / self.grid_mm
        h, w = self.s_table.shape
        s, _, _ = bilinear(self.s_table, np.clip(r, 0, h - 1), np.clip(c, 0, w - 1))
        rows = np.arange(h)
        t = np.interp(r, rows, self.t_table)
        # beyond the table, keep the last slope (the extension is at most a margin)
        t = np.where(r < 0, self.t_table[0] + r * (self.t_table[1] - self.t_table[0]), t)
        t = np.where(r > h - 1, self.t_table[-1] + (r - h + 1) * (self.t_table[-1]
                                                                  - self.t_table[-2]), t)
        s = s + np.where(c < 0, c, np.where(c > w - 1, c - w + 1, 0)) * self.grid_mm
        return np.stack([s, t], axis=-1)

    def describe(self) -> dict:
        """JSON-ready parameters."""
        return {"method": self.name, "cylinder": self.cylinder.describe(),
                "grid_mm": self.grid_mm, "grid_shape": list(self.s_table.shape)}


def _fit_rolled(mesh: SurfaceMesh, cylinder: CylinderMap) -> RolledMap:
    gh, gw = mesh.grid_shape
    h = mesh.grid_mm
    _, _, radius = cylinder.angles(mesh.vertices)
    rad = np.full((gh, gw), np.nan)
    rad[mesh.node[:, 0], mesh.node[:, 1]] = radius
    have = np.isfinite(rad)
    # light smoothing against noise (the radius varies over millimetres), normalised
    w = scipy.ndimage.gaussian_filter(have.astype(float), _SMOOTH)
    with np.errstate(invalid="ignore", divide="ignore"):
        sm = scipy.ndimage.gaussian_filter(np.where(have, rad, 0.0), _SMOOTH) / w
    rad = np.where(have, sm, np.nan)
    _, (ri, ci) = scipy.ndimage.distance_transform_edt(~have, return_indices=True)
    rad = rad[ri, ci]  # empty nodes: nearest measured radius (extension beyond the data)
    origin = mesh.grid_origin + 0.5 * h  # vertices sit near cell centres
    th = (origin[0] + h * np.arange(gw)) / cylinder.radius  # θ of each column
    zz = origin[1] + h * np.arange(gh)
    # arc length around each section: |ΔP| between neighbouring nodes of a row
    seg = np.sqrt((rad[:, 1:] * np.sin(np.diff(th)) ) ** 2
                  + (rad[:, 1:] * np.cos(np.diff(th)) - rad[:, :-1]) ** 2)
    s = np.concatenate([np.zeros((gh, 1)), np.cumsum(seg, axis=1)], axis=1)
    # s = 0 on the pad's centre line (θ = 0)
    s0 = np.array([np.interp(0.0, th, row) for row in s])
    s -= s0[:, None]
    # arc length along the pad's profile (the section radius at θ = 0)
    r_pad = np.array([np.interp(0.0, th, row) for row in rad])
    dt = np.hypot(np.diff(zz), np.diff(r_pad))
    t = np.concatenate([[0.0], np.cumsum(dt)])
    t -= np.interp(0.0, zz, t)
    return RolledMap(cylinder=cylinder, s_table=s, t_table=t, grid_origin=origin, grid_mm=h)


def _sample(points, n_max: int, seed: int = 0) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if len(points) <= n_max:
        return points
    return points[np.random.default_rng(seed).choice(len(points), n_max, replace=False)]


#: Far outliers (a scanner's stray points, a reflection off the rig): points farther from the
#: points' median (per coordinate) than :data:`OUTLIER_FACTOR` times the
#: :data:`OUTLIER_PERCENTILE`-th percentile of the points' distances from it. Every point of a
#: compact surface lies well within (the virtual finger's farthest point, on its tip, at 1.27
#: times that percentile; a cylinder 16 mm across and 30 mm long: 1.08; a disc: 1.05), so no
#: point of the skin is lost, and the percentile stays on the skin while fewer than 10 % of
#: the points are far outliers.
OUTLIER_FACTOR = 2.0
OUTLIER_PERCENTILE = 90.0

#: Largest side of the box holding the points (far outliers left out) that the flattening
#: accepts, mm: ten times a finger's length. Beyond it the points are not one finger, and the
#: grids sized from them (1 mm sections, the 0.5 mm mesh, the print) would not fit in memory.
MAX_EXTENT_MM = 300.0

#: Most cells of :func:`surface_mesh`'s grid (a 1000 mm square at 0.5 mm: far beyond
#: :data:`MAX_EXTENT_MM`, which a cylinder fit gone wrong can still reach around the finger);
#: about 100 MB of work arrays.
MAX_MESH_CELLS = 4_000_000
#: Smallest connected piece of the surface mesh kept, as a fraction of the largest piece's
#: triangles (:func:`surface_mesh`): a cap parted from the body by a band the cameras did not
#: see is 10–40 % of the body; the stray specks left of a scan's outliers are a few triangles
MIN_PIECE_FRACTION = 0.02


def bulk_sphere(xyz, *, n_max: int = 20000, seed: int = 2) -> tuple[np.ndarray, float]:
    """The sphere holding the bulk of the points: far outliers lie outside it.

    Parameters
    ----------
    xyz : (N, 3) float
        Points, mm; non-finite rows are ignored.
    n_max : int
        Points used (a random subset).
    seed : int
        Seed of the subset.

    Returns
    -------
    center : (3,) float64
        Median of the points, per coordinate, mm.
    radius : float
        :data:`OUTLIER_FACTOR` × the :data:`OUTLIER_PERCENTILE`-th percentile of the points'
        distances from `center`, mm.

    Raises
    ------
    ValueError
        If no point is finite.

    Examples
    --------
    >>> pts = np.random.default_rng(0).normal(size=(1000, 3))
    >>> pts[:3] = 1e30  # far outliers
    >>> center, radius = bulk_sphere(pts)
    >>> bool(np.abs(center).max() < 0.2), bool(2 < radius < 10)
    (True, True)
    """
    pts = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if not len(pts):
        raise ValueError("xyz: no finite point")
    pts = _sample(pts, n_max, seed=seed)
    center = np.median(pts, axis=0)
    dist = _distance(pts, center)
    return center, float(OUTLIER_FACTOR * np.percentile(dist, OUTLIER_PERCENTILE))


def _distance(xyz, center) -> np.ndarray:
    """Distances of points ``(N, 3)`` from `center`, float64, without overflow (inf at most)."""
    with np.errstate(over="ignore", invalid="ignore"):
        d = np.asarray(xyz, dtype=np.float64) - center
        return np.hypot(np.hypot(d[:, 0], d[:, 1]), d[:, 2])


def within_sphere(xyz, center, radius: float) -> np.ndarray:
    """``(N,) bool``: the points ``(N, 3)`` that are finite and within `radius` of `center`."""
    return _distance(xyz, center) <= radius  # NaN compares False


def _check_points(xyz, n_max: int | None = None, seed: int = 0) -> np.ndarray:
    """The finite points of `xyz` without far outliers (:func:`bulk_sphere`), float64; with
    `n_max`, of a random subset of `n_max` finite points (:func:`_sample`), drawn before the far
    ones are left out, so that the points kept are those drawn from the same points without
    outliers (a fit does not change because a few far points were removed)."""
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"xyz: expected shape (N, 3), got {xyz.shape}")
    if not np.isfinite(xyz).all():  # (no copy when every point is finite)
        xyz = xyz[np.isfinite(xyz).all(axis=1)]
    if len(xyz) < 100:
        raise ValueError(f"xyz: need at least 100 finite surface points to unroll, got {len(xyz)}")
    sphere = bulk_sphere(xyz)
    if n_max is not None:
        xyz = _sample(xyz, n_max, seed)
    inside = within_sphere(xyz, *sphere)
    if not inside.all():  # (no copy when there is no far outlier)
        xyz = xyz[inside]
    if len(xyz) < 100:
        raise ValueError(f"xyz: need at least 100 surface points to unroll, got {len(xyz)} "
                         "without the far outliers")
    span = float(np.max(xyz.max(axis=0) - xyz.min(axis=0)))
    if span > MAX_EXTENT_MM:
        raise ValueError(f"xyz: the points span {span:.4g} mm (far outliers left out), more than "
                         f"the {MAX_EXTENT_MM:g} mm a finger's scan can (MAX_EXTENT_MM)")
    return xyz


def fit_cylinder(xyz, *, tip_direction=(0.0, 1.0, 0.0), pad_direction=(0.0, 0.0, 1.0),
                 n_max: int = 20000, elliptic: bool = False) -> CylinderMap:
    """Least-squares circular cone (a cylinder that may taper) through surface points.

    The axis starts as the principal direction of the points, turned towards `tip_direction`,
    and is refined with the centre, radius and taper by minimising ``Σ (ρ_i − R − τ t_i)²``
    (ρ the distance to the axis, ``t`` the position along it; Levenberg–Marquardt on a random
    subset of `n_max` points), then again on the finger's body alone. With `elliptic`, the
    body's section may be elliptic: ``ρ = (R + τ t)(1 + a cos 2θ + b sin 2θ)``
    (:func:`_fit_elliptic_cone`), which puts the axis on the section's centre line.

    Parameters
    ----------
    xyz : (N, 3) float
        Surface points, world mm; non-finite rows and far outliers (:func:`bulk_sphere`) are
        ignored.
    tip_direction : (3,) float
        Rough direction of the fingertip (sign of the axis); the world ``+Y`` of
        ``docs/conventions.md`` by default.
    pad_direction : (3,) float
        Rough direction from the finger to the pad's viewer (``θ = 0``); ``+Z`` by default.
    n_max : int
        Points used for the fit.
    elliptic : bool
        Fit the axis of an elliptic cone (the returned `radius` is then its mean radius).

    Returns
    -------
    CylinderMap
        ``center`` is the point of the axis nearest the points' centroid.

    Raises
    ------
    ValueError
        Fewer than 100 points, points spanning more than :data:`MAX_EXTENT_MM`, or the pad
        direction parallel to the axis.
    """
    pts = _check_points(xyz, n_max)
    centroid = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - centroid, full_matrices=False)
    # start from the principal direction nearest the tip direction (a patch may be wider
    # around the finger than it is long, so the first principal direction can run across it)
    tip = _unit(tip_direction)
    a0 = vt[int(np.argmax(np.abs(vt @ tip)))]
    a0 = a0 if np.dot(a0, tip) >= 0 else -a0
    _, n0, e0 = _frame(a0, pad_direction)

    def unpack(p):
        a = _unit(a0 + p[0] * e0 + p[1] * n0)
        c = centroid + p[2] * e0 + p[3] * n0
        return a, c

    def residual(p):
        a, c = unpack(p)
        # ρ − R(z), compiled (ρ = |d − (d·a) a|); R(z) = R + τ z: a cone, since fingers taper
        # (a circular cylinder fitted to one side of a cone tilts its axis towards the pad,
        # and sections oblique to the finger shear the print by several per cent)
        d = pts - c
        return axis_distance(d, a, p[4]) - p[5] * (d @ a)

    d = pts - centroid
    r0 = float(np.median(np.linalg.norm(d - np.outer(d @ a0, a0), axis=1)))
    # start behind the pad: the centroid of a one-sided scan lies in front of the axis
    p0 = np.array([0.0, 0.0, 0.0, -0.3 * r0, r0, 0.0])
    fit = scipy.optimize.least_squares(residual, p0, method="lm")
    # the tip's cap tilts a cone fitted to the whole finger, and a tilted axis shears the
    # unrolled print: fit again to the body only, the 1 mm sections whose radius is within 6 %
    # of the line fitted (robustly) to the sections' radii along the axis
    a, c = unpack(fit.x)
    d = pts - c
    along = d @ a
    rho = np.linalg.norm(d - np.outer(along, a), axis=1)
    slab = np.floor((along - along.min()) / 1.0).astype(np.intp)  # 1 mm sections
    r_slab = np.array([np.median(rho[slab == k]) if np.any(slab == k) else np.nan
                       for k in range(slab.max() + 1)])
    body = _body_sections(r_slab)
    keep = body[slab]
    if keep.sum() >= 100 and keep.mean() < 0.98:
        pts = pts[keep]
        fit = scipy.optimize.least_squares(residual, fit.x, method="lm")
    a_fit, c = unpack(fit.x)
    radius, taper = float(fit.x[4]), float(fit.x[5])
    if elliptic:
        a_fit, c, radius, taper = _fit_elliptic_cone(pts, a_fit, c, radius, taper, pad_direction)
    shift = float(np.dot(centroid - c, a_fit))
    radius = float(abs(radius + taper * shift))  # at the new centre
    c = c + shift * a_fit
    if np.dot(a_fit, tip) < 0:
        a_fit, taper = -a_fit, -taper
    a, n, _ = _frame(a_fit, pad_direction)
    return CylinderMap(center=c, axis=a, pad=n, radius=radius, taper=taper)


#: Fewest mm of elliptic modulation (the 2θ term's amplitude of the section radius) for
#: :func:`section_pad` to turn the pad line; rounder sections keep the rough direction.
MIN_SECTION_ELLIPTICITY_MM = 0.05
#: Largest turn of the pad line from the rough direction that :func:`section_pad` makes, degrees.
MAX_PAD_TURN_DEG = 30.0


def section_pad(xyz, cylinder: CylinderMap, *, n_max: int = 20000) -> tuple[CylinderMap, dict]:
    """Turn the cylinder's pad line (``θ = 0``) onto the symmetry line of the finger's section.

    A finger's section is wider than it is deep (about 0.75–0.95 on adult fingers): its radius
    about the axis is smallest in the middle of the pad. The pad line of a rolled print runs
    there, whichever way the finger is rolled in the scanner; measuring ``s`` from the
    scanner's direction instead shears the print by ``taper × (the roll's arc)`` on a tapered
    finger (about 1.4 % at a taper of 1 % per mm and a roll of 10°) and moves its origin.

    The radius ``ρ`` of the body's points (within 6 % of the cone) is fitted, by linear least
    squares, with ``R + τ t + a cos 2θ + b sin 2θ``; the minimum of the second harmonic nearest
    ``θ = 0`` is the pad line. The cone should be :func:`fit_cylinder`'s elliptic one, whose
    axis is on the section's centre line. (Measured on four random virtual fingers, rolled
    5–9°, sections 0.76–0.93 deep: the pad line within 0.35–0.52° of the truth; with the first
    and fourth harmonics in the fit too, up to 4.2° off.)

    Parameters
    ----------
    xyz : (N, 3) float
        Surface points, world mm.
    cylinder : CylinderMap
        The fitted cone; its `pad` is the rough direction (the cameras' mean direction).
    n_max : int
        Points used for the fit (a random subset).

    Returns
    -------
    cylinder : CylinderMap
        The same cone with `pad` turned (unchanged when the section is too round,
        :data:`MIN_SECTION_ELLIPTICITY_MM`, or the turn exceeds :data:`MAX_PAD_TURN_DEG`).
    info : dict
        ``{"source": "section" | "rough", "turn_deg", "ellipticity_mm"}``.
    """
    pts = _check_points(xyz, n_max, seed=1)
    theta, t, rho = cylinder.angles(pts)
    # the body only (the cap's radius falls towards the tip): within 6 % of the cone
    cone = cylinder.radius + cylinder.taper * t
    keep = np.abs(rho - cone) <= 0.06 * cone
    theta, t, rho = theta[keep], t[keep], rho[keep]
    info: dict = {"source": "rough", "turn_deg": 0.0, "ellipticity_mm": None}
    rough = CylinderMap(center=cylinder.center, axis=cylinder.axis, pad=cylinder.pad,
                        radius=cylinder.radius, taper=cylinder.taper, pad_fit=info)
    if len(rho) < 100:
        return rough, info
    design = np.column_stack([np.ones_like(t), t, np.cos(2 * theta), np.sin(2 * theta)])
    coef, *_ = np.linalg.lstsq(design, rho, rcond=None)
    a2, b2 = coef[2], coef[3]
    amplitude = float(np.hypot(a2, b2))
    # a2 cos 2θ + b2 sin 2θ = A cos 2(θ − θmax); its minima are at θmax ± 90°
    turn = 0.5 * np.arctan2(b2, a2) + 0.5 * np.pi
    turn = (turn + 0.5 * np.pi) % np.pi - 0.5 * np.pi  # the minimum nearest θ = 0
    info["ellipticity_mm"] = round(amplitude, 4)
    if amplitude < MIN_SECTION_ELLIPTICITY_MM or abs(np.degrees(turn)) > MAX_PAD_TURN_DEG:
        return rough, info
    a, n, e = _frame(cylinder.axis, cylinder.pad)
    pad = np.cos(turn) * n + np.sin(turn) * e  # θ = atan2(x·e, x·n): towards +e is +θ
    info.update(source="section", turn_deg=round(float(np.degrees(turn)), 3))
    return CylinderMap(center=cylinder.center, axis=a, pad=pad, radius=cylinder.radius,
                       taper=cylinder.taper, pad_fit=info), info


def _fit_elliptic_cone(pts, axis, center, radius: float, taper: float, pad_direction
                       ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Refine a circular cone's axis as the centre line of an elliptic cone.

    A finger's section is elliptic (depth 0.75–0.95 of its width), and so is the part of it a
    scanner sees; the best circular cone through a tapered elliptic one has its centre off the
    ellipse's by an amount that grows with the section, so its axis tilts (1.9° on a virtual
    finger tapering 0.9 % per mm), and sections cut obliquely shear the sides of the print by
    1–2 %. The radius here is ``(R + τ t)(1 + a cos 2θ + b sin 2θ)``, an ellipse to first
    order in its eccentricity that scales along the finger; Levenberg–Marquardt over the axis
    direction (2), its position (2), ``R``, ``τ``, ``a`` and ``b``. (Higher harmonics trade
    off against the centre on the part of the section a scanner sees: with the fourth too, the
    axis erred by up to 3° on random virtual fingers; with the second alone, 0.3–0.6°.)

    Returns
    -------
    axis, center : (3,) float64
    radius, taper : float
        The mean section's ``R`` at `center` and ``τ = dR/dt``.
    """
    _, n0, e0 = _frame(axis, pad_direction)

    def unpack(p):
        return _unit(axis + p[0] * e0 + p[1] * n0), center + p[2] * e0 + p[3] * n0

    def residual(p):
        a, c = unpack(p)
        _, n, e = _frame(a, n0)
        d = pts - c
        x, z = d @ e, d @ n
        th = np.arctan2(x, z)
        shape = 1 + p[6] * np.cos(2 * th) + p[7] * np.sin(2 * th)
        return np.hypot(x, z) - (p[4] + p[5] * (d @ a)) * shape

    p0 = np.array([0.0, 0.0, 0.0, 0.0, radius, taper, 0.0, 0.0])
    fit = scipy.optimize.least_squares(residual, p0, method="lm")
    if not fit.success or not np.all(np.abs(fit.x[6:]) < 0.5):  # not a finger-like section
        return axis, center, radius, taper
    a, c = unpack(fit.x)
    return a, c, float(fit.x[4]), float(fit.x[5])


def _body_sections(r_slab) -> np.ndarray:
    """The sections of the finger's body: radius within 6 % of a line through the radii.

    The line is fitted to the sections within 6 % of the median radius, then again to those
    within 6 % of the line (a tapered body's radius changes along it; the cap's falls fast).
    """
    k = np.arange(len(r_slab), dtype=float)
    ok = np.isfinite(r_slab)
    med = np.nanmedian(r_slab)
    body = ok & (np.abs(r_slab - med) <= 0.06 * med)
    for _ in range(2):
        if body.sum() < 3:
            break
        slope, icpt = np.polyfit(k[body], r_slab[body], 1)
        line = icpt + slope * k
        body = ok & (np.abs(r_slab - line) <= 0.06 * np.abs(line))
    return body


def fit_sphere(xyz, *, axis, pad_direction=(0.0, 0.0, 1.0), n_max: int = 20000) -> SphereMap:
    """Least-squares sphere (algebraic fit ``|p|² = 2 c·p + k``) for fit-sphere unwrapping.

    Parameters
    ----------
    xyz : (N, 3) float
        Surface points, world mm.
    axis : (3,) float
        Finger axis towards the tip (e.g. of :func:`fit_cylinder`): the longitude runs around it.
    pad_direction : (3,) float
        Direction of longitude 0.
    n_max : int
        Points used for the fit (a random subset).

    Returns
    -------
    SphereMap

    Raises
    ------
    ValueError
        Fewer than 100 finite points, or the pad direction parallel to the axis.

    References
    ----------
    Wang, Lau and Hassebrook, *Fit-sphere unwrapping and performance analysis of 3D
    fingerprints*, Appl. Opt. 49(4), 592–600, 2010, doi:10.1364/AO.49.000592.
    """
    pts = _check_points(xyz, n_max)
    A = np.column_stack([2 * pts, np.ones(len(pts))])
    sol, *_ = np.linalg.lstsq(A, (pts**2).sum(axis=1), rcond=None)
    center = sol[:3]
    radius = float(np.sqrt(sol[3] + center @ center))
    a, n, _ = _frame(axis, pad_direction)
    return SphereMap(center=center, axis=a, pad=n, radius=radius)


@dataclass
class SurfaceMesh:
    """A coarse triangle mesh of the scanned skin, resampled on a cylinder-coordinate grid.

    Attributes
    ----------
    vertices : (V, 3) float64
        Mean world point of the samples in each grid cell, mm.
    faces : (F, 3) int64
    node : (V, 2) int64
        ``(row, col)`` of each vertex on the grid (row: cylinder ``t``, col: cylinder ``s``).
    grid_shape : (int, int)
    grid_origin : (2,) float
        Cylinder ``(s, t)`` of node ``[0, 0]``, mm.
    grid_mm : float
    piece : (V,) int64
        The connected piece of each vertex, numbered by size (0: the largest).
    """

    vertices: np.ndarray
    faces: np.ndarray
    node: np.ndarray
    grid_shape: tuple[int, int]
    grid_origin: np.ndarray
    grid_mm: float
    piece: np.ndarray | None = None
    extra: dict = field(default_factory=dict)

    def largest_piece(self) -> SurfaceMesh:
        """The mesh of the largest connected piece alone (itself when it has one piece)."""
        if self.piece is None or not self.piece.any():
            return self
        keep = self.piece == 0
        remap = np.full(len(keep), -1, dtype=np.int64)
        remap[keep] = np.arange(int(keep.sum()))
        faces = remap[self.faces]
        return SurfaceMesh(vertices=self.vertices[keep], faces=faces[(faces >= 0).all(axis=1)],
                           node=self.node[keep], grid_shape=self.grid_shape,
                           grid_origin=self.grid_origin, grid_mm=self.grid_mm,
                           piece=np.zeros(int(keep.sum()), dtype=np.int64))


def surface_mesh(xyz, cylinder: CylinderMap, *, grid_mm: float = 0.5,
                 min_samples: int = 3) -> SurfaceMesh:
    """Resample surface points on a regular grid of cylinder coordinates and mesh the grid.

    Far outliers (:func:`bulk_sphere`) are left out. Each grid cell's vertex is the mean of
    the points that fall in it (which averages out
    ridges, so the mesh is the skin's base surface); cells with fewer than `min_samples`
    points are empty. Neighbouring cells are joined by two triangles per square, triangles with
    an edge longer than 3 `grid_mm` are dropped (depth jumps), and the connected pieces with at
    least :data:`MIN_PIECE_FRACTION` of the largest one's triangles are kept (a band the
    cameras did not see, a shadow or a hair across the finger, parts the cap from the body:
    both are skin; specks of stray points are not).

    Parameters
    ----------
    xyz : (N, 3) float
        Surface points, world mm.
    cylinder : CylinderMap
        Its ``(s, t)`` are the grid's coordinates.
    grid_mm : float
        Cell size, mm.
    min_samples : int
        Fewest points in a cell for it to give a vertex.

    Returns
    -------
    SurfaceMesh

    Raises
    ------
    ValueError
        If fewer than 10 triangles remain, or the grid would exceed :data:`MAX_MESH_CELLS`.
    """
    if not (np.isfinite(grid_mm) and grid_mm > 0):
        raise ValueError(f"grid_mm: expected a positive cell size in mm, got {grid_mm!r}")
    pts = _check_points(xyz)
    st = cylinder(pts)
    if not np.isfinite(st).all():
        raise ValueError("cylinder: maps some points to non-finite print coordinates")
    origin = st.min(axis=0)
    size = st.max(axis=0) - origin
    cells = np.floor(size / grid_mm) + 2  # (gw, gh), as float: no overflow
    if cells[0] * cells[1] > MAX_MESH_CELLS:
        raise ValueError(f"xyz: the surface spans {size[0]:.4g} x {size[1]:.4g} mm in the "
                         f"cylinder's coordinates, {cells[0]:.4g} x {cells[1]:.4g} cells of "
                         f"{grid_mm:g} mm: more than {MAX_MESH_CELLS} (MAX_MESH_CELLS)")
    cr = np.floor((st - origin) / grid_mm).astype(np.int64)
    gw, gh = int(cr[:, 0].max()) + 2, int(cr[:, 1].max()) + 2
    cell = cr[:, 1] * gw + cr[:, 0]
    count = np.bincount(cell, minlength=gh * gw)
    mean: np.ndarray = np.stack(
        [np.bincount(cell, pts[:, k], minlength=gh * gw) for k in range(3)], -1)
    ok = count >= min_samples
    mean[ok] /= count[ok, None]
    index = np.full(gh * gw, -1, dtype=np.int64)
    index[ok] = np.arange(np.count_nonzero(ok))
    idx = index.reshape(gh, gw)
    tl, tr, bl, br = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    tris = np.concatenate([np.stack([tl, tr, bl], -1).reshape(-1, 3),
                           np.stack([tr, br, bl], -1).reshape(-1, 3)])
    tris = tris[(tris >= 0).all(axis=1)]
    verts = mean[ok]
    edge = np.max([np.linalg.norm(verts[tris[:, i]] - verts[tris[:, (i + 1) % 3]], axis=1)
                   for i in range(3)], axis=0)
    tris = tris[edge <= 3 * grid_mm]
    if len(tris) < 10:
        raise ValueError(f"xyz: the surface gives only {len(tris)} triangles at {grid_mm} mm; "
                         "too few points or too small a scan to unroll")
    n = len(verts)
    adj = scipy.sparse.coo_matrix(
        (np.ones(3 * len(tris)), (tris.ravel(), np.roll(tris, 1, axis=1).ravel())), (n, n))
    _, label = scipy.sparse.csgraph.connected_components(adj, directed=False)
    size = np.bincount(label[tris[:, 0]])
    kept = np.flatnonzero(size >= MIN_PIECE_FRACTION * size.max())
    tri_label = label[tris[:, 0]]
    inside = np.isin(tri_label, kept)
    tris, tri_label = tris[inside], tri_label[inside]
    used = np.unique(tris)
    remap = np.full(n, -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    rows, cols = np.divmod(np.flatnonzero(ok)[used], gw)
    # pieces numbered by size, 0 the largest
    rank = np.empty(label.max() + 1, dtype=np.int64)
    rank[kept[np.argsort(-size[kept], kind="stable")]] = np.arange(kept.size)
    return SurfaceMesh(vertices=verts[used], faces=remap[tris], node=np.stack([rows, cols], -1),
                       grid_shape=(gh, gw), grid_origin=origin, grid_mm=float(grid_mm),
                       piece=rank[label[used]])


def _fit_isometric(mesh: SurfaceMesh, cylinder: CylinderMap, *, iterations: int) -> IsometricMap:
    import igl

    st0 = cylinder(mesh.vertices)
    piece = np.zeros(len(st0), np.int64) if mesh.piece is None else mesh.piece
    data = igl.ARAPData()
    data.max_iter = int(iterations)
    # one vertex pinned per connected piece (near its middle) fixes its translation at its
    # cylinder coordinates (a piece parted from the others by a band the cameras did not see
    # would float free); the rotations stay free
    pins = np.array([np.flatnonzero(piece == k)[np.argmin(np.linalg.norm(
        st0[piece == k] - st0[piece == k].mean(axis=0), axis=1))]
        for k in range(int(piece.max()) + 1)], dtype=np.int32)
    igl.arap_precomputation(mesh.vertices, mesh.faces, 2, pins, data)
    uv = igl.arap_solve(st0[pins], data, st0)
    # ARAP is defined up to a rigid motion: turn each piece about its pin onto the cylinder
    # coordinates (Kabsch, no scale, no reflection), so that s still runs around the finger
    # and t towards the tip
    for k, pin in enumerate(pins):
        sel = piece == k
        mu, m0 = uv[sel].mean(axis=0), st0[sel].mean(axis=0)
        u, _, vt = np.linalg.svd((uv[sel] - mu).T @ (st0[sel] - m0))
        rot = u @ vt
        if np.linalg.det(rot) < 0:
            u[:, -1] *= -1
            rot = u @ vt
        uv[sel] = (uv[sel] - uv[pin]) @ rot + st0[pin]
    # the displacement on the grid nodes; empty nodes take their nearest node's value
    gh, gw = mesh.grid_shape
    disp = np.zeros((gh, gw, 2))
    have = np.zeros((gh, gw), dtype=bool)
    node = mesh.node
    # a vertex sits at its cell's mean point: give the displacement at the cell's node
    disp[node[:, 0], node[:, 1]] = uv - st0
    have[node[:, 0], node[:, 1]] = True
    _, (ri, ci) = scipy.ndimage.distance_transform_edt(~have, return_indices=True)
    disp = disp[ri, ci]
    # nodes are cell corners; vertices lie near cell centres: shift the origin by half a cell
    origin = mesh.grid_origin + 0.5 * mesh.grid_mm
    return IsometricMap(cylinder=cylinder, displacement=disp, grid_origin=origin,
                        grid_mm=mesh.grid_mm, iterations=int(iterations))


def map_distortion(flat, mesh: SurfaceMesh) -> dict:
    """Length and area distortion of a flattening map over a surface mesh.

    For each triangle, the singular values ``σ1 ≥ σ2`` of the map's Jacobian from the
    triangle's 3D plane to the print plane: the length distortion is ``max(|σ1 − 1|,
    |σ2 − 1|)`` (the worst stretch or shrink of a length on the skin) and the area distortion
    ``|σ1 σ2 − 1|``. Statistics are weighted by the triangles' 3D areas.

    Parameters
    ----------
    flat : callable
        A flattening map (``(N, 3) -> (N, 2)``, mm).
    mesh : SurfaceMesh

    Returns
    -------
    dict
        ``{"length": {"median", "p95", "max"}, "area": {...}}`` as fractions (0.01 = 1 %),
        plus ``"area_mm2"`` of the mesh.
    """
    v, f = mesh.vertices, mesh.faces
    uv = flat(v)
    p0, p1, p2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    e1, e2 = p1 - p0, p2 - p0
    # orthonormal basis of each triangle's plane
    b1 = e1 / np.linalg.norm(e1, axis=1, keepdims=True)
    nrm = np.cross(e1, e2)
    area = 0.5 * np.linalg.norm(nrm, axis=1)
    b2 = np.cross(nrm / (2 * area[:, None]), b1)
    X = np.stack([np.stack([np.einsum("ij,ij->i", e, b) for b in (b1, b2)], -1)
                  for e in (e1, e2)], -1)  # (F, 2, 2): columns are e1, e2 in-plane
    U = np.stack([uv[f[:, 1]] - uv[f[:, 0]], uv[f[:, 2]] - uv[f[:, 0]]], -1)
    J = U @ np.linalg.inv(X)
    sv = np.linalg.svd(J, compute_uv=False)
    length = np.max(np.abs(sv - 1), axis=1)
    areal = np.abs(sv[:, 0] * sv[:, 1] - 1)
    return {"length": _weighted_stats(length, area), "area": _weighted_stats(areal, area),
            "area_mm2": round(float(area.sum()), 2)}


def _weighted_stats(x, w) -> dict:
    median, p95 = weighted_quantiles(x, w, (0.5, 0.95))
    return {"median": round(float(median), 5), "p95": round(float(p95), 5),
            "max": round(float(x.max()), 5)}


#: The fingertip's cap on the pad's profile: the profile's points whose radius is below this
#: fraction of the profile's largest within :data:`CAP_REFERENCE_MM` below them are the cap's
#: (the cap's radius falls to zero; the body's does not)
CAP_RADIUS_FRACTION = 0.85
#: How far below a row of the profile its reference radius is looked for, mm: a tapered
#: body widens by up to 25 % over the 25 mm a scan sees (the random conditions' taper,
#: 1 % per mm), so the profile's widest row overall lies far down the finger, and a fraction
#: of it took the body's upper part for the cap (fitted semi-axes 1–3 mm off on tapered
#: fingers). 6 mm reaches the cap's base from where its radius has fallen to 0.85 on caps up
#: to 11 mm long (0.53 of the cap's length), and leaves the body out for tapers up to 2.9 %
#: per mm (1 / (1 + 6 τ) > 0.85)
CAP_REFERENCE_MM = 6.0
#: half-width of the band around the pad's centre line whose points make its profile, mm
PROFILE_BAND_MM = 1.5
#: Where the cap's fit is short of rows under :data:`CAP_RADIUS_FRACTION` (the scan stopped near
#: the cap's base), the cap is the profile's rows that fall this fraction below the body's
#: trend, the trend a line fitted between these distances below the profile's last row, mm
#: (the cap is at most ~12 mm long; the body's radius is linear in z there, tapered or not),
#: and its last row must lie :data:`CAP_BASE_DEPTH` below the trend
CAP_DEPARTURE = 0.02
BODY_TREND_MM = (12.0, 24.0)
CAP_BASE_DEPTH = 0.05
#: the most arc the fingertip's estimate may add beyond the scanned skin, mm (a cap seen only
#: at its base extrapolates badly; a fingertip's whole cap is about 10–13 mm of arc)
MAX_TIP_ARC_MM = 10.0


def fingertip(mesh: SurfaceMesh, cylinder: CylinderMap) -> dict:
    """The fingertip's apex, where the scanner did not see it: an ellipse fitted to the pad's cap.

    Cameras that look at the pad see the fingertip's cap at a grazing angle near its apex, so
    a scan stops a few millimetres short of the tip, by how much depending on the rig. A
    rolled print's length is counted from the tip (:data:`~nail2nail.unroll.rolled.
    DEFAULT_LENGTH_MM`), so the unseen arc is estimated: the pad's profile (median radius of
    the mesh vertices within :data:`PROFILE_BAND_MM` of the centre line, per row of the
    mesh) is, where its radius is below :data:`CAP_RADIUS_FRACTION` of its largest within
    :data:`CAP_REFERENCE_MM` below (the cap's base, on a tapered finger too), fitted by
    least squares with a conic of revolution ``r² = c₀ + c₁ z + c₂ z²`` (``c₂ < 0``: an ellipse
    of semi-axes ``(R, a)`` centred on the axis, the section of an ellipsoidal cap), and the
    arc from the last scanned point of the profile to the ellipse's apex (``r = 0``) is
    integrated. Where fewer than four rows are under that fraction (the scan stopped near the
    cap's base), the ellipse is fitted on the rows that fall away from the body's trend
    instead (:func:`_cap_base`).

    Parameters
    ----------
    mesh : SurfaceMesh
        :func:`surface_mesh` of the scan.
    cylinder : CylinderMap
        Its axis (towards the tip) and pad direction.

    Returns
    -------
    dict
        ``estimated`` (bool); when True: ``last_point`` (3,) world mm, the last scanned point
        of the pad's profile towards the tip, ``arc_mm`` (along the profile to the apex),
        ``axial_mm`` (along the axis), ``cap_semi_axes_mm`` ``[R, a]``, ``cap_points`` (rows
        of the profile fitted), ``last_angle_deg`` (the last point's elevation on the cap, 90°
        at the apex), ``fit`` (``"cap"`` or ``"cap base"``, the rows fitted); when False:
        ``reason``.
    """
    theta, z, r = cylinder.angles(mesh.vertices)
    near = np.abs(theta) * cylinder.radius <= PROFILE_BAND_MM
    if near.sum() < 4:
        return {"estimated": False, "reason": "no pad profile"}
    row = mesh.node[near, 0]
    rows, inverse = np.unique(row, return_inverse=True)
    # median radius per mesh row: sort by row, then by radius within it
    order = np.lexsort((r[near], inverse))
    counts = np.bincount(inverse)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    rad = 0.5 * (r[near][order][starts + (counts - 1) // 2] + r[near][order][starts + counts // 2])
    top = int(np.argmax(rad))
    # each row's reference: the profile's largest radius within CAP_REFERENCE_MM below it
    # (rows may have gaps: a running maximum over the row numbers, not the list)
    window = max(1, round(CAP_REFERENCE_MM / mesh.grid_mm))
    line = np.full(int(rows[-1] - rows[0]) + 1 + window, -np.inf)
    line[window + (rows - rows[0])] = rad
    reference = np.lib.stride_tricks.sliding_window_view(line, window + 1).max(axis=1)
    reference = reference[rows - rows[0]]
    # the cap: the profile's vertices beyond its widest row whose radius is below the fraction
    # of their row's reference (every vertex of the band, not the rows' medians: a vertex more
    # or less moves the fit less)
    beyond = np.zeros(rows.size, bool)
    beyond[top + 1:] = True
    cap = beyond[inverse] & (r[near] < CAP_RADIUS_FRACTION * reference[inverse])
    method = "cap"
    if np.unique(inverse[cap]).size < 4:
        # the scan stopped near the cap's base: the rows that fall away from the body's trend
        cap = _cap_base(z[near], r[near], inverse, rad)
        method = "cap base"
        if cap is None:
            return {"estimated": False, "reason": "the fingertip's cap was not scanned"}
    zc, rc = z[near][cap], r[near][cap]
    design = np.stack([np.ones(zc.size), zc, zc * zc], axis=1)
    (c0, c1, c2), *_ = np.linalg.lstsq(design, rc * rc, rcond=None)
    z0 = -c1 / (2 * c2) if c2 < 0 else np.nan
    r2 = c0 + c1 * z0 + c2 * z0 * z0 if c2 < 0 else np.nan
    if not (c2 < 0 and r2 > 0):
        return {"estimated": False, "reason": "the cap's profile is not an ellipse"}
    big_r, a = float(np.sqrt(r2)), float(np.sqrt(r2 / -c2))
    # the last scanned point of the profile: in its row nearest the tip, nearest the centre line
    pick = np.flatnonzero(near)[row == rows[-1]]
    pick = pick[np.argmin(np.abs(theta[pick]))]
    psi = float(np.arcsin(np.clip((z[pick] - z0) / a, -1.0, 1.0)))
    angles = np.linspace(psi, np.pi / 2, 256)
    speed = np.hypot(big_r * np.sin(angles), a * np.cos(angles))
    arc = float(np.sum(0.5 * (speed[1:] + speed[:-1]) * np.diff(angles)))
    if not arc <= MAX_TIP_ARC_MM:
        return {"estimated": False, "reason": f"the fitted cap adds {arc:.1f} mm of arc, more "
                                              f"than {MAX_TIP_ARC_MM:g} mm"}
    point = mesh.vertices[pick]
    return {"estimated": True, "last_point": point, "arc_mm": arc,
            "axial_mm": float(z0 + a - z[pick]), "cap_semi_axes_mm": [big_r, a],
            "cap_points": int(cap.sum()), "last_angle_deg": float(np.degrees(psi)),
            "fit": method}


def _cap_base(z, r, inverse, rad) -> np.ndarray | None:
    """The profile's vertices on the cap's base, or None: those of the rows towards the tip
    whose radius falls more than :data:`CAP_DEPARTURE` below the body's straight trend (a line
    fitted to the profile's rows :data:`BODY_TREND_MM` below its last one; a tapered body's
    radius changes linearly there, the cap's falls away). At least four rows, the last of
    them :data:`CAP_BASE_DEPTH` below the trend (a cap seen far enough to bend the fit)."""
    zrow = np.bincount(inverse, z) / np.bincount(inverse)
    near_end, far_end = BODY_TREND_MM
    body = (zrow <= zrow[-1] - near_end) & (zrow >= zrow[-1] - far_end)
    if body.sum() < 6:
        return None
    slope, icept = np.polyfit(zrow[body], rad[body], 1)
    below = rad < (1.0 - CAP_DEPARTURE) * (icept + slope * zrow)
    # the cap's rows: the run of departing rows that ends the profile
    run = np.flatnonzero(~below)
    first = int(run[-1]) + 1 if run.size else 0
    if rad.size - first < 4 or not rad[-1] < (1.0 - CAP_BASE_DEPTH) * (icept + slope * zrow[-1]):
        return None
    return inverse >= first


def fit_flattening(xyz, method: str = "isometric", *, tip_direction=(0.0, 1.0, 0.0),
                   pad_direction=(0.0, 0.0, 1.0), grid_mm: float = 0.5,
                   iterations: int = 30, pad_from_section: bool = False):
    """Fit the flattening map of `method` to surface points, and the coarse mesh it is judged on.

    Parameters
    ----------
    xyz : (N, 3) float
        Surface points, world mm (every camera's valid points).
    method : {"cylinder", "sphere", "rolled", "isometric"}
    tip_direction, pad_direction : (3,) float
        Rough directions of the fingertip and of the pad's viewer, world frame.
    grid_mm : float
        Cell size of the coarse mesh (:func:`surface_mesh`), mm.
    iterations : int
        ARAP iterations (``isometric``).
    pad_from_section : bool
        Turn `pad_direction` (then only a rough direction) onto the symmetry line of the
        finger's section (:func:`section_pad`).

    Returns
    -------
    flat : CylinderMap or SphereMap or RolledMap or IsometricMap
        The map, callable on world points ``(N, 3)`` → print plane ``(N, 2)``, mm.
    mesh : SurfaceMesh
        With ``extra["fingertip"]``, :func:`fingertip` of the mesh.

    Raises
    ------
    ValueError
        Unknown method, or too few points.
    """
    if method not in METHODS:
        raise ValueError(f"method: expected one of {', '.join(METHODS)}, got {method!r}")
    cyl = fit_cylinder(xyz, tip_direction=tip_direction, pad_direction=pad_direction,
                       elliptic=True)
    if pad_from_section:
        cyl, _ = section_pad(xyz, cyl)
    mesh = surface_mesh(xyz, cyl, grid_mm=grid_mm)
    mesh.extra["fingertip"] = fingertip(mesh, cyl)
    if method == "cylinder":
        return cyl, mesh
    if method == "sphere":
        return fit_sphere(xyz, axis=cyl.axis, pad_direction=cyl.pad), mesh
    if method == "rolled":
        return _fit_rolled(mesh, cyl), mesh
    return _fit_isometric(mesh, cyl, iterations=iterations), mesh
