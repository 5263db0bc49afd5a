"""Rendering: per-camera geometry (computed once) and frames for any projector image sequence.

:func:`camera_geometry` casts the ray of every camera pixel (through the pixel centre, OpenCV
pinhole model with optional distortion), intersects the scene, checks that the projector sees
the hit point (the first hit along the projector's ray from its centre, and the surface facing
it), and maps the point into the projector: pinhole → ideal coordinates → thesis distortion
inverted → panel coordinates (eq. 3.34). It also precomputes the bilinear sampling of the panel
and the irradiance factor, so that :func:`render_frames` costs a few array operations per frame.

Image formation (fractions of full scale), for a pattern value ``P`` (8-bit) at the panel
coordinate of a pixel:

    ``E = blur_p((P / 255) ** gamma)``  (projector response and defocus, on the panel; with a
    ``projector_fill_factor`` each panel pixel is a sharp square aperture instead, see
    :func:`aperture_weights`),
    ``L = power · cos(incidence) · (d_ref / d)² · E``  (projector light on the skin),
    ``L ← blur_s(L)``  (subsurface spread, σ ``subsurface_mm``; none by default),
    ``s = albedo · (ambient · power + L) + specular · power · (n·h)^m · (d_ref / d)² · E``,
    ``s ← blur_c(s)``  (camera defocus),
    ``electrons = s · full_well`` + shot noise ``√electrons`` + read noise,
    quantised to ``bit_depth`` bits (``round``, clipped).

Pixels that see no surface stay black; shadowed pixels get the ambient term only. The blurs
(subsurface, camera) are applied to an image rendered :func:`blur_margin` pixels beyond each
side of the sensor and cropped afterwards, as a lens integrates the scene beyond the sensor's
edge.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.ndimage as ndi

from nail2nail.calibration.camera_models import Pinhole
from nail2nail.scan.motion import mm_per_pixel
from nail2nail.simulation.rig import Photometry, Rig
from nail2nail.simulation.scenes import Scene

__all__ = ["CameraGeometry", "blur_margin", "camera_geometry", "frame_flicker",
           "projector_radiance", "render_frames"]

#: hit points closer than this to the projector's own first hit count as lit (mm)
SHADOW_TOLERANCE_MM = 1e-3


@dataclass
class CameraGeometry:
    """Ground truth of one camera, and what rendering needs from it.

    Attributes
    ----------
    xyz : (H, W, 3) float64
        World point seen by each pixel, mm; NaN where the camera sees no surface.
    normal : (H, W, 3) float64
        Unit outward surface normal; NaN where no surface.
    surface : (H, W) bool
        The pixel sees the surface.
    mask : (H, W) bool
        The pixel sees the surface, the projector lights that point (no shadow, surface facing
        it) and the panel coordinate lies on the panel: ``xp, yp`` are valid.
    xp, yp : (H, W) float64
        True panel coordinates of the projector pixel lighting the point, projector px;
        NaN outside `mask`.
    xp_ideal, yp_ideal : (H, W) float64
        The same in ideal (pinhole) projector coordinates.
    albedo : (H, W) float32
        Surface albedo (0 where no surface).
    irradiance : (H, W) float32
        ``cos(incidence) · (d_ref / d)²`` of the projector light (0 outside `mask`).
    specular : (H, W) float32
        ``specular · max(n·h, 0)^m · (d_ref / d)²`` (Blinn-Phong, ``h`` the half vector of the
        directions to the projector and to the camera; 0 outside `mask` or without
        highlights).
    mm_per_px : float
        Median distance between horizontally adjacent surface points, mm (the camera's
        sampling of the surface: the subsurface spread's scale in pixels).
    params : dict of str to (H, W) float64
        Scene surface parameters (finger: rolled-print ``u, v`` in mm); NaN where no surface.
    camera : Pinhole
    name : str
    margin : int
        Pixels rendered beyond each side of the sensor for the blurs (camera defocus,
        subsurface spread), which reach that far into the image; :attr:`extended` holds that
        larger geometry and the frames are cropped to the sensor after the blurs. A sensor's
        optics integrate the light of the scene beyond its edge too: a blur with the edge
        pixels repeated instead would bend the fringes' phase in the outer rows.
    """

    xyz: np.ndarray
    normal: np.ndarray
    surface: np.ndarray
    mask: np.ndarray
    xp: np.ndarray
    yp: np.ndarray
    xp_ideal: np.ndarray
    yp_ideal: np.ndarray
    albedo: np.ndarray
    irradiance: np.ndarray
    params: dict
    camera: Pinhole
    name: str = "cam0"
    specular: np.ndarray | None = None
    mm_per_px: float = float("nan")
    margin: int = 0
    extended: CameraGeometry | None = field(default=None, repr=False)
    _sampler: tuple | None = field(default=None, repr=False)
    _aperture: tuple | None = field(default=None, repr=False)

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)`` of the camera image."""
        return self.surface.shape

    def truth_arrays(self) -> dict[str, np.ndarray]:
        """The arrays of ``truth/<camera>.npz`` (see ``docs/capture-format.md``)."""
        out: dict[str, np.ndarray] = {
            "xyz": self.xyz.astype(np.float64), "normal": self.normal.astype(np.float32),
            "xp": self.xp, "yp": self.yp, "xp_ideal": self.xp_ideal, "yp_ideal": self.yp_ideal,
            "mask": self.mask, "surface": self.surface, "albedo": self.albedo,
            "irradiance": self.irradiance,
        }
        for key, value in self.params.items():
            out[f"param_{key}"] = value
        return out


def _pixel_grid(camera: Pinhole, margin: int = 0) -> np.ndarray:
    width, height = camera.size
    cols, rows = np.meshgrid(np.arange(-margin, width + margin, dtype=float),
                             np.arange(-margin, height + margin, dtype=float))
    return np.stack([cols, rows], axis=-1).reshape(-1, 2)


def blur_margin(camera: Pinhole, photometry: Photometry, scale: float = 1.0) -> int:
    """Pixels the camera's blurs reach into the image from beyond its edge (4 σ): the camera
    defocus (`camera_blur_px` at full resolution, times `scale`) and the subsurface spread
    (`subsurface_mm` over the pixel's footprint at the camera's distance from the origin,
    the rig's working point)."""
    sigma = photometry.camera_blur_px * scale
    if photometry.subsurface_mm > 0:
        footprint = float(np.linalg.norm(camera.center)) / float(camera.K[0, 0])
        sigma += photometry.subsurface_mm / footprint
    return int(np.ceil(4 * sigma)) if sigma > 0 else 0


def camera_geometry(rig: Rig, scene: Scene, camera_index: int) -> CameraGeometry:
    """Intersect every pixel ray of one camera with the scene; shadows; panel coordinates.

    Parameters
    ----------
    rig : Rig
    scene : Scene
    camera_index : int

    Returns
    -------
    CameraGeometry
    """
    if not 0 <= camera_index < len(rig.cameras):
        raise ValueError(f"camera_index: expected 0..{len(rig.cameras) - 1}, got {camera_index}")
    camera = rig.cameras[camera_index]
    margin = blur_margin(camera, rig.photometry, rig.scale)
    geometry = _geometry(rig, scene, camera_index, margin)
    if margin == 0:
        return geometry
    # the sensor's own pixels; rendering uses the extended geometry, cropped after the blurs
    inner = (slice(margin, -margin), slice(margin, -margin))
    sensor = CameraGeometry(
        xyz=geometry.xyz[inner], normal=geometry.normal[inner],
        surface=geometry.surface[inner], mask=geometry.mask[inner],
        xp=geometry.xp[inner], yp=geometry.yp[inner], xp_ideal=geometry.xp_ideal[inner],
        yp_ideal=geometry.yp_ideal[inner], albedo=geometry.albedo[inner],
        irradiance=geometry.irradiance[inner],
        params={k: v[inner] for k, v in geometry.params.items()}, camera=camera,
        name=geometry.name,
        specular=None if geometry.specular is None else geometry.specular[inner],
        margin=margin, extended=geometry)
    spacing = mm_per_pixel(sensor.xyz, sensor.surface)
    sensor.mm_per_px = float("nan") if spacing is None else spacing
    geometry.mm_per_px = sensor.mm_per_px  # the subsurface spread's scale: the sensor's
    return sensor


def _geometry(rig: Rig, scene: Scene, camera_index: int, margin: int) -> CameraGeometry:
    """:func:`camera_geometry` over the sensor and `margin` pixels beyond each side."""
    camera = rig.cameras[camera_index]
    width, height = camera.size
    width, height = width + 2 * margin, height + 2 * margin
    n = width * height
    origin, dirs = camera.rays(_pixel_grid(camera, margin))
    t = scene.intersect(origin, dirs)
    surface = np.isfinite(t)
    idx = np.flatnonzero(surface)
    pts = origin + t[idx, None] * dirs[idx]
    info = scene.surface(pts)
    normal = info.normal
    # shadow test: the projector's first hit along its ray to the point must be the point
    c_p = rig.projector.center
    to_p = c_p - pts
    dist = np.linalg.norm(to_p, axis=-1)
    l_dir = to_p / dist[:, None]
    cos_inc = np.einsum("ij,ij->i", normal, l_dir)
    t_proj = scene.intersect(c_p, -l_dir)
    # lit: the projector's own first hit is this point (earlier: shadow; later: the projector's
    # ray only grazes the surface here and the marcher stepped over it — counted as unlit)
    lit = (cos_inc > 0) & (np.abs(t_proj - dist) <= SHADOW_TOLERANCE_MM)
    ideal = rig.projector.project(pts)
    panel = rig.panel_from_ideal(ideal)
    pw, ph = rig.panel_size
    on_panel = (
        (panel[:, 0] >= -0.5) & (panel[:, 0] <= pw - 0.5)
        & (panel[:, 1] >= -0.5) & (panel[:, 1] <= ph - 0.5)
    )
    lit &= on_panel & np.all(np.isfinite(panel), axis=-1)

    def full(values, fill, dtype=np.float64):
        shape = (n, *values.shape[1:])
        out = np.full(shape, fill, dtype=dtype)
        out[idx] = values
        return out.reshape((height, width, *values.shape[1:]))

    xyz = full(pts, np.nan)
    lit_full = np.zeros(n, dtype=bool)
    lit_full[idx] = lit
    panel_lit = np.where(lit[:, None], panel, np.nan)
    ideal_lit = np.where(lit[:, None], ideal, np.nan)
    photometry = rig.photometry
    ref = photometry.reference_distance_mm
    irr = np.where(lit, cos_inc * (ref / dist) ** 2, 0.0)
    spec = np.zeros_like(irr)
    if photometry.specular > 0:
        to_c = camera.center - pts
        half = l_dir + to_c / np.linalg.norm(to_c, axis=-1)[:, None]
        half /= np.linalg.norm(half, axis=-1)[:, None]
        cos_h = np.clip(np.einsum("ij,ij->i", normal, half), 0, 1)
        spec = np.where(lit, photometry.specular * cos_h**photometry.specular_exponent
                        * (ref / dist) ** 2, 0.0)
    geometry = CameraGeometry(
        xyz=xyz,
        normal=full(normal, np.nan),
        surface=surface.reshape(height, width),
        mask=lit_full.reshape(height, width),
        xp=full(panel_lit[:, 0], np.nan), yp=full(panel_lit[:, 1], np.nan),
        xp_ideal=full(ideal_lit[:, 0], np.nan), yp_ideal=full(ideal_lit[:, 1], np.nan),
        albedo=full(info.albedo, 0.0, np.float32),
        irradiance=full(irr, 0.0, np.float32),
        params={k: full(v, np.nan) for k, v in info.params.items()},
        camera=camera,
        name=rig.camera_names[camera_index],
        specular=full(spec, 0.0, np.float32),
    )
    spacing = mm_per_pixel(xyz, geometry.surface)  # the scan stage's own measure of it
    geometry.mm_per_px = float("nan") if spacing is None else spacing
    geometry._sampler = _bilinear_plan(geometry, rig.panel_size)
    if photometry.projector_fill_factor is not None:
        geometry._aperture = aperture_weights(geometry, photometry)
    return geometry


#: at most this many panel pixels either side of a camera pixel's panel coordinate are summed
MAX_APERTURE_HALF_WIDTH = 8


def _box_gauss(d, width, sigma):
    """``(1/width) ∫ box_width(d − x) N(x; σ) dx``: a sharp aperture of `width` px, blurred."""
    from scipy.special import ndtr

    s = np.maximum(sigma, 1e-3)
    return ((ndtr((d + width / 2) / s) - ndtr((d - width / 2) / s)) / width).astype(np.float32)


def aperture_weights(geometry: CameraGeometry, photometry: Photometry) -> tuple:
    """Weights of the panel pixels that light each lit camera pixel (sharp-aperture model).

    A panel pixel ``i`` emits through a square aperture of side ``a = √fill`` px centred on
    it, normalised to the pixel's mean radiance (``1/a`` per axis), blurred by the projector's
    defocus σ_p (`projector_blur_px`). A camera pixel integrates over its footprint on the
    panel, the parallelogram spanned by the panel coordinate's steps to the next column and
    row; its variance ``(J_c² + J_r²)/12`` per axis is added to σ_p² (a box taken as the
    Gaussian of the same variance). The radiance a pixel sees is then
    ``Σ_j Σ_l wx_j wy_l E[iy + l, ix + j]``, separable per axis.

    Parameters
    ----------
    geometry : CameraGeometry
        With ``xp``, ``yp`` and ``mask``.
    photometry : Photometry
        With ``projector_fill_factor`` set.

    Returns
    -------
    tuple
        ``(K, ix, iy, wx, wy)``: the half width ``K`` of the window (px), the panel pixel of
        offset ``−K`` for each lit pixel (into the panel padded by ``K + 1`` dark pixels) and
        the weights ``(n_lit, 2K + 1)`` float32 per axis.
    """
    assert photometry.projector_fill_factor is not None  # documented: set
    width = float(np.sqrt(photometry.projector_fill_factor))
    lit = geometry.mask
    var = []
    for p in (geometry.xp, geometry.yp):
        with np.errstate(invalid="ignore"):
            jr, jc = np.gradient(p)
        foot = (jr * jr + jc * jc)[lit]
        fill = np.nanmedian(foot) if np.isfinite(foot).any() else 0.0
        foot = np.where(np.isfinite(foot), np.minimum(foot, 16.0), fill)
        var.append(photometry.projector_blur_px**2 + foot / 12.0)
    sigma = np.sqrt(np.maximum(var[0], var[1]))
    half = int(np.ceil(width / 2 + 3 * float(sigma.max(initial=0.0))))
    half = min(max(half, 1), MAX_APERTURE_HALF_WIDTH)
    offsets = np.arange(-half, half + 1)
    out = [half]
    for p, v in zip((geometry.xp, geometry.yp), var, strict=True):
        x = p[lit]
        centre = np.rint(x)
        d = (x - centre)[:, None] - offsets[None, :]
        out.append(centre.astype(np.intp) + 1)  # offset −K in the panel padded by K + 1
        out.append(_box_gauss(d, width, np.sqrt(v)[:, None]))
    K, ix, wx, iy, wy = out
    return K, ix, iy, wx, wy


def _aperture_sample(aperture: tuple, emitted: np.ndarray, ones: tuple) -> np.ndarray:
    """Radiance seen by each lit pixel from the emitted panel values ``(Hp, Wp)``."""
    K, ix, iy, wx, wy = aperture
    pad = K + 1
    rows_equal = bool((emitted == emitted[:1]).all())
    cols_equal = bool((emitted == emitted[:, :1]).all())
    if rows_equal:  # a pattern along x (or uniform): one row, the rows' aperture precomputed
        row = np.pad(emitted[0], pad)
        return np.einsum("ij,ij->i", wx, row[ix[:, None] + np.arange(2 * K + 1)]) * ones[1]
    if cols_equal:
        col = np.pad(emitted[:, 0], pad)
        return np.einsum("ij,ij->i", wy, col[iy[:, None] + np.arange(2 * K + 1)]) * ones[0]
    panel = np.pad(emitted, pad)
    flat = panel.ravel()
    stride = panel.shape[1]
    out = np.zeros(len(ix), np.float32)
    for lr in range(2 * K + 1):
        base = (iy + lr) * stride + ix
        acc = np.zeros(len(ix), np.float32)
        for j in range(2 * K + 1):
            acc += wx[:, j] * flat[base + j]
        out += wy[:, lr] * acc
    return out


def _aperture_ones(aperture: tuple, panel_shape) -> tuple[np.ndarray, np.ndarray]:
    """Each axis's aperture sum over the panel's extent (the other axis of a 1-D pattern)."""
    K, ix, iy, wx, wy = aperture
    taps = np.arange(2 * K + 1)
    ph, pw = panel_shape
    on_x = np.pad(np.ones(pw, np.float32), K + 1)
    on_y = np.pad(np.ones(ph, np.float32), K + 1)
    return (np.einsum("ij,ij->i", wx, on_x[ix[:, None] + taps]),
            np.einsum("ij,ij->i", wy, on_y[iy[:, None] + taps]))


def _bilinear_plan(geometry: CameraGeometry, panel_size) -> tuple:
    """Flat indices and weights into the panel padded by one pixel (zeros) for lit pixels."""
    pw, ph = panel_size
    lit = np.flatnonzero(geometry.mask.ravel())
    x = geometry.xp.ravel()[lit] + 1.0  # padded coordinates
    y = geometry.yp.ravel()[lit] + 1.0
    x0 = np.clip(np.floor(x).astype(np.intp), 0, pw)
    y0 = np.clip(np.floor(y).astype(np.intp), 0, ph)
    fx = (x - x0).astype(np.float32)
    fy = (y - y0).astype(np.float32)
    stride = pw + 2
    i00 = y0 * stride + x0
    w = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy])
    return lit, i00, stride, w


def projector_radiance(pattern, photometry: Photometry) -> np.ndarray:
    """Emitted radiance of one panel image: gamma, defocus; padded by a dark 1-px border.

    Parameters
    ----------
    pattern : (Hp, Wp) uint8 or float
        8-bit panel image (floats are taken as values in ``[0, 1]``).

    Returns
    -------
    (Hp + 2, Wp + 2) float32
        With a ``projector_fill_factor`` (sharp apertures): ``(Hp, Wp)``, the emitted values
        after gamma alone (the apertures and defocus are applied per camera pixel,
        :func:`aperture_weights`).
    """
    p = np.asarray(pattern)
    if p.ndim != 2:
        raise ValueError(f"pattern: expected a 2-D panel image, got shape {p.shape}")
    if np.issubdtype(p.dtype, np.integer):
        lut = (np.arange(256, dtype=np.float64) / 255.0) ** photometry.projector_gamma
        if p.dtype != np.uint8:
            raise TypeError(f"pattern: expected uint8 or float values, got {p.dtype}")
        value = lut.astype(np.float32)[p]
    else:
        value = np.clip(p.astype(np.float32), 0, 1) ** np.float32(photometry.projector_gamma)
    if photometry.projector_fill_factor is not None:
        return value
    value = np.pad(value, 1)
    if photometry.projector_blur_px > 0:
        value = ndi.gaussian_filter(value, photometry.projector_blur_px, mode="constant")
    return value


def frame_flicker(photometry: Photometry, n_frames: int, seed: int | None) -> np.ndarray | None:
    """Each frame's projector brightness factor ``1 + projector_flicker · z_k``
    (:class:`~nail2nail.simulation.rig.Photometry`), ``(n_frames,) float32``; None without
    flicker (nothing to multiply: the frames stay byte-identical)."""
    if not photometry.projector_flicker:
        return None
    rng = [np.random.default_rng([0 if seed is None else int(seed), 0x666C, k])
           for k in range(n_frames)]
    z = np.array([r.standard_normal() for r in rng])
    return np.maximum(1 + photometry.projector_flicker * z, 0).astype(np.float32)


def render_frames(
    geometry: CameraGeometry,
    patterns,
    photometry: Photometry,
    *,
    seed: int | None = 0,
    camera_index: int = 0,
    scale: float = 1.0,
    radiance: list[np.ndarray] | None = None,
) -> np.ndarray:
    """Render the camera frames of a projector image sequence.

    Parameters
    ----------
    geometry : CameraGeometry
        From :func:`camera_geometry`.
    patterns : (n_frames, Hp, Wp) uint8
        Panel images, in order (the simulator does not interpret them).
    photometry : Photometry
    seed : int or None
        Noise seed; frame ``k`` of camera ``i`` draws from ``default_rng([seed, i, k])`` so any
        subset of frames and cameras renders reproducibly.
    camera_index : int
        Used for the noise stream only.
    scale : float
        Camera resolution scale: the camera blur (full-resolution px) is scaled by it.
    radiance : list of (Hp + 2, Wp + 2) float32, optional
        Precomputed :func:`projector_radiance` of `patterns` (shared between cameras), each
        times its :func:`frame_flicker` factor.

    Returns
    -------
    frames : (n_frames, H, W) uint8 (8-bit) or uint16 (10/12/16-bit, left-aligned)
    """
    patterns = np.asarray(patterns)
    if patterns.ndim != 3:
        raise ValueError(f"patterns: expected (n_frames, Hp, Wp), got shape {patterns.shape}")
    light = _LightPlan(geometry, photometry, patterns.shape[1:])
    height, width = geometry.shape
    dtype = np.uint8 if photometry.bit_depth == 8 else np.uint16
    frames = np.empty((len(patterns), height, width), dtype=dtype)
    flicker = frame_flicker(photometry, len(patterns), seed) if radiance is None else None
    for k, pattern in enumerate(patterns):
        if radiance is not None:  # computed by the caller, flicker included
            rad = radiance[k]
        else:
            rad = projector_radiance(pattern, photometry)
            if flicker is not None:
                rad = rad * flicker[k]
        frames[k] = expose(light.signal(rad), photometry, seed=seed, camera_index=camera_index,
                           frame=k, scale=scale, margin=light.margin)
    return frames


class _LightPlan:
    """What rendering a frame of one camera's geometry needs, computed once per geometry."""

    def __init__(self, geometry: CameraGeometry, photometry: Photometry, panel_shape) -> None:
        #: pixels beyond each side of the sensor in `signal`'s images (cropped by `expose`)
        self.margin = geometry.margin
        if geometry.extended is not None:
            geometry = geometry.extended
        assert geometry._sampler is not None  # set by camera_geometry
        lit, i00, stride, w = geometry._sampler
        ph, pw = panel_shape
        aperture = geometry._aperture if photometry.projector_fill_factor is not None else None
        if photometry.projector_fill_factor is not None and aperture is None:
            aperture = geometry._aperture = aperture_weights(geometry, photometry)
        self.ones = _aperture_ones(aperture, (ph, pw)) if aperture is not None else None
        if stride != pw + 2:
            raise ValueError(f"patterns: panel size {pw}x{ph} does not match the rig's projector "
                             f"({stride - 2} wide)")
        self.aperture, self.lit, self.i00, self.stride, self.w = aperture, lit, i00, stride, w
        self.shape = geometry.shape
        albedo = geometry.albedo.ravel()
        self.albedo = albedo
        self.base = albedo * np.float32(photometry.ambient * photometry.projector_power)
        power = np.float32(photometry.projector_power)
        self.light = geometry.irradiance.ravel()[lit] * power
        self.gain = albedo.ravel()[lit] * geometry.irradiance.ravel()[lit] * power
        self.specular = None
        if geometry.specular is not None and photometry.specular > 0:
            self.specular = geometry.specular.ravel()[lit] * power
        self.subsurface = photometry.subsurface_mm / geometry.mm_per_px \
            if photometry.subsurface_mm > 0 and geometry.mm_per_px > 0 else 0.0

    def signal(self, rad: np.ndarray) -> np.ndarray:
        """The irradiance image ``(H, W)`` float32 of one projector radiance, before the
        camera's blur and noise."""
        lit, i00, stride, w = self.lit, self.i00, self.stride, self.w
        height, width = self.shape
        if self.aperture is not None:
            assert self.ones is not None  # computed with aperture
            sample = _aperture_sample(self.aperture, rad, self.ones)
        else:
            flat = rad.ravel()
            sample = (w[0] * flat[i00] + w[1] * flat[i00 + 1] + w[2] * flat[i00 + stride]
                      + w[3] * flat[i00 + stride + 1])
        if self.subsurface > 0:
            lit_light = np.zeros(height * width, np.float32)
            lit_light[lit] = self.light * sample
            lit_light = ndi.gaussian_filter(lit_light.reshape(height, width), self.subsurface,
                                            mode="constant").ravel()
            signal = self.base + self.albedo * lit_light
        else:  # (the arithmetic of the default model, unchanged)
            signal = self.base.copy()
            signal[lit] += self.gain * sample
        if self.specular is not None:
            signal[lit] += self.specular * sample
        return signal.reshape(height, width)


def expose(image: np.ndarray, photometry: Photometry, *, seed: int | None, camera_index: int,
           frame: int, scale: float = 1.0, margin: int = 0) -> np.ndarray:
    """One camera frame from its irradiance image: the camera's blur, noise and quantisation.

    Parameters
    ----------
    image : (H, W) float32
        Irradiance, full scale 1 (e.g. the mean over an exposure's sub-steps).
    photometry : Photometry
    seed : int or None
        Noise seed; frame `frame` of camera `camera_index` draws from
        ``default_rng([seed, camera_index, frame])``. None: no noise.
    camera_index, frame : int
    scale : float
        Camera resolution scale (the blur is given in full-resolution px).
    margin : int
        Pixels beyond each side of the sensor in `image` (:attr:`CameraGeometry.margin`),
        cropped after the blur.

    Returns
    -------
    (H, W) uint8 (8-bit) or uint16 (10/12/16-bit, left-aligned)
    """
    bits = photometry.bit_depth
    top = 2**bits - 1
    dtype = np.uint8 if bits == 8 else np.uint16
    blur = photometry.camera_blur_px * scale
    if blur > 0:
        image = ndi.gaussian_filter(image, blur, mode="nearest")
    if margin:  # the sensor's pixels, after the blur (the noise is drawn over them only)
        image = image[margin:-margin, margin:-margin]
    if photometry.noise and seed is not None:
        rng = np.random.default_rng([seed, camera_index, frame])
        electrons = np.maximum(image, 0) * np.float32(photometry.full_well)
        noise = rng.standard_normal(image.shape, dtype=np.float32)
        noise *= np.sqrt(electrons + np.float32(photometry.read_noise**2))
        image = (electrons + noise) / np.float32(photometry.full_well)
    levels = np.rint(np.clip(image, 0, 1) * top)
    if bits != 8:
        levels = levels * 2 ** (16 - bits)
    return levels.astype(dtype)
