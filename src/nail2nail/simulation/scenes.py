"""Objects the virtual scanner sees: target cylinder, finger, plane, sphere, coin, board.

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
import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nail2nail.calibration.boards import Board, default_board
from nail2nail.calibration.markers import TargetGeometry
from nail2nail.io._atomic import write_npz
from nail2nail.io._npz import read_npz
from nail2nail.simulation.fingerprint import Fingerprint, generate_fingerprint, legacy_geometry

__all__ = [
    "SCENES",
    "BoardScene",
    "Coin",
    "CylinderTarget",
    "Finger",
    "Plane",
    "Scene",
    "Sphere",
    "SurfaceInfo",
    "make_scene",
]

SCENES = ("finger", "target", "plane", "sphere", "coin", "board")


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
    """The thesis's cylindrical calibration target with bright marks
    (:mod:`nail2nail.calibration.markers`).

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


def _default_board() -> Board:
    return default_board("checkerboard")


def _rotation_from_vector(rvec_deg) -> np.ndarray:
    """Rotation matrix ``(3, 3)`` of a rotation vector in degrees (axis · angle, Rodrigues)."""
    r = np.radians(np.asarray(rvec_deg, dtype=float))
    angle = float(np.linalg.norm(r))
    if angle < 1e-15:
        return np.eye(3)
    k = r / angle
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx


#: board frame -> world frame of the rest pose: printed face towards +Z, rows down world -Y
BOARD_REST_ROTATION = np.diag([1.0, -1.0, -1.0])


@dataclass
class BoardScene(Scene):
    """A printed planar calibration board (:class:`nail2nail.calibration.boards.Board`), a flat
    sheet.

    Pose: ``pose = (rx, ry, rz, tx, ty, tz)``, a rotation vector in degrees (axis times angle,
    world frame) and the world position of the sheet's centre in mm. At rest (rotation 0) the
    printed face looks towards ``+Z`` (the centre camera) and the board stands upright as the
    cameras see it: board ``x`` along world ``+X``, board ``y`` (down the sheet) along world
    ``−Y``. So a board point ``p`` (board frame, mm) is at
    ``X = R_world_board p + t_world_board`` with ``R_world_board = R(r) · diag(1, −1, −1)`` and
    ``t_world_board = t − R_world_board c`` (``c`` the sheet centre, :attr:`Board.center`);
    :attr:`R_world_board`, :attr:`t_world_board` give them, and :meth:`to_dict` records both in
    ``capture.json`` (``scene``).

    The sheet (pattern plus white margin, :meth:`Board.extent`) is opaque from both sides; rays
    beyond it miss. Surface parameters: the board coordinates ``x``, ``y`` (mm) of every hit
    (``truth/<cam>.npz`` ``param_x``, ``param_y``).

    Anti-aliasing: the renderer samples one point per camera pixel, so the albedo is the
    printed board's (:meth:`Board.albedo`) box-filtered over a pixel's footprint on the board.
    With `viewers` (``((x, y, z), focal_px)`` of each camera; :func:`make_scene` takes them
    from the rig) the box's side at a point is the largest, over the cameras, of the long side
    of that camera's pixel footprint there, ``distance / (focal · cos(obliquity))`` (obliquity
    capped at 75°), and at least `footprint` mm; without, it is `footprint`. So an oblique
    camera integrates its pixels' area (point samples of an under-filtered board leave
    aliasing, 0.1–0.2 px of corner noise at 60° obliquity), while a camera facing the board
    sees it blurred by up to ``1 / cos`` of the most oblique camera's angle (2.3 pixels at
    64°; detection there stays within 0.02 px).
    """

    board: Board = field(default_factory=_default_board)
    pose: tuple[float, float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 3.175, 0.0)
    footprint: float = 0.03
    viewers: tuple = ()
    name = "board"

    def __post_init__(self):
        if not isinstance(self.board, Board):
            raise TypeError(f"board: expected a nail2nail.calibration.boards.Board, got "
                            f"{type(self.board).__name__}")
        pose = np.asarray(self.pose, dtype=float)
        if pose.shape != (6,) or not np.all(np.isfinite(pose)):
            raise ValueError(f"pose: expected 6 finite numbers (rx ry rz in degrees, tx ty tz in "
                             f"mm), got {self.pose!r}")
        if not (np.isfinite(self.footprint) and self.footprint >= 0):
            raise ValueError(f"footprint: expected a length >= 0 mm, got {self.footprint!r}")
        self.pose = tuple(float(v) for v in pose)
        self._R = _rotation_from_vector(pose[:3]) @ BOARD_REST_ROTATION
        self._t = pose[3:] - self._R @ self.board.center
        self._n = -self._R[:, 2]  # the printed face looks towards -z of the board
        try:
            self.viewers = tuple((tuple(float(v) for v in c), float(f)) for c, f in self.viewers)
        except (TypeError, ValueError):
            raise ValueError(f"viewers: expected ((x, y, z), focal_px) pairs, got "
                             f"{self.viewers!r}") from None
        if any(len(c) != 3 or not f > 0 for c, f in self.viewers):
            raise ValueError("viewers: expected ((x, y, z), focal_px > 0) pairs")

    def pixel_footprint(self, xyz) -> np.ndarray:
        """Side ``(N,)`` of the albedo's box filter at world points ``(N, 3)`` on the board, mm."""
        xyz = np.asarray(xyz, dtype=float)
        size = np.full(len(xyz), float(self.footprint))
        for centre, focal in self.viewers:
            view = np.asarray(centre) - xyz
            distance = np.linalg.norm(view, axis=-1)
            cos = np.abs(view @ self._n) / distance
            size = np.maximum(size, distance / (focal * np.maximum(cos, np.cos(np.radians(75)))))
        return size

    @property
    def R_world_board(self) -> np.ndarray:
        """Rotation ``(3, 3)`` from the board frame to the world frame."""
        return self._R.copy()

    @property
    def t_world_board(self) -> np.ndarray:
        """World position ``(3,)`` of the board frame's origin, mm."""
        return self._t.copy()

    def board_from_world(self, xyz) -> np.ndarray:
        """Board-frame coordinates ``(N, 3)`` of world points ``(N, 3)``, mm."""
        return (np.asarray(xyz, dtype=float) - self._t) @ self._R

    def world_from_board(self, points) -> np.ndarray:
        """World coordinates ``(N, 3)`` of board-frame points ``(N, 3)`` (e.g.
        :meth:`Board.object_points`), mm."""
        return np.asarray(points, dtype=float) @ self._R.T + self._t

    def intersect(self, origin, directions):
        o = np.asarray(origin, dtype=float)
        d = np.asarray(directions, dtype=float)
        denom = d @ self._n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((self._t - o) @ self._n) / denom
        hit = (t > 0) & np.isfinite(t)
        t = np.where(hit, t, np.inf)
        local = self.board_from_world(o + np.where(hit, t, 0.0)[:, None] * d)
        x0, x1, y0, y1 = self.board.extent()
        on_sheet = ((local[:, 0] >= x0) & (local[:, 0] <= x1)
                    & (local[:, 1] >= y0) & (local[:, 1] <= y1))
        return np.where(hit & on_sheet, t, np.inf)

    def surface(self, xyz):
        xyz = np.asarray(xyz, dtype=float)
        local = self.board_from_world(xyz)
        normal = np.broadcast_to(self._n, xyz.shape).copy()
        albedo = self.board.albedo(local[:, 0], local[:, 1],
                                   footprint=self.pixel_footprint(xyz))
        return SurfaceInfo(normal, albedo, {"x": local[:, 0].copy(), "y": local[:, 1].copy()})

    def to_dict(self):
        return {"name": self.name, "board": self.board.to_dict(),
                "pose": {"rotation_vector_deg": list(self.pose[:3]),
                         "center_mm": list(self.pose[3:])},
                "R_world_board": self._R.tolist(), "t_world_board": self._t.tolist(),
                "footprint_mm": self.footprint,
                "viewers": [{"center": list(c), "focal_px": f} for c, f in self.viewers]}


def board_footprint(rig, point) -> float:
    """Largest camera pixel footprint (mm) of a rig at a world point, facing the camera."""
    point = np.asarray(point, dtype=float)
    sizes = [np.linalg.norm(cam.center - point) / min(cam.K[0, 0], cam.K[1, 1])
             for cam in rig.cameras]
    return float(max(sizes))


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


def _finger_rotation(rotation_deg) -> np.ndarray:
    """``R = R_z(yaw) R_x(tilt) R_y(roll)`` of ``(tilt, roll, yaw)`` in degrees (local → world)."""
    tilt, roll, yaw = np.radians(np.asarray(rotation_deg, dtype=float))
    c, s = np.cos(tilt), np.sin(tilt)
    rx = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    c, s = np.cos(roll), np.sin(roll)
    ry = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    c, s = np.cos(yaw), np.sin(yaw)
    rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return rz @ rx @ ry


#: Environment variable naming a directory where synthetic prints are kept between processes
#: (:func:`_cached_fingerprint`); unset: none are kept
PRINT_CACHE_ENV = "NAIL2NAIL_FINGERPRINT_CACHE"


@functools.lru_cache(maxsize=4)
def _cached_fingerprint(u_range, v_range, center, seed, pattern) -> Fingerprint:
    """The synthetic print of these parameters, grown once per process (about 10 s for a
    finger's), and once for all processes when ``$NAIL2NAIL_FINGERPRINT_CACHE`` names a
    directory: the print is stored there (``.npz``, keyed by the parameters and the synthesis
    code's own bytes, so a changed synthesis never reads an old print) and read back."""
    store = os.environ.get(PRINT_CACHE_ENV)
    path = None
    if store:
        code = Path(generate_fingerprint.__code__.co_filename).read_bytes()
        key = hashlib.sha256(repr((u_range, v_range, center, seed, pattern)).encode() + code)
        path = Path(store) / f"print-{key.hexdigest()[:24]}.npz"
        if path.is_file():
            try:
                return _read_print(path)
            except (OSError, ValueError):
                pass  # a damaged entry is grown again and replaced
    fp = generate_fingerprint(u_range=u_range, v_range=v_range, center=center, seed=seed,
                              pattern=pattern)
    if path is not None:
        _write_print(path, fp)
    return fp


_PRINT_ARRAYS = ("ridges", "orientation", "minutiae", "cores", "deltas")


def _write_print(path: Path, fp: Fingerprint) -> None:
    """Store a grown print (its arrays and scalars; about 8 MB for a finger's) atomically
    (:func:`nail2nail.io._atomic.write_npz`); the upsampled relief is computed again when it
    is read (about 2 s, four times the bytes)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    write_npz(path, {**{k: getattr(fp, k) for k in _PRINT_ARRAYS},
                     "scalars": np.array([fp.u0, fp.v0, fp.pitch, fp.ridge_period, fp.seed,
                                          fp._pad], dtype=np.float64),
                     "pattern": np.array(fp.pattern)}, compress=False)


def _read_print(path: Path) -> Fingerprint:
    data = read_npz(path, required=(*_PRINT_ARRAYS, "scalars", "pattern"),
                    what="synthetic print")
    u0, v0, pitch, period, seed, pad = data["scalars"]
    if int(pad):  # a print of an image with flat skin beyond: never grown here
        raise ValueError(f"{path}: not a grown print")
    return Fingerprint(ridges=data["ridges"], u0=float(u0), v0=float(v0), pitch=float(pitch),
                       orientation=data["orientation"], minutiae=data["minutiae"],
                       cores=data["cores"], deltas=data["deltas"],
                       pattern=str(data["pattern"]), seed=int(seed),
                       ridge_period=float(period))


def _smoothstep(x):
    """``3x² − 2x³`` of `x` clipped to ``[0, 1]``: 0 → 1 with zero slope at both ends."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


@dataclass
class Finger(Scene):
    """A fingertip with friction-ridge relief, pad towards ``+Z`` (the centre camera).

    Base shape: the elliptic cylinder ``x²/ax² + z²/az² = 1`` for ``y ≤ y0`` capped by the
    half-ellipsoid of semi-axes ``(ax, ay, az)`` for ``y > y0`` (tip at ``y0 + ay``). With
    scaled coordinates ``q = (x/ax, max(y − y0, 0)/ay, z/az)`` the base is ``|q| = 1`` and
    ``D = (|q| − 1) / |∇|q||`` approximates the signed distance to it. The surface is
    ``f = D − e · h(u, v) = 0`` with the ridge height ``h`` of the fingerprint at the
    rolled-print coordinates of the point and ``e`` the friction-ridge envelope:

    - ``φ = atan2(qx, qz)`` (angle around the finger from the pad), ``ψ = asin(q̂y)`` (0 on the
      body, up to 90° at the tip), ``q̂ = q / |q|``;
    - ``u = cos ψ · S(φ)`` with ``S`` the arc length of the cross-section ellipse from the pad
      centre (exact arc length around the body), ``v = y`` on the body and
      ``v = y0 + M(ψ)`` on the cap, ``M`` the arc length of the pad meridian (ellipse ``az, ay``).

    Friction-ridge skin (glabrous skin) covers only the palmar side of a finger, from nail edge
    to nail edge; the back (nail plate, nail folds, dorsal skin) is smooth. The envelope
    ``e = smoothstep((S(φ_r) − |S(φ)|) / ridge_edge_mm)`` (``φ_r`` = `ridge_arc_deg`) is 1 on
    the pad and falls smoothly to 0 over the last `ridge_edge_mm` of arc before ``|φ| = φ_r``,
    on the body and, at the same ``φ``, on the tip's cap; beyond, the skin is smooth. With
    ``ridge_arc_deg >= 180`` (or a print from an image) ``e = 1`` everywhere.

    Ridges are relief of ``relief_height`` mm peak to valley; the albedo is
    ``skin_albedo · (1 + albedo_contrast · e · r)`` with ``r ∈ [−1, 1]`` the ridge field (+1
    on ridge crests).

    The print: `fingerprint` if given; else `print_image` (a real print, ``(H, W)`` uint8 in
    the legacy convention, ridges dark, at `print_ppi`) centred on the pad centre
    ``(u, v) = (0, y0 − 2)`` (:meth:`Fingerprint.from_image`, flat skin beyond it, no
    envelope); else a synthetic print of `pattern` (by default drawn by `seed`) with its core
    near the pad centre, grown over the whole skin (ridges continue below the rolled extent,
    as on the middle phalanx). Print images (:meth:`rolled_print`) are in the legacy
    convention: :meth:`legacy_print_pixel` maps ``(u, v)`` to ``(col, row)``.

    Friction-ridge skin and the truth print
    ---------------------------------------
    ridge_arc_deg : float
        Half the angular extent ``φ_r`` of the friction-ridge skin around the finger from the
        pad centre, degrees (default 110). The boundary between palmar and dorsal skin runs
        along the finger's sides just dorsal of the mid-lateral line, up to the lateral nail
        folds: on this cross-section (17 × 14 mm) ±110° puts the nail edges at
        ``x = ±8.0 mm``, 2.4 mm behind the centre, and leaves 140° (about 20 mm of arc) of
        nail and dorsal skin smooth; a nail-to-nail rolled print of it is
        ``2 S(110°) ≈ 29 mm`` wide, as inked rolls of index fingers are (25–30 mm).
    ridge_edge_mm : float
        Width of the envelope's fall to smooth skin, mm of arc (default 1: the ridges fade out
        over two ridge periods into the nail folds).
    rolled_length_mm : float
        Length of the truth rolled print from the fingertip along the pad's profile, mm
        (default 25): a rolled print records the distal phalanx from the tip to about the
        distal interphalangeal crease, some 22–28 mm on adult fingers (ridges go on below it
        on the skin, but not on the print).

    Shape and pose
    --------------
    taper : float
        Relative growth of the body's cross-section per mm below the cap's base (``y0``), up
        to 30 mm below it (default 0: a straight body): the section at ``y`` has semi-axes
        ``k(y) · (ax, az)``, ``k = 1 + taper · clip(y0 − y, 0, 30)``; ``u`` around the body
        scales with it (``u = cos ψ · k · S(φ)``).
    rotation_deg : (3,) float
        The finger's rotation in the world, degrees: ``(tilt, roll, yaw)`` about the world's
        ``X`` (tip towards or away from the cameras), the finger's own axis ``Y``, and ``Z``
        (in the images' plane), applied as ``R = R_z(yaw) R_x(tilt) R_y(roll)`` about the
        local origin (on the axis, ``y0`` below the cap's base). Default: no rotation.
    offset_mm : (3,) float
        Translation of the finger in the world, mm (default 0): ``X_world = R X + offset``.
        The rolled-print coordinates ``u, v`` stay those of the finger's own frame.
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
    ridge_arc_deg: float = 110.0
    ridge_edge_mm: float = 1.0
    rolled_length_mm: float = 25.0
    taper: float = 0.0
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    offset_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    name = "finger"

    #: how far below the cap's base the taper goes on growing the section, mm
    TAPER_LENGTH_MM = 30.0

    def __post_init__(self):
        if not (np.isfinite(self.taper) and 0 <= self.taper <= 0.05):
            raise ValueError(f"taper: expected 0 <= taper <= 0.05 per mm, got {self.taper}")
        rotation = np.asarray(self.rotation_deg, dtype=float)
        offset = np.asarray(self.offset_mm, dtype=float)
        if rotation.shape != (3,) or not np.isfinite(rotation).all():
            raise ValueError(f"rotation_deg: expected 3 finite angles, got {self.rotation_deg}")
        if offset.shape != (3,) or not np.isfinite(offset).all():
            raise ValueError(f"offset_mm: expected 3 finite numbers, got {self.offset_mm}")
        self._R = _finger_rotation(rotation)
        self._t = offset
        self._posed = bool(np.any(rotation != 0) or np.any(offset != 0))
        if not 0 <= self.relief_height < 0.5:
            raise ValueError(f"relief_height: expected 0 <= h < 0.5 mm, got {self.relief_height}")
        if not (np.isfinite(self.ridge_arc_deg) and 0 < self.ridge_arc_deg):
            raise ValueError(f"ridge_arc_deg: expected a positive angle (degrees, 180 or more "
                             f"for ridges all around), got {self.ridge_arc_deg}")
        if not (np.isfinite(self.ridge_edge_mm) and self.ridge_edge_mm > 0):
            raise ValueError(f"ridge_edge_mm: expected a positive width (mm), got "
                             f"{self.ridge_edge_mm}")
        if not (np.isfinite(self.rolled_length_mm) and self.rolled_length_mm > 0):
            raise ValueError(f"rolled_length_mm: expected a positive length (mm), got "
                             f"{self.rolled_length_mm}")
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
            half_u = float(self._s[-1]) * self._k_max + 1.0
            self.fingerprint = _cached_fingerprint(
                (-half_u, half_u), (-32.0, self.y0 + float(self._m[-1]) + 1.0),
                self.pad_center, int(self.seed), self.pattern,
            )
        self._hmax = self.relief_height / 2
        s_max = float(self._s[-1])
        self._synthetic = self.fingerprint.image is None
        self._all_round = not self._synthetic or self.ridge_arc_deg >= 180.0
        self._s_ridge = s_max if self._all_round else float(
            np.interp(np.radians(self.ridge_arc_deg), self._phi, self._s))
        self._box = self._rolled_box()

    # rolled-print coordinates --------------------------------------------------------------
    @property
    def _k_max(self) -> float:
        return 1.0 + self.taper * self.TAPER_LENGTH_MM

    def _k(self, y):
        """The taper's scale ``k(y)`` of the body's section (1 on the cap)."""
        if self.taper == 0:
            return 1.0
        return 1.0 + self.taper * np.clip(self.y0 - np.asarray(y, dtype=float), 0.0,
                                          self.TAPER_LENGTH_MM)

    def _local(self, xyz):
        """Points in the finger's own frame (``R⁻¹ (X − offset)``)."""
        if not self._posed:
            return xyz
        return (np.asarray(xyz, dtype=float) - self._t) @ self._R

    def _scaled(self, xyz):
        x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        qy = np.maximum(y - self.y0, 0.0) / self.ay
        k = self._k(y)
        return x / (self.ax * k), qy, z / (self.az * k)

    def _skin(self, xyz):
        """``u, v`` (mm) and the arc length ``S(φ)`` around the body (mm) of local points."""
        qx, qy, qz = self._scaled(xyz)
        norm = np.sqrt(qx * qx + qy * qy + qz * qz)
        psi = np.arcsin(np.clip(qy / np.maximum(norm, 1e-12), 0.0, 1.0))
        s = np.interp(np.arctan2(qx, qz), self._phi, self._s)
        u = np.cos(psi) * s * self._k(xyz[:, 1])
        v = np.where(qy > 0, self.y0 + np.interp(psi, self._psi, self._m), xyz[:, 1])
        return u, v, s

    def _envelope_of_arc(self, s):
        if self._all_round:
            return np.ones_like(s)
        return _smoothstep((self._s_ridge - np.abs(s)) / self.ridge_edge_mm)

    def print_coordinates(self, xyz) -> tuple[np.ndarray, np.ndarray]:
        """Rolled-print coordinates ``u, v`` (mm) of points ``(N, 3)`` (see the class doc)."""
        u, v, _ = self._skin(self._local(np.asarray(xyz, dtype=float)))
        return u, v

    @property
    def pad_center(self) -> tuple[float, float]:
        """``(u, v)`` of the pad centre, mm: ``(0, y0 − 2)``, where prints are centred."""
        return 0.0, self.y0 - 2.0

    @property
    def v_tip(self) -> float:
        """``v`` of the fingertip (the cap's apex), mm: ``y0 + M(90°)``."""
        return self.y0 + float(self._m[-1])

    def _half_width(self, v, s_limit):
        """``|u|`` of the arc ``S = s_limit`` at `v` (``cos ψ · s_limit`` on the cap)."""
        dv = np.asarray(v, dtype=float) - self.y0
        psi = np.interp(np.clip(dv, 0, None), self._m, self._psi)
        return np.where(dv <= 0, s_limit * self._k(v), np.cos(psi) * s_limit)

    def ridge_envelope(self, u, v) -> np.ndarray:
        """Friction-ridge envelope ``e`` at rolled-print coordinates ``(u, v)`` mm.

        1 on the pad, falling smoothly (``3x² − 2x³``) to 0 over the last `ridge_edge_mm` of
        arc before ``φ = ±ridge_arc_deg`` (the nail edges), 0 beyond; 1 everywhere for a print
        from an image or ``ridge_arc_deg >= 180``. The ridge relief and the albedo contrast are
        multiplied by it (see the class doc).

        Examples
        --------
        >>> from nail2nail.simulation.fingerprint import Fingerprint
        >>> fp = Fingerprint(ridges=np.zeros((3, 3), np.float32), u0=1.0, v0=1.0, pitch=1.0)
        >>> finger = Finger(fingerprint=fp)
        >>> [float(e) for e in finger.ridge_envelope(np.array([0.0, 20.0]), np.zeros(2))]
        [1.0, 0.0]
        """
        u, v = np.broadcast_arrays(np.asarray(u, dtype=float), np.asarray(v, dtype=float))
        if self._all_round:
            return np.ones(u.shape)
        # S(φ) = u / cos ψ; at the apex (cos ψ = 0, u = 0) the pad centre line
        c = self._half_width(v, 1.0)
        s = np.divide(np.abs(u), c, out=np.zeros(u.shape), where=c > 1e-12)
        return self._envelope_of_arc(s)

    def rolled_extent(self, u, v) -> np.ndarray:
        """Whether rolled-print coordinates ``(u, v)`` mm lie in the truth print's extent.

        A synthetic print: the friction-ridge skin (``|φ| ≤ ridge_arc_deg``) from the tip down
        to `rolled_length_mm` along the pad's profile (``v ≥ v_tip − rolled_length_mm``). A
        print from an image: the skin, the whole finger (the image is its own extent).
        """
        u, v = np.broadcast_arrays(np.asarray(u, dtype=float), np.asarray(v, dtype=float))
        inside = (np.abs(u) <= self._half_width(v, self._s_ridge)) & (v <= self.v_tip)
        if self._synthetic:
            inside &= v >= self.v_tip - self.rolled_length_mm
        return inside

    def _rolled_box(self):
        """``(r0, r1, c0, c1)``: the truth print's rows and columns of the ridge grid.

        A synthetic print: the rolled extent's bounding box plus 1 mm, clipped to the grid; a
        print from an image: the whole image.
        """
        fp = self.fingerprint
        h, w = fp.shape
        if not self._synthetic:
            return 0, h, 0, w
        margin = 1.0
        u_hi = self._s_ridge * self._k_max + margin
        v_hi = self.v_tip + margin
        v_lo = self.v_tip - self.rolled_length_mm - margin
        c0 = int(np.floor((fp.u0 - u_hi) / fp.pitch + 1e-9))
        c1 = int(np.ceil((fp.u0 + u_hi) / fp.pitch - 1e-9)) + 1
        r0 = int(np.floor((fp.v0 - v_hi) / fp.pitch + 1e-9))
        r1 = int(np.ceil((fp.v0 - v_lo) / fp.pitch - 1e-9)) + 1
        r0, r1 = max(r0, 0), min(r1, h)
        c0, c1 = max(c0, 0), min(c1, w)
        if r1 <= r0 or c1 <= c0:
            raise ValueError("fingerprint: its grid does not cover the rolled extent of the "
                             "finger (ridge_arc_deg, rolled_length_mm)")
        return r0, r1, c0, c1

    @property
    def _print_origin(self) -> tuple[float, float]:
        """``(u0, v0)`` of pixel ``[0, 0]`` of :meth:`rolled_print`, mm."""
        r0, _, c0, _ = self._box
        fp = self.fingerprint
        assert fp is not None  # set in __post_init__
        return fp.u0 - c0 * fp.pitch, fp.v0 - r0 * fp.pitch

    def legacy_print_pixel(self, u, v) -> tuple[np.ndarray, np.ndarray]:
        """``(col, row)`` in :meth:`rolled_print` of rolled-print coordinates ``(u, v)`` mm.

        Legacy convention (the mirror of the pad view, tip up), pixel centres at integers:
        ``col = (u0 − u) / pitch``, ``row = (v0 − v) / pitch`` with ``u0``, ``v0``, ``pitch``
        of :meth:`rolled_print_geometry` (``truth/fingerprint.json``: ``u_of_col0_mm``,
        ``v_of_row0_mm``, ``pitch_mm``; for a print from an image those of the image). Use with
        :meth:`print_coordinates` to find the truth pixel of a surface point.

        Examples
        --------
        >>> from nail2nail.simulation.fingerprint import Fingerprint
        >>> import numpy as np
        >>> finger = Finger(fingerprint=Fingerprint.from_image(np.zeros((5, 5), np.uint8)))
        >>> [float(x) for x in finger.legacy_print_pixel(0.0508, 0.0)]
        [1.0, 2.0]
        """
        u0, v0 = self._print_origin
        assert self.fingerprint is not None  # set in __post_init__
        pitch = self.fingerprint.pitch
        return (u0 - np.asarray(u, dtype=float)) / pitch, (v0 - np.asarray(v, dtype=float)) / pitch

    def uv_from_legacy_pixel(self, col, row) -> tuple[np.ndarray, np.ndarray]:
        """Rolled-print coordinates ``(u, v)`` mm of :meth:`rolled_print` pixels (inverse)."""
        u0, v0 = self._print_origin
        assert self.fingerprint is not None  # set in __post_init__
        pitch = self.fingerprint.pitch
        return u0 - pitch * np.asarray(col, dtype=float), v0 - pitch * np.asarray(row, dtype=float)

    def rolled_print_geometry(self) -> dict:
        """Placement of :meth:`rolled_print` on the rolled-print plane and its extent (JSON).

        The keys of :func:`~nail2nail.simulation.fingerprint.legacy_geometry` for the truth
        image, plus `ridge_arc_deg`, `ridge_edge_mm`, `rolled_length_mm` and
        ``rolled_extent``: ``u_max_mm`` (the arc ``S(ridge_arc_deg)`` on the body),
        ``v_tip_mm``, ``v_min_mm`` (``v_tip − rolled_length_mm``); for a print from an image
        ``rolled_extent`` is None (the image is the truth).
        """
        r0, r1, c0, c1 = self._box
        u0, v0 = self._print_origin
        extent = None
        assert self.fingerprint is not None  # set in __post_init__
        if self._synthetic:
            extent = {"u_max_mm": round(self._s_ridge, 6), "v_tip_mm": round(self.v_tip, 6),
                      "v_min_mm": round(self.v_tip - self.rolled_length_mm, 6)}
        return {**legacy_geometry(u0, v0, self.fingerprint.pitch, (r1 - r0, c1 - c0)),
                "ridge_arc_deg": self.ridge_arc_deg, "ridge_edge_mm": self.ridge_edge_mm,
                "rolled_length_mm": self.rolled_length_mm, "rolled_extent": extent}

    def rolled_print(self) -> tuple[np.ndarray, np.ndarray]:
        """Ground-truth rolled print: ``(image (H, W) uint8, mask (H, W) bool)``.

        What an inked roll or a live scan records, in their legacy convention: the mirror of
        the pad seen from outside, fingertip up (:meth:`legacy_print_pixel`), ridges dark on
        white, 500 ppi. A synthetic print covers the friction-ridge skin from nail edge to nail
        edge (``|φ| ≤ ridge_arc_deg``) and from the tip down to `rolled_length_mm` along the
        pad (:meth:`rolled_extent`, ``mask``), cut to that extent's bounding box plus 1 mm
        (:meth:`rolled_print_geometry`) and white outside it; the ink is
        ``I = 255 − k (127.5 + 127.5 r)`` with ``k`` the ridge envelope (fading into the nail
        folds) times a fade over `ridge_edge_mm` above the bottom edge. A print from an image
        is that image unchanged, ``mask`` the pixels that map onto the finger surface.
        """
        fp = self.fingerprint
        assert fp is not None  # set in __post_init__
        r0, r1, c0, c1 = self._box
        u, v = self.uv_from_legacy_pixel(np.arange(c1 - c0)[None, :],
                                         np.arange(r1 - r0)[:, None])
        mask = self.rolled_extent(u, v)
        if not self._synthetic:
            assert fp.image is not None  # not synthetic: a print from an image
            return fp.image.copy(), mask
        v_min = self.v_tip - self.rolled_length_mm
        ink = self.ridge_envelope(u, v) * _smoothstep((v - v_min) / self.ridge_edge_mm)
        ridges = fp.ridges[r0:r1, c0:c1].astype(np.float64)
        image = np.where(mask, np.rint(255.0 - ink * (127.5 + 127.5 * ridges)), 255)
        return image.astype(np.uint8), mask

    def rolled_print_minutiae(self) -> np.ndarray:
        """Minutiae of :meth:`rolled_print`: ``(M, 6)`` ``u, v, col, row, kind, orientation``.

        Those of the synthetic print inside the rolled extent where the ink is at least half
        (:meth:`rolled_print`), ``col, row`` in the truth image, the ridge orientation
        (radians in ``[0, π)``) from the print's orientation field; ``(0, 6)`` for an image.
        """
        fp = self.fingerprint
        assert fp is not None  # set in __post_init__
        if not self._synthetic or len(fp.minutiae) == 0 or fp.orientation is None:
            return np.zeros((0, 6))
        m = fp.minutiae
        u, v = m[:, 0], m[:, 1]
        v_min = self.v_tip - self.rolled_length_mm
        ink = self.ridge_envelope(u, v) * _smoothstep((v - v_min) / self.ridge_edge_mm)
        col, row = self.legacy_print_pixel(u, v)
        h, w = self._box[1] - self._box[0], self._box[3] - self._box[2]
        keep = (self.rolled_extent(u, v) & (ink >= 0.5) & (col > -0.5) & (col < w - 0.5)
                & (row > -0.5) & (row < h - 0.5))
        theta = fp.orientation[m[keep, 3].astype(np.intp), m[keep, 2].astype(np.intp)]
        return np.column_stack([u[keep], v[keep], np.rint(col[keep]), np.rint(row[keep]),
                                m[keep, 4], theta])

    def _base_distance(self, xyz):
        qx, qy, qz = self._scaled(xyz)
        norm = np.sqrt(qx * qx + qy * qy + qz * qz)
        gx, gy, gz = qx / self.ax, qy / self.ay, qz / self.az
        gnorm = np.sqrt(gx * gx + gy * gy + gz * gz) / np.maximum(norm, 1e-12)
        return (norm - 1.0) / np.maximum(gnorm, 1e-12)

    def implicit(self, xyz) -> np.ndarray:
        """``f (N,)`` of points in the finger's own frame: positive outside, zero on its surface,
        ~mm near it."""
        xyz = np.asarray(xyz, dtype=float)
        u, v, s = self._skin(xyz)
        assert self.fingerprint is not None  # set in __post_init__
        r = self.fingerprint.sample(u, v) * self._envelope_of_arc(s)
        return self._base_distance(xyz) - self._hmax * r

    def _shell_t(self, o, d, offset):
        """Entry/exit of the base shape grown by `offset` mm (approximately: axes + offset;
        the body's cylinder as wide as the taper's widest section when growing)."""
        ax, ay, az = self.ax + offset, self.ay + offset, self.az + offset
        k = self._k_max if offset > 0 else 1.0
        c0, c1 = _elliptic_cylinder_t(o, d, self.ax * k + offset, self.az * k + offset)
        e0, e1 = _ellipsoid_t(o, d, (ax, ay, az), np.array([0.0, self.y0, 0.0]))
        # the body's part: the cylinder's interval cut to the half-space y <= y0. A ray can
        # enter it through the plane y = y0 (or leave through it), inside the cylinder's
        # section but outside the cap's: a tapered body's grown cylinder is wider than the cap
        # (by ax · taper · TAPER_LENGTH_MM), and a projector's ray from above that entered
        # there, missed, started its march past the skin below the cap's base (a false shadow
        # band there)
        dy = d[:, 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            t_plane = (self.y0 - o[1]) / dy
        lo = np.where(dy < 0, np.fmax(c0, t_plane), c0)
        hi = np.where(dy > 0, np.fmin(c1, t_plane), c1)
        lo = np.where((dy == 0) & (o[1] > self.y0), np.inf, lo)
        inside = np.isfinite(lo) & np.isfinite(hi) & (lo < hi)
        entry = np.where(inside, lo, np.inf)
        exit_ = np.where(inside, hi, -np.inf)
        entry = np.fmin(entry, np.where(np.isfinite(e0), e0, np.inf))
        exit_ = np.fmax(exit_, np.where(np.isfinite(e1), e1, -np.inf))
        return entry, exit_

    def intersect(self, origin, directions):
        o = self._local(np.asarray(origin, dtype=float))
        d = np.asarray(directions, dtype=float)
        if self._posed:
            d = d @ self._R
        margin = 2 * self._hmax + 0.02
        t0, t1 = self._shell_t(o, d, margin)
        hit = np.isfinite(t0) & (t1 > t0) & (t1 > 0)
        t0 = np.where(hit, np.maximum(t0, 0.0), np.inf)
        i0, _ = self._shell_t(o, d, -margin)
        t_end = np.where(np.isfinite(i0) & hit, np.minimum(i0, t1), t1)
        t_end = np.where(hit, t_end, np.inf)
        return _march(self.implicit, o, d, t0, t_end, self.march_step)

    def surface(self, xyz):
        xyz = self._local(np.asarray(xyz, dtype=float))
        normal = _normal_from_gradient(self.implicit, xyz)
        if self._posed:
            normal = normal @ self._R.T
        u, v, s = self._skin(xyz)
        r = self.fingerprint.sample(u, v) * self._envelope_of_arc(s)
        albedo = np.clip(self.skin_albedo * (1 + self.albedo_contrast * r), 0, 1)
        return SurfaceInfo(normal, albedo, {"u": u, "v": v})

    def to_dict(self):
        return {"name": self.name, "ax": self.ax, "ay": self.ay, "az": self.az, "y0": self.y0,
                "taper": self.taper, "rotation_deg": [float(a) for a in self.rotation_deg],
                "offset_mm": [float(a) for a in self.offset_mm],
                "relief_height": self.relief_height, "skin_albedo": self.skin_albedo,
                "albedo_contrast": self.albedo_contrast, "seed": self.seed,
                "pad_center": list(self.pad_center), "ridge_arc_deg": self.ridge_arc_deg,
                "ridge_edge_mm": self.ridge_edge_mm, "rolled_length_mm": self.rolled_length_mm,
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
    """Build a scene by name: ``finger``, ``target``, ``plane``, ``sphere``, ``coin`` or ``board``.

    Parameters
    ----------
    name : str
    rig : Rig, optional
        For the plane's default pose: facing the projector (normal towards its centre), through
        the axis point ``(0, 3.175, 0)``, so that it fills the projector's view (distortion
        estimation). Without a rig the plane faces ``+Z``. For the board, the default
        `footprint` (:func:`board_footprint`: one camera pixel at the board's centre) and
        `viewers` (the rig's cameras, :class:`BoardScene`).
    seed : int
        Fingerprint seed (finger).
    **options
        Keyword arguments of the scene class (e.g. ``point=``, ``normal=`` for the plane;
        ``pattern=``, ``print_image=``, ``print_ppi=`` for the finger; ``board=``, ``pose=``
        for the board, :class:`BoardScene`).

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
    if name == "board":
        if rig is not None and "footprint" not in options:
            pose = options.get("pose", BoardScene.pose)
            options["footprint"] = board_footprint(rig, np.asarray(pose, dtype=float)[3:])
        if rig is not None and "viewers" not in options:
            options["viewers"] = tuple((tuple(float(v) for v in cam.center),
                                        float(min(cam.K[0, 0], cam.K[1, 1])))
                                       for cam in rig.cameras)
        return BoardScene(**options)
    if name == "plane":
        if rig is not None and "normal" not in options:
            point = np.asarray(options.get("point", (0.0, 3.175, 0.0)), dtype=float)
            n = rig.projector.center - point
            options["normal"] = tuple(float(v) for v in n / np.linalg.norm(n))
        return Plane(**options)
    raise ValueError(f"scene: expected one of {', '.join(SCENES)}, got {name!r}")
