"""What the decoder hands on: the reason flags, :class:`Decoded` and :class:`Scan`.

A pixel is valid where its reason is 0; otherwise the :class:`Reason` bits say why it was
left out. The per-pixel reasons of the decoder (low modulation, saturation, shadow, unwrapping,
panel extent) are completed by the neighbourhood checks (:func:`neighbourhood_reasons`:
``EDGE``, ``STEEP``) and by the triangulation (``NO_POINT``). A :class:`Scan` carries them on
to the report, so that nothing downstream decodes again.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np
import scipy.ndimage as ndi

__all__ = [
    "EDGE",
    "LOW_MODULATION",
    "NO_POINT",
    "OUT_OF_PANEL",
    "REASON_NAMES",
    "SATURATED",
    "SHADOW",
    "STEEP",
    "UNWRAP_ERROR",
    "Decoded",
    "Reason",
    "Scan",
    "finish_decoded",
    "neighbourhood_reasons",
]


class Reason(enum.IntFlag):
    """Why a pixel was left out: the bits of ``Decoded.reason`` and ``Scan.reason`` (0 = valid).

    The first five are the decoder's per-pixel tests, ``EDGE`` and ``STEEP`` its neighbourhood
    checks (:func:`neighbourhood_reasons`), ``NO_POINT`` the triangulation's. The module-level
    constants of the same names are the plain ``int`` values, for NumPy arithmetic on ``uint8``
    reason arrays (an ``IntFlag`` member is not a weakly typed Python int there).
    """

    LOW_MODULATION = 1  #: some frequency's amplitude B below ``min_modulation``
    SATURATED = 2  #: some frame at or above ``saturation``
    SHADOW = 4  #: mean intensity below ``min_albedo``
    UNWRAP_ERROR = 8  #: inconsistency between frequencies above ``unwrap_tolerance``
    OUT_OF_PANEL = 16  #: decoded coordinate outside the panel's physical extent
    EDGE = 32  #: an invalid pixel within ``erode`` pixels
    STEEP = 64  #: decoded coordinate changes faster than ``max_gradient`` panel px per camera px
    NO_POINT = 128  #: triangulation gave no finite point


LOW_MODULATION: int = Reason.LOW_MODULATION.value
SATURATED: int = Reason.SATURATED.value
SHADOW: int = Reason.SHADOW.value
UNWRAP_ERROR: int = Reason.UNWRAP_ERROR.value
OUT_OF_PANEL: int = Reason.OUT_OF_PANEL.value
EDGE: int = Reason.EDGE.value
STEEP: int = Reason.STEEP.value
NO_POINT: int = Reason.NO_POINT.value

#: Short descriptions of the bits, in bit order, for reports.
REASON_NAMES: dict[Reason, str] = {
    Reason.LOW_MODULATION: "low modulation",
    Reason.SATURATED: "saturated",
    Reason.SHADOW: "shadow (no signal)",
    Reason.UNWRAP_ERROR: "unwrap error",
    Reason.OUT_OF_PANEL: "outside the panel",
    Reason.EDGE: "edge",
    Reason.STEEP: "steep",
    Reason.NO_POINT: "no 3D point",
}


@dataclass
class Decoded:
    """Per-pixel result of :func:`decode` for one camera.

    Attributes
    ----------
    xp, yp : (H, W) float32 or None
        Projector panel coordinates (column, row), px, NaN where invalid; ``None`` when the
        pattern set has no frequencies in that direction.
    modulation : (H, W) float32
        Fringe amplitude ``B`` of the finest frequency (the smaller of the two directions), in
        intensity units ``[0, 1]`` (full scale = 1).
    albedo : (H, W) float32
        Mean intensity over all frames, ``[0, 1]`` (the thesis's C image).
    intensity : (H, W) float32
        Projector-lit intensity ``2 B`` (the thesis's I image), 0 where invalid.
    mask : (H, W) bool
        Valid pixels (``reason == 0``).
    reason : (H, W) uint8
        Bit set of :data:`LOW_MODULATION`, :data:`SATURATED`, :data:`SHADOW`,
        :data:`UNWRAP_ERROR`, :data:`OUT_OF_PANEL` (per pixel), :data:`EDGE`, :data:`STEEP`
        (neighbourhood checks on the per-pixel validity) and :data:`NO_POINT` (triangulation).
    xyz : (H, W, 3) float32 or None
        World points (mm, NaN where invalid) when a triangulation table was given.
    coords : (n_dirs, H, W) float32 or None
        The one buffer behind `xp` and `yp` when :func:`~nail2nail.scan.kernels.decode_fast`
        made them (``out=`` reuses it); ``None`` otherwise.
    """

    xp: np.ndarray | None
    yp: np.ndarray | None
    modulation: np.ndarray
    albedo: np.ndarray
    intensity: np.ndarray
    mask: np.ndarray
    reason: np.ndarray
    xyz: np.ndarray | None = None
    coords: np.ndarray | None = field(default=None, repr=False)

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)``."""
        return self.mask.shape


def neighbourhood_reasons(reason, coords, *, erode: int = 1, max_gradient: float | None = None):
    """Add :data:`EDGE` and :data:`STEEP` to per-pixel reasons (NumPy reference).

    Parameters
    ----------
    reason : (H, W) uint8
        Per-pixel reasons (0 = valid).
    coords : sequence of (H, W) float arrays
        Decoded coordinates (values at invalid pixels are ignored).
    erode : int
        A valid pixel with an invalid pixel within Chebyshev distance `erode` gets
        :data:`EDGE`: mixed pixels at silhouettes and shadow borders.
    max_gradient : float or None
        A valid pixel whose 4 neighbours are valid gets :data:`STEEP` when the central-difference
        gradient of a coordinate exceeds this, panel px per camera px (fringes too dense for the
        camera's blur: the phase is biased). ``None`` disables.

    Returns
    -------
    (H, W) uint8
    """
    reason = np.asarray(reason, dtype=np.uint8)
    valid = reason == 0
    out = reason.copy()
    if erode > 0:
        kept = ndi.binary_erosion(valid, structure=np.ones((3, 3), bool), iterations=erode,
                                  border_value=1)
        out[valid & ~kept] |= EDGE
    if max_gradient is not None:
        inner = np.zeros_like(valid)
        inner[1:-1, 1:-1] = (valid[1:-1, 1:-1] & valid[1:-1, :-2] & valid[1:-1, 2:]
                             & valid[:-2, 1:-1] & valid[2:, 1:-1])
        for u in coords:
            u = np.asarray(u, dtype=np.float32)
            gx = np.zeros_like(u)
            gy = np.zeros_like(u)
            gx[1:-1, 1:-1] = (u[1:-1, 2:] - u[1:-1, :-2]) * np.float32(0.5)
            gy[1:-1, 1:-1] = (u[2:, 1:-1] - u[:-2, 1:-1]) * np.float32(0.5)
            with np.errstate(invalid="ignore"):
                steep = inner & (gx * gx + gy * gy > np.float32(max_gradient) ** 2)
            out[steep] |= STEEP
    return out


def finish_decoded(reason, coords: dict, modulation, albedo, *, erode: int,
                   max_gradient: float | None, keep_invalid: bool) -> Decoded:
    """The :class:`Decoded` of any scheme from its per-pixel reasons: the neighbourhood checks
    (:func:`neighbourhood_reasons`), the mask, NaN outside it (unless `keep_invalid`) and the
    lit intensity ``2 B`` (``B`` = `modulation`, the finest fringe's amplitude).

    Parameters
    ----------
    reason : (H, W) uint8
        Per-pixel reasons so far.
    coords : dict of str to (H, W) float32
        Decoded panel coordinate per direction (``"x"``, ``"y"``), modified in place.
    modulation, albedo : (H, W) float
        Fringe amplitude and mean intensity, fractions of full scale.
    """
    reason = neighbourhood_reasons(reason, list(coords.values()), erode=erode,
                                   max_gradient=max_gradient)
    mask = reason == 0
    if not keep_invalid:
        for u in coords.values():
            u[~mask] = np.nan
    intensity = np.where(mask, np.float32(2.0) * modulation, np.float32(0.0))
    return Decoded(
        xp=coords.get("x"),
        yp=coords.get("y"),
        modulation=modulation.astype(np.float32, copy=False),
        albedo=albedo.astype(np.float32, copy=False),
        intensity=np.minimum(intensity, np.float32(1.0)).astype(np.float32),
        mask=mask,
        reason=reason,
    )


@dataclass
class Scan:
    """One camera's 3D scan on its pixel grid (the content of a legacy mat5 set and more).

    Attributes
    ----------
    name : str
        Camera name, e.g. ``"cam0"``.
    xyz : (H, W, 3) float32
        World points, mm; NaN where invalid.
    xp, yp : (H, W) float32
        Decoded projector coordinates, panel px; NaN where invalid.
    albedo : (H, W) float32
        Mean intensity in ``[0, 1]`` (the thesis's C image).
    intensity : (H, W) float32
        Projector-lit intensity ``2 B`` clipped to 1 (the thesis's I image; 0 where invalid).
    modulation : (H, W) float32
        Fringe amplitude ``B`` in ``[0, 1]``; a quality weight.
    mask : (H, W) bool
        Valid pixels.
    camera_center : (3,) float64 or None
        Optical centre in world mm (for viewing angles).
    projector_center : (3,) float64 or None
        The projector's optical centre in world mm (for the angle of incidence of its light,
        :func:`nail2nail.merge.incidence_cosine`); None when not known (a mat5 set, an older
        scan file).
    reason : (H, W) uint8 or None
        Why each pixel was left out, :class:`Reason` bits (0 where the decoder and the
        triangulation kept it; a pixel with reason 0 outside `mask` was cut by a user mask);
        ``None`` for a scan read from a file that does not store it (a mat5 set, an older
        scan file).
    motion : dict or None
        What the frames say of the finger's motion during the capture
        (:meth:`nail2nail.scan.motion.MotionEstimate.to_dict`); None when not measured.
    fringe_periods : dict or None
        The finest fringe period of each decoded direction, panel px (``{"x": 20.0, "y":
        16.25}`` for the default patterns, :func:`nail2nail.scan.patterns.fringe_periods`):
        the period of the decoder's systematic error, which the unroll takes out of the
        ridge signal (:mod:`nail2nail.unroll.fringes`); None when not known (a mat5 set, an
        older scan file).
    triangulated_from : {"xpyp", "xp", "yp"} or None
        The projector coordinates the points were triangulated from (``use`` of
        :func:`nail2nail.scan.scan_frames`; a stabilised capture's is its reference
        direction's); the merge pairs scans by these (:func:`nail2nail.merge.correspond`'s
        `pair_by`). None when not known (a mat5 set, an older scan file): taken as both.
    """

    name: str
    xyz: np.ndarray
    xp: np.ndarray
    yp: np.ndarray
    albedo: np.ndarray
    intensity: np.ndarray
    modulation: np.ndarray
    mask: np.ndarray
    camera_center: np.ndarray | None = field(default=None)
    reason: np.ndarray | None = field(default=None)
    motion: dict | None = field(default=None)
    fringe_periods: dict | None = field(default=None)
    projector_center: np.ndarray | None = field(default=None)
    triangulated_from: str | None = field(default=None)

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)``."""
        return self.mask.shape

