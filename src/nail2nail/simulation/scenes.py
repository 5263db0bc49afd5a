"""Objects the virtual scanner sees: target cylinder, finger, plane, sphere, coin.

Every scene answers two questions, vectorised over rays and points:

- :meth:`Scene.intersect` — the distance ``t`` (mm) along each unit ray to the first surface hit
  (``inf`` for a miss). Analytic for the plane, sphere and cylinder; for the relief surfaces
  (finger, coin) the surface is the zero set of an implicit function ``f`` (positive outside),
  bracketed by marching along the ray from an analytic outer shell and refined by the Illinois
  (modified regula falsi) method to ``1e-10`` mm;
- :meth:`Scene.surface` — unit outward normals, albedo and surface parameters at surface points
  (the finger's parameters ``u, v`` are its rolled-print coordinates, mm).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from ..markers import TargetGeometry
from .fingerprint import Fingerprint, generate_fingerprint

__all__ = [
    "SCENES",
    "Coin",
    "CylinderTarget",
    "Finger",
    "Plane",
    "Scene",
    "Sphere",
    "SurfaceInfo",
    "make_scene",
]

SCENES = ("finger", "target", "plane", "sphere", "coin")


@dataclass
class SurfaceInfo:
    """Properties of surface points.

    Attributes
    ----------
    normal : (N, 3) float64
        Unit outward normals, world frame.
    albedo : (N,) float64
        Diffuse reflectance in ``[0, 1]``.
    params : dict of str to (N,) float64
        Scene-specific surface parameters (e.g. the finger's rolled-print ``u``, ``v`` in mm).
    """

    normal: np.ndarray
    albedo: np.ndarray
    params: dict = field(default_factory=dict)


class Scene:
    """Base class: an opaque diffuse surface."""

    name = "scene"

    def intersect(self, origin, directions) -> np.ndarray:  # pragma: no cover - abstract
        """Distance ``(N,)`` along unit rays ``origin + t · directions`` to the first hit, mm.

        `origin` is ``(3,)``, `directions` ``(N, 3)``; ``inf`` where a ray misses.
        """
        raise NotImplementedError

    def surface(self, xyz) -> SurfaceInfo:  # pragma: no cover - abstract
        """Normals, albedo and parameters at surface points ``(N, 3)``."""
        raise NotImplementedError

    def to_dict(self) -> dict:
        """JSON-ready description (name and parameters)."""
        return {"name": self.name}


def _smoothstep_edge(distance_inside, width):
    """0 outside, 1 inside, linear ramp of `width` mm across the edge (anti-aliased albedo)."""
    return np.clip(distance_inside / width + 0.5, 0.0, 1.0)


# -- analytic scenes ------------------------------------------------------------------------------
@dataclass
class Plane(Scene):
    """An infinite diffuse plane through `point` with unit `normal` (towards the viewers)."""

    point: tuple[float, float, float] = (0.0, 3.175, 0.0)
    normal: tuple[float, float, float] = (0.0, 0.0, 1.0)
    albedo: float = 0.8
    name = "plane"

    def __post_init__(self):
        n = np.asarray(self.normal, dtype=float)
        if n.shape != (3,) or not np.linalg.norm(n) > 0:
            raise ValueError(f"normal: expected a non-zero 3-vector, got {self.normal!r}")
        self._n = n / np.linalg.norm(n)
        self._p = np.asarray(self.point, dtype=float)

    def intersect(self, origin, directions):
        o = np.asarray(origin, dtype=float)
        d = np.asarray(directions, dtype=float)
        denom = d @ self._n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((self._p - o) @ self._n) / denom
        return np.where((t > 0) & np.isfinite(t), t, np.inf)

    def surface(self, xyz):
        xyz = np.asarray(xyz, dtype=float)
        normal = np.broadcast_to(self._n, xyz.shape).copy()
        return SurfaceInfo(normal, np.full(len(xyz), self.albedo))

    def to_dict(self):
        return {"name": self.name, "point": list(self.point), "normal": self._n.tolist(),
                "albedo": self.albedo}


@dataclass
class Sphere(Scene):
    """A diffuse sphere."""

    center: tuple[float, float, float] = (0.0, 3.175, 0.0)
    radius: float = 10.0
    albedo: float = 0.8
    name = "sphere"

    def intersect(self, origin, directions):
        o = np.asarray(origin, dtype=float) - np.asarray(self.center, dtype=float)
        d = np.asarray(directions, dtype=float)
        b = d @ o
        c = o @ o - self.radius**2
        disc = b * b - c
        with np.errstate(invalid="ignore"):
            t = -b - np.sqrt(disc)
        return np.where((disc > 0) & (t > 0), t, np.inf)

    def surface(self, xyz):
        n = (np.asarray(xyz, dtype=float) - np.asarray(self.center)) / self.radius
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        return SurfaceInfo(n, np.full(len(n), self.albedo))

    def to_dict(self):
        return {"name": self.name, "center": list(self.center), "radius": self.radius,
                "albedo": self.albedo}


@dataclass
class CylinderTarget(Scene):
    """The thesis's cylindrical calibration target with bright marks (:mod:`nail2nail.markers`).

    The marks are discs (the key a ring) drawn by arc length on the cylinder; the albedo ramps
    linearly over ``edge`` mm across mark edges.
    """

    geometry: TargetGeometry = field(default_factory=TargetGeometry)
    surface_albedo: float = 0.3
    mark_albedo: float = 0.85
    edge: float = 0.02
    name = "target"

    def intersect(self, origin, directions):
        o = np.asarray(origin, dtype=float)
        d = np.asarray(directions, dtype=float)
        a = d[:, 0] ** 2 + d[:, 2] ** 2
        b = o[0] * d[:, 0] + o[2] * d[:, 2]
        c = o[0] ** 2 + o[2] ** 2 - self.geometry.radius**2
        disc = b * b - a * c
        with np.errstate(invalid="ignore", divide="ignore"):
            t = (-b - np.sqrt(disc)) / a
        y = o[1] + t * d[:, 1]
        lo, hi = self.geometry.y_range
        return np.where((disc > 0) & (t > 0) & (y >= lo) & (y <= hi), t, np.inf)

    def surface(self, xyz):
        xyz = np.asarray(xyz, dtype=float)
        g = self.geometry
        normal = xyz * np.array([1.0, 0.0, 1.0])
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
        theta = np.arctan2(xyz[:, 0], xyz[:, 2])
        cols = np.radians(np.asarray(g.column_angles_deg))
        rows = np.asarray(g.row_y)
        # nearest column and row
        j = np.clip(np.searchsorted(cols, theta), 1, len(cols) - 1)
        j = np.where(np.abs(theta - cols[j - 1]) < np.abs(theta - cols[j]), j - 1, j)
        i = np.clip(np.searchsorted(rows, xyz[:, 1]), 1, len(rows) - 1)
        i = np.where(np.abs(xyz[:, 1] - rows[i - 1]) < np.abs(xyz[:, 1] - rows[i]), i - 1, i)
        s = g.radius * (theta - cols[j])
        r = np.hypot(s, xyz[:, 1] - rows[i])
        is_key = (i == g.key[0]) & (j == g.key[1])
        plain = _smoothstep_edge(g.mark_diameter / 2 - r, self.edge)
        ring = np.minimum(
            _smoothstep_edge(g.key_outer_diameter / 2 - r, self.edge),
            _smoothstep_edge(r - g.key_inner_diameter / 2, self.edge),
        )
        cover = np.where(is_key, ring, plain)
        albedo = self.surface_albedo + (self.mark_albedo - self.surface_albedo) * cover
        return SurfaceInfo(normal, albedo, {"theta": theta, "y": xyz[:, 1].copy()})

    def to_dict(self):
        g = self.geometry
        return {"name": self.name, "radius": g.radius,
                "column_angles_deg": list(g.column_angles_deg), "row_y": list(g.row_y),
                "mark_diameter": g.mark_diameter, "key": list(g.key),
                "key_outer_diameter": g.key_outer_diameter,
                "key_inner_diameter": g.key_inner_diameter,
                "surface_albedo": self.surface_albedo, "mark_albedo": self.mark_albedo}


# -- implicit (relief) scenes ---------------------------------------------------------------------
def _illinois(f, origin, d, a, b, fa, fb, *, tol=1e-10, max_iter=80):
    """Root of ``f(origin + t d)`` in brackets ``[a, b]`` with ``fa > 0 >= fb`` (vectorised)."""
    a, b, fa, fb = a.copy(), b.copy(), fa.copy(), fb.copy()
    side = np.zeros(len(a), dtype=int)
    active = np.ones(len(a), dtype=bool)
    for it in range(max_iter):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        ai, bi, fai, fbi = a[idx], b[idx], fa[idx], fb[idx]
        with np.errstate(invalid="ignore", divide="ignore"):
            c = (ai * fbi - bi * fai) / (fbi - fai)
        if it % 4 == 3:  # a bisection now and then guarantees convergence on kinked functions
            c = 0.5 * (ai + bi)
        c = np.where(np.isfinite(c) & (c > ai) & (c < bi), c, 0.5 * (ai + bi))
        fc = f(origin + c[:, None] * d[idx])
        pos = fc > 0
        # replace the endpoint with the same sign; halve the retained one if it repeats
        s = side[idx]
        new_a = np.where(pos, c, ai)
        new_fa = np.where(pos, fc, np.where(s == -1, fai * 0.5, fai))
        new_b = np.where(pos, bi, c)
        new_fb = np.where(pos, np.where(s == 1, fbi * 0.5, fbi), fc)
        side[idx] = np.where(pos, 1, -1)
        a[idx], fa[idx], b[idx], fb[idx] = new_a, new_fa, new_b, new_fb
        done = (np.abs(b[idx] - a[idx]) < tol) | (fc == 0)
        active[idx[done]] = False
    return np.where(fb == 0, b, np.where(np.abs(fa) < np.abs(fb), a, b))


def _march(f, origin, d, t_start, t_end, step):
    """First sign change of ``f`` from positive to non-positive along rays, refined to 1e-10 mm.

    Returns ``t (N,)`` with ``inf`` where ``f`` stays positive on ``[t_start, t_end]``.
    """
    n = len(d)
    t_hit = np.full(n, np.inf)
    idx = np.flatnonzero(np.isfinite(t_start) & np.isfinite(t_end) & (t_end > t_start))
    t0 = t_start[idx]
    f0 = f(origin + t0[:, None] * d[idx])
    # rays already inside at the start (should not happen with a proper shell): treat as hits
    inside = f0 <= 0
    t_hit[idx[inside]] = t0[inside]
    keep = ~inside
    idx, t0, f0 = idx[keep], t0[keep], f0[keep]
    brackets = []
    while idx.size:
        t1 = np.minimum(t0 + step, t_end[idx])
        f1 = f(origin + t1[:, None] * d[idx])
        crossed = f1 <= 0
        if np.any(crossed):
            brackets.append((idx[crossed], t0[crossed], t1[crossed], f0[crossed], f1[crossed]))
        go = ~crossed & (t1 < t_end[idx])
        idx, t0, f0 = idx[go], t1[go], f1[go]
    for ids, a, b, fa, fb in brackets:
        t_hit[ids] = _illinois(f, origin, d[ids], a, b, fa, fb)
    return t_hit


def _ellipsoid_t(o, d, axes, center):
    """Entry and exit ``t`` of rays with an axis-aligned ellipsoid (NaN for a miss)."""
    s = 1.0 / np.asarray(axes, dtype=float)
    oo = (o - center) * s
    dd = d * s
    a = np.einsum("ij,ij->i", dd, dd)
    b = dd @ oo
    c = oo @ oo - 1.0
    disc = b * b - a * c
    with np.errstate(invalid="ignore"):
        root = np.sqrt(disc)
    return (-b - root) / a, (-b + root) / a


def _elliptic_cylinder_t(o, d, ax, az):
    """Entry and exit ``t`` of rays with the infinite cylinder ``x²/ax² + z²/az² = 1``."""
    dx, dz = d[:, 0] / ax, d[:, 2] / az
    ox, oz = o[0] / ax, o[2] / az
    a = dx * dx + dz * dz
    b = ox * dx + oz * dz
    c = ox * ox + oz * oz - 1.0
    disc = b * b - a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        root = np.sqrt(disc)
        return (-b - root) / a, (-b + root) / a


def _normal_from_gradient(f, xyz, eps=1e-5):
    grad = np.empty_like(xyz)
    for k in range(3):
        e = np.zeros(3)
        e[k] = eps
        grad[:, k] = (f(xyz + e) - f(xyz - e)) / (2 * eps)
    return grad / np.linalg.norm(grad, axis=-1, keepdims=True)


@functools.lru_cache(maxsize=4)
def _cached_fingerprint(u_range, v_range, center, seed, pattern) -> Fingerprint:
    # growing a print takes a few seconds: scenes with the same parameters share it (read-only)
    return generate_fingerprint(u_range=u_range, v_range=v_range, center=center, seed=seed,
                                pattern=pattern)


@dataclass
class Finger(Scene):
    """A fingertip with friction-ridge relief, pad towards ``+Z`` (the centre camera).

    Base shape: the elliptic cylinder ``x²/ax² + z²/az² = 1`` for ``y ≤ y0`` capped by the
    half-ellipsoid of semi-axes ``(ax, ay, az)`` for ``y > y0`` (tip at ``y0 + ay``). With
    scaled coordinates ``q = (x/ax, max(y − y0, 0)/ay, z/az)`` the base is ``|q| = 1`` and
    ``D = (|q| − 1) / |∇|q||`` approximates the signed distance to it. The surface is
    ``f = D − h(u, v) = 0`` with the ridge height ``h`` of the fingerprint at the rolled-print
    coordinates of the point:

    - ``φ = atan2(qx, qz)`` (angle around the finger from the pad), ``ψ = asin(q̂y)`` (0 on the
      body, up to 90° at the tip), ``q̂ = q / |q|``;
    - ``u = cos ψ · S(φ)`` with ``S`` the arc length of the cross-section ellipse from the pad
      centre (exact arc length around the body), ``v = y`` on the body and
      ``v = y0 + M(ψ)`` on the cap, ``M`` the arc length of the pad meridian (ellipse ``az, ay``).

    Ridges are relief of ``relief_height`` mm peak to valley; the albedo is
    ``skin_albedo · (1 + albedo_contrast · r)`` with ``r ∈ [−1, 1]`` the ridge field (+1 on
    ridge crests).

    The print: `fingerprint` if given; else `print_image` (a real print, ``(H, W)`` uint8 in
    the legacy convention, ridges dark, at `print_ppi`) centred on the pad centre
    ``(u, v) = (0, y0 − 2)`` (:meth:`Fingerprint.from_image`, flat skin beyond it); else a
    synthetic print of `pattern` (by default drawn by `seed`) with its core near the pad
    centre. Print images (``rolled_print``) are in the legacy convention:
    :meth:`legacy_print_pixel` maps ``(u, v)`` to ``(col, row)``.
    """

    fingerprint: Fingerprint | None = None
    ax: float = 8.5
    az: float = 7.0
    ay: float = 8.0
    y0: float = 6.0
    relief_height: float = 0.05
    skin_albedo: float = 0.7
    albedo_contrast: float = 0.15
    seed: int = 0
    march_step: float = 0.03
    pattern: str | None = None
    print_image: np.ndarray | None = field(default=None, repr=False, compare=False)
    print_ppi: float = 500.0
    name = "finger"

    def __post_init__(self):
        if not 0 <= self.relief_height < 0.5:
            raise ValueError(f"relief_height: expected 0 <= h < 0.5 mm, got {self.relief_height}")
        phi = np.linspace(-np.pi, np.pi, 8193)
        ds = np.hypot(self.ax * np.cos(phi), self.az * np.sin(phi))
        s = np.concatenate([[0], np.cumsum(0.5 * (ds[1:] + ds[:-1]) * np.diff(phi))])
        self._phi, self._s = phi, s - np.interp(0.0, phi, s)
        psi = np.linspace(0, np.pi / 2, 2049)
        dm = np.hypot(self.ay * np.cos(psi), self.az * np.sin(psi))
        self._psi = psi
        self._m = np.concatenate([[0], np.cumsum(0.5 * (dm[1:] + dm[:-1]) * np.diff(psi))])
        if self.fingerprint is None and self.print_image is not None:
            self.fingerprint = Fingerprint.from_image(
                self.print_image, ppi=self.print_ppi, center_uv=self.pad_center)
        elif self.fingerprint is None:
            half_u = float(self._s[-1]) + 1.0
            self.fingerprint = _cached_fingerprint(
                (-half_u, half_u), (-32.0, self.y0 + float(self._m[-1]) + 1.0),
                self.pad_center, int(self.seed), self.pattern,
            )
        self._hmax = self.relief_height / 2

    # rolled-print coordinates --------------------------------------------------------------
    def _scaled(self, xyz):
        x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        qy = np.maximum(y - self.y0, 0.0) / self.ay
        return x / self.ax, qy, z / self.az

    def print_coordinates(self, xyz) -> tuple[np.ndarray, np.ndarray]:
        """Rolled-print coordinates ``u, v`` (mm) of points ``(N, 3)`` (see the class doc)."""
        xyz = np.asarray(xyz, dtype=float)
        qx, qy, qz = self._scaled(xyz)
        norm = np.sqrt(qx * qx + qy * qy + qz * qz)
        psi = np.arcsin(np.clip(qy / np.maximum(norm, 1e-12), 0.0, 1.0))
        phi = np.arctan2(qx, qz)
        u = np.cos(psi) * np.interp(phi, self._phi, self._s)
        v = np.where(qy > 0, self.y0 + np.interp(psi, self._psi, self._m), xyz[:, 1])
        return u, v

    @property
    def pad_center(self) -> tuple[float, float]:
        """``(u, v)`` of the pad centre, mm: ``(0, y0 − 2)``, where prints are centred."""
        return 0.0, self.y0 - 2.0

    def legacy_print_pixel(self, u, v) -> tuple[np.ndarray, np.ndarray]:
        """``(col, row)`` in :meth:`rolled_print` of rolled-print coordinates ``(u, v)`` mm.

        Legacy convention (the mirror of the pad view, tip up), pixel centres at integers:
        ``col = (u0 − u) / pitch``, ``row = (v0 − v) / pitch`` with ``u0``, ``v0``, ``pitch``
        of :attr:`fingerprint` (``truth/fingerprint.json``: ``u_of_col0_mm``,
        ``v_of_row0_mm``, ``pitch_mm``). Use with :meth:`print_coordinates` to find the truth
        pixel of a surface point.

        Examples
        --------
        >>> from nail2nail.simulation.fingerprint import Fingerprint
        >>> import numpy as np
        >>> finger = Finger(fingerprint=Fingerprint.from_image(np.zeros((5, 5), np.uint8)))
        >>> [float(x) for x in finger.legacy_print_pixel(0.0508, 0.0)]
        [1.0, 2.0]
        """
        return self.fingerprint.pixel_from_uv(u, v)

    def uv_from_legacy_pixel(self, col, row) -> tuple[np.ndarray, np.ndarray]:
        """Rolled-print coordinates ``(u, v)`` mm of :meth:`rolled_print` pixels (inverse)."""
        return self.fingerprint.uv_from_pixel(col, row)

    def rolled_print(self) -> tuple[np.ndarray, np.ndarray]:
        """Ground-truth rolled print: ``(image (H, W) uint8, mask (H, W) bool)``.

        The fingerprint laid flat by arc length (``u``, ``v``) in the legacy convention of
        inked rolls and live scans: the mirror of the pad seen from outside, fingertip up
        (:meth:`legacy_print_pixel`), ridges dark on white. A synthetic print is 500 ppi and
        white where ``mask`` is False; a print from an image is that image unchanged.
        ``mask`` marks the pixels that map onto the finger surface.
        """
        fp = self.fingerprint
        h, w = fp.shape
        u, v = fp.uv_from_pixel(np.arange(w)[None, :], np.arange(h)[:, None])
        s_max = float(self._s[-1])
        dv = v - self.y0
        psi = np.interp(np.clip(dv, 0, None), self._m, self._psi)
        half = np.where(dv <= 0, s_max, np.cos(psi) * s_max)
        mask = (np.abs(u) <= half) & (dv <= self._m[-1])
        if fp.image is not None:
            return fp.image.copy(), mask
        image = np.where(mask, np.rint(127.5 - 127.5 * fp.ridges), 255).astype(np.uint8)
        return image, mask

    def _base_distance(self, xyz):
        qx, qy, qz = self._scaled(xyz)
        norm = np.sqrt(qx * qx + qy * qy + qz * qz)
        gx, gy, gz = qx / self.ax, qy / self.ay, qz / self.az
        gnorm = np.sqrt(gx * gx + gy * gy + gz * gz) / np.maximum(norm, 1e-12)
        return (norm - 1.0) / np.maximum(gnorm, 1e-12)

    def implicit(self, xyz) -> np.ndarray:
        """``f (N,)``: positive outside the finger, zero on its surface, ~mm near it."""
        xyz = np.asarray(xyz, dtype=float)
        u, v = self.print_coordinates(xyz)
        r = self.fingerprint.sample(u, v)
        return self._base_distance(xyz) - self._hmax * r

    def _shell_t(self, o, d, offset):
        """Entry/exit of the base shape grown by `offset` mm (approximately: axes + offset)."""
        ax, ay, az = self.ax + offset, self.ay + offset, self.az + offset
        c0, c1 = _elliptic_cylinder_t(o, d, ax, az)
        e0, e1 = _ellipsoid_t(o, d, (ax, ay, az), np.array([0.0, self.y0, 0.0]))
        y_c0 = o[1] + c0 * d[:, 1]
        y_c1 = o[1] + c1 * d[:, 1]
        entry = np.where(y_c0 <= self.y0, c0, np.inf)
        entry = np.fmin(entry, np.where(np.isfinite(e0), e0, np.inf))
        exit_ = np.where(y_c1 <= self.y0, c1, -np.inf)
        exit_ = np.fmax(exit_, np.where(np.isfinite(e1), e1, -np.inf))
        entry = np.where(np.isnan(entry), np.inf, entry)
        return entry, exit_

    def intersect(self, origin, directions):
        o = np.asarray(origin, dtype=float)
        d = np.asarray(directions, dtype=float)
        margin = 2 * self._hmax + 0.02
        t0, t1 = self._shell_t(o, d, margin)
        hit = np.isfinite(t0) & (t1 > t0) & (t1 > 0)
        t0 = np.where(hit, np.maximum(t0, 0.0), np.inf)
        i0, _ = self._shell_t(o, d, -margin)
        t_end = np.where(np.isfinite(i0) & hit, np.minimum(i0, t1), t1)
        t_end = np.where(hit, t_end, np.inf)
        return _march(self.implicit, o, d, t0, t_end, self.march_step)

    def surface(self, xyz):
        xyz = np.asarray(xyz, dtype=float)
        normal = _normal_from_gradient(self.implicit, xyz)
        u, v = self.print_coordinates(xyz)
        r = self.fingerprint.sample(u, v)
        albedo = np.clip(self.skin_albedo * (1 + self.albedo_contrast * r), 0, 1)
        return SurfaceInfo(normal, albedo, {"u": u, "v": v})

    def to_dict(self):
        return {"name": self.name, "ax": self.ax, "ay": self.ay, "az": self.az, "y0": self.y0,
                "relief_height": self.relief_height, "skin_albedo": self.skin_albedo,
                "albedo_contrast": self.albedo_contrast, "seed": self.seed,
                "pad_center": list(self.pad_center),
                "fingerprint": self.fingerprint.describe()}


@dataclass
class Coin(Scene):
    """A coin-like relief disc lying on a background plane ``z = 0``, face towards ``+Z``.

    Height field ``z = H(x, y)``: a disc of `radius` mm and `thickness` mm with bevelled edge
    (`bevel` mm wide), a raised rim and a raised five-pointed star of `relief` mm on its face;
    the background plane is darker. Intersection: march from ``z = max H`` down to ``z = 0``.
    """

    center: tuple[float, float] = (0.0, 3.175)
    radius: float = 12.0
    thickness: float = 1.0
    bevel: float = 0.3
    relief: float = 0.2
    albedo: float = 0.7
    background_albedo: float = 0.25
    march_step: float = 0.03
    name = "coin"

    def height(self, x, y) -> np.ndarray:
        """Height ``H (N,)`` of the coin surface above the plane ``z = 0``, mm."""
        dx, dy = x - self.center[0], y - self.center[1]
        r = np.hypot(dx, dy)
        body = self.thickness * np.clip((self.radius - r) / self.bevel, 0.0, 1.0)
        ramp = 0.15
        rim = np.clip((r - (self.radius - 1.2)) / ramp, 0, 1) * np.clip(
            (self.radius - self.bevel - r) / ramp, 0, 1)
        ang = np.arctan2(dy, dx)
        star_r = 0.5 * self.radius * (0.6 + 0.4 * np.cos(5 * ang)) ** 2 + 1.0
        star = np.clip((star_r - r) / 0.4, 0.0, 1.0)
        rings = 0.5 + 0.5 * np.cos(2 * np.pi * r / 0.8)
        field_ = 0.25 * rings * (r > star_r + 0.4) * (r < self.radius - 1.5)
        return body + self.relief * (rim + star + field_) * (r < self.radius)

    def implicit(self, xyz):
        xyz = np.asarray(xyz, dtype=float)
        return xyz[:, 2] - self.height(xyz[:, 0], xyz[:, 1])

    def intersect(self, origin, directions):
        o = np.asarray(origin, dtype=float)
        d = np.asarray(directions, dtype=float)
        top = self.thickness + self.relief * 1.5 + 0.01
        with np.errstate(divide="ignore", invalid="ignore"):
            t_top = (top - o[2]) / d[:, 2]
            t_bot = (-1e-9 - o[2]) / d[:, 2]
        ok = (d[:, 2] < 0) & (t_bot > 0)
        t0 = np.where(ok, np.maximum(t_top, 0), np.inf)
        t1 = np.where(ok, t_bot, np.inf)
        return _march(self.implicit, o, d, t0, t1, self.march_step)

    def surface(self, xyz):
        xyz = np.asarray(xyz, dtype=float)
        normal = _normal_from_gradient(self.implicit, xyz)
        on_coin = np.hypot(xyz[:, 0] - self.center[0], xyz[:, 1] - self.center[1]) < self.radius
        albedo = np.where(on_coin, self.albedo, self.background_albedo)
        return SurfaceInfo(normal, albedo, {"height": xyz[:, 2].copy()})

    def to_dict(self):
        return {"name": self.name, "center": list(self.center), "radius": self.radius,
                "thickness": self.thickness, "relief": self.relief}


def make_scene(name: str, *, rig=None, seed: int = 0, **options) -> Scene:
    """Build a scene by name: ``finger``, ``target``, ``plane``, ``sphere`` or ``coin``.

    Parameters
    ----------
    name : str
    rig : Rig, optional
        For the plane's default pose: facing the projector (normal towards its centre), through
        the axis point ``(0, 3.175, 0)``, so that it fills the projector's view (distortion
        estimation). Without a rig the plane faces ``+Z``.
    seed : int
        Fingerprint seed (finger).
    **options
        Keyword arguments of the scene class (e.g. ``point=``, ``normal=`` for the plane;
        ``pattern=``, ``print_image=``, ``print_ppi=`` for the finger).

    Examples
    --------
    >>> make_scene("sphere").radius
    10.0
    """
    if name == "finger":
        return Finger(seed=seed, **options)
    if name == "target":
        return CylinderTarget(**options)
    if name == "sphere":
        return Sphere(**options)
    if name == "coin":
        return Coin(**options)
    if name == "plane":
        if rig is not None and "normal" not in options:
            point = np.asarray(options.get("point", (0.0, 3.175, 0.0)), dtype=float)
            n = rig.projector.center - point
            options["normal"] = tuple(float(v) for v in n / np.linalg.norm(n))
        return Plane(**options)
    raise ValueError(f"scene: expected one of {', '.join(SCENES)}, got {name!r}")
