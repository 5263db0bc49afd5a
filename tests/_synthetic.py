"""Small synthetic scenes shared by the tests: pinhole cameras and a projector around a cylinder.

Each camera pixel's ray is intersected analytically with a finger-like cylinder (axis along world
Y) or a sphere; the hit point is projected into the projector for its ``(xp, yp)``. The scans are
ground truth (``xyz`` exact unless noise is asked for), so merge errors are known in advance.

Tests run with ``--import-mode=importlib``: import it after adding the ``tests`` folder to
``sys.path`` (``sys.path.insert(0, str(Path(__file__).parent))``, as
tests/test_merge_correspondence.py does).
Nothing here runs at import time.
"""

from __future__ import annotations

import numpy as np

from nail2nail.calibration.camera_models import Pinhole, look_at
from nail2nail.scan.results import Scan

__all__ = [
    "camera_ring",
    "intersect_cylinder",
    "intersect_sphere",
    "make_projector",
    "scan_from_camera",
    "synthetic_scans",
]


def _pinhole(eye, target, *, size, focal) -> Pinhole:
    width, height = size
    K = np.array([[focal, 0.0, (width - 1) / 2], [0.0, focal, (height - 1) / 2], [0, 0, 1]])
    R, t = look_at(eye, target, [0.0, 1.0, 0.0])
    return Pinhole(K=K, R=R, t=t, size=(width, height))


def camera_ring(
    angles_deg=(-45.0, 0.0, 45.0),
    *,
    distance: float = 120.0,
    size: tuple[int, int] = (64, 80),
    field_mm: float = 26.0,
) -> list[Pinhole]:
    """Cameras on a circle around the world Y axis, looking at the origin.

    `size` is ``(width, height)``; the focal length makes `field_mm` fill the image width at the
    origin's distance.
    """
    focal = size[0] * distance / field_mm
    cams = []
    for a in np.radians(angles_deg):
        eye = distance * np.array([np.sin(a), 0.0, np.cos(a)])
        cams.append(_pinhole(eye, [0.0, 0.0, 0.0], size=size, focal=focal))
    return cams


def make_projector(
    *, distance: float = 150.0, height: float = 25.0, size=(1280, 1040), field_mm: float = 40.0
) -> Pinhole:
    """A projector above the centre camera, tilted down so both ``xp`` and ``yp`` vary."""
    focal = size[0] * distance / field_mm
    return _pinhole([0.0, height, distance], [0.0, 0.0, 0.0], size=size, focal=focal)


def intersect_cylinder(origin, directions, *, radius: float = 8.0, half_length: float = 14.0):
    """First hit of rays with the cylinder ``x² + z² = radius²``, ``|y| ≤ half_length``.

    Returns ``(xyz (..., 3), normal (..., 3))``, NaN where the ray misses.
    """
    o = np.asarray(origin, dtype=float)
    d = np.asarray(directions, dtype=float)
    a = d[..., 0] ** 2 + d[..., 2] ** 2
    b = 2 * (o[0] * d[..., 0] + o[2] * d[..., 2])
    c = o[0] ** 2 + o[2] ** 2 - radius**2
    disc = b * b - 4 * a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (-b - np.sqrt(disc)) / (2 * a)
    xyz = o + t[..., None] * d
    hit = (disc > 0) & (t > 0) & (np.abs(xyz[..., 1]) <= half_length)
    xyz[~hit] = np.nan
    normal = xyz.copy()
    normal[..., 1] = 0.0
    normal /= radius
    return xyz, normal


def intersect_sphere(origin, directions, *, radius: float = 10.0):
    """First hit of rays with the sphere of `radius` about the origin; NaN where missed."""
    o = np.asarray(origin, dtype=float)
    d = np.asarray(directions, dtype=float)
    b = 2 * (d @ o)
    c = o @ o - radius**2
    disc = b * b - 4 * c
    with np.errstate(invalid="ignore"):
        t = (-b - np.sqrt(disc)) / 2
    xyz = o + t[..., None] * d
    xyz[~((disc > 0) & (t > 0))] = np.nan
    return xyz, xyz / radius


def scan_from_camera(
    camera: Pinhole,
    projector: Pinhole,
    *,
    name: str = "cam",
    shape: str = "cylinder",
    noise_px: float = 0.0,
    xyz_noise_mm: float = 0.0,
    shift_mm=(0.0, 0.0, 0.0),
    rng: np.random.Generator | None = None,
    **shape_kwargs,
) -> Scan:
    """Ground-truth :class:`Scan` of one camera.

    A pixel is valid where its ray hits the object, the projector sees the hit point (front
    facing) inside its panel, and the incidence is not grazing. ``xp, yp`` get Gaussian noise of
    `noise_px` projector px; ``xyz`` gets `xyz_noise_mm` and a constant `shift_mm`.
    """
    rng = np.random.default_rng(0) if rng is None else rng
    width, height = camera.size
    rows, cols = np.mgrid[0:height, 0:width]
    center, dirs = camera.rays(np.stack([cols, rows], axis=-1).astype(float))
    hit = {"cylinder": intersect_cylinder, "sphere": intersect_sphere}[shape]
    xyz, normal = hit(center, dirs, **shape_kwargs)
    to_proj = projector.center - xyz
    to_proj /= np.linalg.norm(to_proj, axis=-1, keepdims=True)
    to_cam = center - xyz
    to_cam /= np.linalg.norm(to_cam, axis=-1, keepdims=True)
    cos_p = np.einsum("...k,...k->...", normal, to_proj)
    cos_c = np.einsum("...k,...k->...", normal, to_cam)
    xy_p = projector.project(xyz)
    wp, hp = projector.size
    with np.errstate(invalid="ignore"):
        mask = (
            np.isfinite(xyz).all(-1) & (cos_p > 0.1) & (cos_c > 0.1)
            & (xy_p[..., 0] >= -0.5) & (xy_p[..., 0] <= wp - 0.5)
            & (xy_p[..., 1] >= -0.5) & (xy_p[..., 1] <= hp - 0.5)
        )
    xy_p = xy_p + noise_px * rng.standard_normal(xy_p.shape)
    xyz = xyz + xyz_noise_mm * rng.standard_normal(xyz.shape) + np.asarray(shift_mm, float)
    xyz[~mask] = np.nan
    xy_p[~mask] = np.nan
    modulation = np.where(mask, 0.5 * np.clip(cos_p, 0, 1), 0.0).astype(np.float32)
    albedo = np.where(mask, 0.6, 0.0).astype(np.float32)
    return Scan(
        name=name,
        xyz=xyz.astype(np.float32),
        xp=xy_p[..., 0].astype(np.float32),
        yp=xy_p[..., 1].astype(np.float32),
        albedo=albedo,
        intensity=modulation.copy(),
        modulation=modulation,
        mask=mask,
        camera_center=np.asarray(center, dtype=np.float64),
        projector_center=np.asarray(projector.center, dtype=np.float64),
    )


def synthetic_scans(
    *,
    angles_deg=(-45.0, 0.0, 45.0),
    size: tuple[int, int] = (64, 80),
    noise_px: float = 0.0,
    shifts=None,
    shape: str = "cylinder",
    seed: int = 0,
    **shape_kwargs,
) -> list[Scan]:
    """Scans of one object by a ring of cameras (``cam0``, ``cam1``, …) and one projector."""
    rng = np.random.default_rng(seed)
    projector = make_projector()
    cams = camera_ring(angles_deg, size=size)
    shifts = shifts or [(0.0, 0.0, 0.0)] * len(cams)
    return [
        scan_from_camera(cam, projector, name=f"cam{i}", shape=shape, noise_px=noise_px,
                         shift_mm=shifts[i], rng=rng, **shape_kwargs)
        for i, cam in enumerate(cams)
    ]
