"""The virtual scanner's rig: three pinhole cameras, one projector with the thesis's distortion.

Every number lives in a :class:`Rig` (JSON round trip through :meth:`Rig.to_dict` /
:meth:`Rig.from_dict`); :func:`default_rig` builds the thesis-like default:

- world frame (``docs/conventions.md``): mm, ``Y`` along the finger axis, ``Z`` towards the
  centre camera, origin on the axis;
- cameras ``cam0``, ``cam1``, ``cam2`` at azimuth −45°, 0°, +45° about ``Y`` (azimuth measured
  from ``+Z`` towards ``+X``), 150 mm from the axis, looking horizontally at the axis point
  ``(0, 3.175, 0)`` (the middle of the target's mark rows), portrait 1024 × 1280 px with 32 px/mm
  on the axis (the thesis's Table 2 spans 1004 px over 31.75 mm), ``+Y`` up the image;
- projector 1280 × 1040 px, principal point ``(640, 1000)`` (the lens is offset: the optical
  centre sits near the bottom of the panel), 0.04 mm per panel pixel on the axis, 25° above the
  cameras (the baseline runs along the finger axis, so fringes encoding ``yp`` triangulate for all
  three cameras), panel rows running down world ``Y``; radial distortion of the thesis
  (eq. 3.34: ``r ↦ r + ρ³ r³``, centre ``(640, 1000)``, ``ρ = −0.004``) between panel and ideal
  coordinates (:mod:`nail2nail.calibration.distortion`).
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass, field, fields
from typing import cast

import numpy as np

from nail2nail._validation import as_name, check_format, check_unique
from nail2nail.calibration.camera_models import Pinhole, handedness, look_at
from nail2nail.calibration.distortion import (
    THESIS_CENTER,
    THESIS_RHO,
    ProjectorDistortion,
    as_projector_distortion,
)
from nail2nail.io._json import read_json, write_json

__all__ = [
    "MIN_CAMERA_PX",
    "RIG_FORMAT",
    "Photometry",
    "Rig",
    "check_camera_sizes",
    "default_rig",
    "ideal_calibration",
    "load_rig",
    "save_rig",
    "scale_camera",
]

RIG_FORMAT = "nail2nail-rig"

#: Smallest simulated camera image, px on each side: below it nothing can be decoded or seen.
MIN_CAMERA_PX = 64


def check_camera_sizes(cameras, names, where: str) -> None:
    """Refuse cameras smaller than :data:`MIN_CAMERA_PX` on a side, naming `where` and the camera.

    Examples
    --------
    >>> check_camera_sizes(default_rig(0.0625).cameras, ["a", "b", "c"], "rig")
    >>> check_camera_sizes(default_rig(0.0625).cameras[:1], ["cam0"], "--scale 0.01")
    """
    for cam, name in zip(cameras, names, strict=False):
        width, height = cam.size
        if min(width, height) < MIN_CAMERA_PX:
            raise ValueError(
                f"{where}: camera {name!r} would be {width} x {height} px; the smallest camera "
                f"is {MIN_CAMERA_PX} px on each side (--scale ≥ 0.0625 for the default rig)")


@dataclass
class Photometry:
    """Photometric model of the virtual scanner (all intensities are fractions of full scale).

    Attributes
    ----------
    projector_gamma : float
        Projector response: an 8-bit pattern value ``v`` emits ``(v / 255) ** gamma``.
    projector_power : float
        Camera signal of a white (albedo 1) surface facing the projector at the reference
        distance under a full-white pattern.
    ambient : float
        Ambient irradiance relative to ``projector_power`` (added before the albedo).
    camera_blur_px : float
        Gaussian defocus of the cameras, sigma in full-resolution camera pixels.
    projector_blur_px : float
        Gaussian defocus of the projector, sigma in panel pixels.
    full_well : float
        Electrons at full scale (shot noise ``sqrt(electrons)``).
    read_noise : float
        Read noise, electrons (Gaussian).
    bit_depth : int
        Quantisation: 8 (default), 10, 12 or 16 bits.
    noise : bool
        ``False`` renders noise-free (still quantised).
    reference_distance_mm : float
        Distance at which the projector irradiance equals ``projector_power`` (inverse square).
    projector_fill_factor : float or None
        ``None`` (default): the panel image is interpolated bilinearly between pixel centres
        (a soft projector). A number in ``(0, 1]``: each panel pixel is a sharp square
        aperture covering this fraction of its area (dark gaps between pixels, as on a DLP or
        LCD panel), blurred by `projector_blur_px` only; the camera pixel's footprint on the
        panel is integrated (:func:`~nail2nail.simulation.render.camera_geometry`).
    specular : float
        Strength of specular highlights (Blinn-Phong: J. F. Blinn, "Models of light
        reflection for computer synthesized pictures", SIGGRAPH 1977; fraction of full scale
        for a mirror facing the projector at the reference distance; 0: Lambertian skin).
    specular_exponent : float
        Blinn-Phong exponent (larger: smaller, sharper highlights).
    subsurface_mm : float
        σ of the subsurface spread of the projected light in the skin, mm (0: none): light
        enters at one point and leaves nearby, which lowers the fringes' contrast at fine
        periods and blurs the ridges' shading.
    projector_flicker : float
        RMS of the projector's frame-to-frame brightness variation, relative (0: none; DLP and
        LCD projectors and unsynchronised camera exposures vary by 0.2–2 %): frame ``k``'s
        projected light is scaled by ``1 + projector_flicker · z_k``, ``z_k`` standard normal
        from ``default_rng([seed, 0x666C, k])`` of the capture's noise seed (0 without one),
        the same for every camera. Unequal steps put a phase-locked error into the decoded
        phase (:mod:`nail2nail.unroll.fringes`); the ambient light does not flicker.
    """

    projector_gamma: float = 2.2
    projector_power: float = 0.9
    ambient: float = 0.03
    camera_blur_px: float = 0.6
    projector_blur_px: float = 0.7
    full_well: float = 20000.0
    read_noise: float = 10.0
    bit_depth: int = 8
    noise: bool = True
    reference_distance_mm: float = 176.5
    projector_fill_factor: float | None = None
    specular: float = 0.0
    specular_exponent: float = 40.0
    subsurface_mm: float = 0.0
    projector_flicker: float = 0.0

    def __post_init__(self) -> None:
        if self.bit_depth not in (8, 10, 12, 16):
            raise ValueError(f"bit_depth: expected 8, 10, 12 or 16, got {self.bit_depth!r}")
        for name in ("projector_gamma", "full_well", "reference_distance_mm"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: expected a positive number, got {getattr(self, name)!r}")
        if self.projector_fill_factor is not None and not 0 < self.projector_fill_factor <= 1:
            raise ValueError(f"projector_fill_factor: expected None or a number in (0, 1], got "
                             f"{self.projector_fill_factor!r}")
        if not self.specular_exponent > 0:
            raise ValueError(f"specular_exponent: expected a positive number, got "
                             f"{self.specular_exponent!r}")
        for name in ("projector_power", "ambient", "camera_blur_px", "projector_blur_px",
                     "read_noise", "specular", "subsurface_mm", "projector_flicker"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name}: expected a number >= 0, got {getattr(self, name)!r}")

    @classmethod
    def from_dict(cls, data: dict) -> Photometry:
        """Photometry from a dict of its fields; ``ValueError`` on unknown keys."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"photometry: unknown key(s) {unknown}")
        return cls(**data)


@dataclass
class Rig:
    """Cameras, projector and photometry of the virtual scanner.

    Attributes
    ----------
    cameras : list of Pinhole
        Camera models (``T_cam_world`` poses, OpenCV intrinsics; optional OpenCV distortion).
    projector : Pinhole
        Ideal (pinhole) projector model; its ``K`` maps to *ideal* projector coordinates.
    projector_distortion : ProjectorDistortion or None
        The thesis's radial distortion (eq. 3.34) from panel to ideal coordinates (its JSON
        dict ``{"center": [x, y], "rho": r}`` is accepted); ``None`` for a distortion-free
        projector.
    photometry : Photometry
    camera_names : list of str
        ``cam0``, ``cam1`` … by default.
    scale : float
        Camera resolution scale the rig was built with (informational; 1 = full resolution).
    """

    cameras: list[Pinhole]
    projector: Pinhole
    projector_distortion: ProjectorDistortion | None = None
    photometry: Photometry = field(default_factory=Photometry)
    camera_names: list[str] = field(default_factory=list)
    scale: float = 1.0

    def __post_init__(self) -> None:
        if not self.cameras:
            raise ValueError("cameras: the rig needs at least one camera")
        for i, cam in enumerate(self.cameras):
            if not isinstance(cam, Pinhole):
                raise TypeError(f"cameras[{i}]: expected a Pinhole, got {type(cam).__name__}")
        if not isinstance(self.projector, Pinhole):
            raise TypeError(f"projector: expected a Pinhole, got {type(self.projector).__name__}")
        if not self.camera_names:
            self.camera_names = [f"cam{i}" for i in range(len(self.cameras))]
        if len(self.camera_names) != len(self.cameras):
            raise ValueError(
                f"camera_names: expected {len(self.cameras)} names, got {len(self.camera_names)}"
            )
        self.projector_distortion = as_projector_distortion(self.projector_distortion)

    # -- projector mapping ----------------------------------------------------------------------
    @property
    def panel_size(self) -> tuple[int, int]:
        """Projector panel ``(W, H)`` in pixels."""
        return self.projector.size

    def panel_from_world(self, xyz_world) -> np.ndarray:
        """Panel coordinates ``(..., 2)`` that light world points ``(..., 3)``.

        The pinhole projector gives ideal coordinates; the thesis distortion (eq. 3.34) is then
        inverted: the panel pixel ``p`` lights the ideal ray ``ideal_from_panel(p)``.
        """
        ideal = self.projector.project(xyz_world)
        return self.panel_from_ideal(ideal)

    def panel_from_ideal(self, xy_ideal) -> np.ndarray:
        """Panel coordinates of ideal projector coordinates (identity without distortion)."""
        if self.projector_distortion is None:
            return np.asarray(xy_ideal, dtype=float)
        return self.projector_distortion.panel_from_ideal(xy_ideal)

    def ideal_from_panel(self, xy_panel) -> np.ndarray:
        """Ideal projector coordinates of panel coordinates (eq. 3.34)."""
        if self.projector_distortion is None:
            return np.asarray(xy_panel, dtype=float)
        return self.projector_distortion.ideal_from_panel(xy_panel)

    def projector_rays(self, xy_panel) -> tuple[np.ndarray, np.ndarray]:
        """World rays ``(origin (3,), directions (..., 3))`` lit by panel coordinates."""
        return self.projector.rays(self.ideal_from_panel(xy_panel))

    # -- serialisation --------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """JSON-ready dict (``format: "nail2nail-rig"``)."""
        return {
            "format": RIG_FORMAT,
            "version": 1,
            "scale": self.scale,
            "cameras": [
                {"name": n, **c.to_dict()} for n, c in zip(self.camera_names, self.cameras,
                                                           strict=True)
            ],
            "projector": self.projector.to_dict(),
            "projector_distortion": (None if self.projector_distortion is None
                                     else self.projector_distortion.to_dict()),
            "photometry": asdict(self.photometry),
        }

    @classmethod
    def from_capture(cls, capture) -> Rig:
        """The nominal rig a virtual capture's manifest stores
        (:class:`~nail2nail.io.capture.Capture`).

        ``KeyError`` naming the capture when its manifest holds no rig (a real capture).
        """
        if "rig" not in capture.manifest:
            raise KeyError(f"{capture.path}: the manifest holds no rig")
        return cls.from_dict(capture.manifest["rig"], where=f"{capture.path / 'capture.json'}: rig")

    @classmethod
    def from_dict(cls, data: dict, *, where: str = "rig") -> Rig:
        """Inverse of :meth:`to_dict`; ``ValueError`` naming `where` on bad content."""
        check_format(data, fmt=RIG_FORMAT, where=where)
        cams = data.get("cameras")
        if not isinstance(cams, list) or not cams:
            raise ValueError(f"{where}: 'cameras' must be a non-empty list")
        if "projector" not in data:
            raise ValueError(f"{where}: missing 'projector'")
        try:
            cameras = [Pinhole.from_dict(c) for c in cams]
            projector = Pinhole.from_dict(data["projector"])
            photometry = Photometry.from_dict(data.get("photometry", {}))
            rig = cls(
                cameras=cameras,
                projector=projector,
                projector_distortion=data.get("projector_distortion"),
                photometry=photometry,
                camera_names=[as_name(c.get("name", f"cam{i}"), f"cameras[{i}].name")
                              for i, c in enumerate(cams)],
                scale=float(data.get("scale", 1.0)),
            )
        except (TypeError, ValueError, AttributeError, IndexError, KeyError, OverflowError) as exc:
            raise ValueError(f"{where}: {exc}") from exc
        check_unique(rig.camera_names, where)
        for name, model in [*zip(rig.camera_names, rig.cameras, strict=True),
                            ("projector", rig.projector)]:
            if handedness(model) < 0:
                raise ValueError(f"{where}: {name} is mirrored (det(R) · fx · fy < 0)")
        return rig


def scale_camera(camera: Pinhole, scale: float) -> Pinhole:
    """The same camera with its resolution scaled by `scale` (pixel-centre convention kept).

    ``fx, fy`` scale by `scale`; the principal point maps by ``c' = (c + ½) · scale − ½`` so the
    image keeps covering the same field of view; the size is rounded.

    Examples
    --------
    >>> from nail2nail.calibration.camera_models import Pinhole
    >>> cam = Pinhole(K=[[100, 0, 511.5], [0, 100, 639.5], [0, 0, 1]], R=np.eye(3), t=[0, 0, 1])
    >>> half = scale_camera(cam, 0.5)
    >>> half.size, float(half.K[0, 2])
    ((512, 640), 255.5)
    """
    if not (isinstance(scale, (int, float)) and math.isfinite(scale) and scale > 0):
        raise ValueError(f"scale: expected a positive number, got {scale!r}")
    K = camera.K.copy()
    K[0, 0] *= scale
    K[1, 1] *= scale
    K[0, 1] *= scale
    K[0, 2] = (K[0, 2] + 0.5) * scale - 0.5
    K[1, 2] = (K[1, 2] + 0.5) * scale - 0.5
    size = (max(1, round(camera.size[0] * scale)), max(1, round(camera.size[1] * scale)))
    return Pinhole(K=K, R=camera.R, t=camera.t, dist=camera.dist, size=size)


def _aim(eye, target, up, K, pixel) -> tuple[np.ndarray, np.ndarray]:
    """Pose ``(R, t)`` whose ray through `pixel` passes through `target`, `up` appearing up."""
    R0, _ = look_at(eye, target, up)
    d = np.linalg.solve(K, np.array([pixel[0], pixel[1], 1.0]))
    d /= np.linalg.norm(d)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, d)
    s, c = np.linalg.norm(axis), float(z @ d)
    if s < 1e-15:
        Q = np.eye(3)
    else:
        k = axis / s
        Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        Q = np.eye(3) + s * Kx + (1 - c) * Kx @ Kx
    R = Q @ R0
    return R, -R @ np.asarray(eye, dtype=float)


def default_rig(
    scale: float = 1.0,
    *,
    projector_distortion: str = "thesis",
    camera_distortion: tuple[float, ...] | None = None,
    camera_distance_mm: float = 150.0,
    pixels_per_mm: float = 32.0,
    azimuths_deg: tuple[float, ...] = (-45.0, 0.0, 45.0),
    look_at_y_mm: float = 3.175,
    projector_distance_mm: float = 160.0,
    projector_elevation_deg: float = 25.0,
    projector_mm_per_px: float = 0.04,
    photometry: Photometry | None = None,
) -> Rig:
    """The thesis-like default rig (see the module docstring).

    Parameters
    ----------
    scale : float
        Camera resolution scale (1 = 1024 × 1280); projector coordinates keep their meaning.
    projector_distortion : {"thesis", "none"}
        Thesis radial distortion (centre (640, 1000), ρ = −0.004) or none.
    camera_distortion : (5,) float or None
        OpenCV ``(k1, k2, p1, p2, k3)`` for every camera; ``None`` (default) for none.
    camera_distance_mm, pixels_per_mm, azimuths_deg, look_at_y_mm
        Camera ring: distance from the axis, resolution on the axis, azimuths about ``Y``
        (from ``+Z`` towards ``+X``) and the height of the axis point they look at.
    projector_distance_mm, projector_elevation_deg, projector_mm_per_px
        Projector: horizontal distance from the axis, elevation above the cameras (its centre
        sits at ``Y = look_at_y + distance · tan(elevation)``), panel pixel size on the axis.
    photometry : Photometry or None

    Returns
    -------
    Rig

    Examples
    --------
    >>> rig = default_rig(0.5)
    >>> rig.cameras[0].size, rig.projector.size
    ((512, 640), (1280, 1040))
    """
    if projector_distortion not in ("thesis", "none"):
        raise ValueError(
            f"projector_distortion: expected 'thesis' or 'none', got {projector_distortion!r}"
        )
    width, height = 1024, 1280
    focal = pixels_per_mm * camera_distance_mm
    K = np.array([[focal, 0, (width - 1) / 2], [0, focal, (height - 1) / 2], [0, 0, 1]])
    target = np.array([0.0, look_at_y_mm, 0.0])
    cameras = []
    for az in np.radians(azimuths_deg):
        eye = target + camera_distance_mm * np.array([np.sin(az), 0.0, np.cos(az)])
        R, t = look_at(eye, target, [0.0, 1.0, 0.0])
        # Pinhole converts the tuple to an array
        camera_dist = cast(np.ndarray, camera_distortion or np.zeros(5))
        cam = Pinhole(K=K, R=R, t=t, dist=camera_dist, size=(width, height))
        cameras.append(scale_camera(cam, scale) if scale != 1 else cam)
    check_camera_sizes(cameras, [f"cam{i}" for i in range(len(cameras))], f"scale {scale:g}")
    elev = np.radians(projector_elevation_deg)
    eye = target + np.array([0.0, projector_distance_mm * np.tan(elev), projector_distance_mm])
    throw = projector_distance_mm / np.cos(elev)
    fp = throw / projector_mm_per_px
    pw, ph = 1280, 1040
    Kp = np.array([[fp, 0, THESIS_CENTER[0]], [0, fp, THESIS_CENTER[1]], [0, 0, 1]])
    R, t = _aim(eye, target, [0.0, 1.0, 0.0], Kp, ((pw - 1) / 2, (ph - 1) / 2))
    projector = Pinhole(K=Kp, R=R, t=t, size=(pw, ph))
    dist = (ProjectorDistortion(THESIS_CENTER, THESIS_RHO) if projector_distortion == "thesis"
            else None)
    photometry = photometry or Photometry(reference_distance_mm=float(throw))
    return Rig(cameras=cameras, projector=projector, projector_distortion=dist,
               photometry=photometry, scale=float(scale))


def ideal_calibration(rig: Rig) -> dict:
    """The rig's true calibration as a calibration-file dict (pinhole models).

    The format is that of :mod:`nail2nail.calibration.files` (``docs/capture-format.md``): one entry
    per camera with its pinhole model and the (shared) ideal projector model, plus the
    projector's radial distortion. ``RigCalibration.from_dict`` reads it.

    Examples
    --------
    >>> calib = ideal_calibration(default_rig(0.25))
    >>> calib["format"], len(calib["cameras"]), calib["projector_distortion"]["rho"]
    ('nail2nail-calibration', 3, -0.004)
    """
    return {
        "format": "nail2nail-calibration",
        "version": 1,
        "cameras": [
            {"name": name, "camera": cam.to_dict(), "projector": rig.projector.to_dict()}
            for name, cam in zip(rig.camera_names, rig.cameras, strict=True)
        ],
        "projector_distortion": (
            None if rig.projector_distortion is None else rig.projector_distortion.to_dict()
        ),
        "source": "nail2nail virtual scanner (ground truth)",
    }


def save_rig(path: str | os.PathLike, rig: Rig) -> None:
    """Write `rig` as JSON (atomically)."""
    write_json(path, rig.to_dict())


def load_rig(path: str | os.PathLike) -> Rig:
    """Read a rig JSON file; ``ValueError`` naming the file on bad content."""
    return Rig.from_dict(read_json(path), where=os.fspath(path))
