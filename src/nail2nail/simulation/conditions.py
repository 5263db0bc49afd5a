"""Random scanning conditions: the virtual scanner as many scanners, not one.

Every figure tuned on one simulator flatters the code that was tuned on it. A seed here draws
one *condition*, every optical and physical parameter of the virtual scanner from a stated
range: the projector (a soft or a sharp pixel grid, its fill factor and defocus, its gamma
against the patterns' pre-compensation, its frame-to-frame flicker), the cameras (defocus,
noise), the light (ambient, specular highlights, subsurface spread), the skin (albedo, the
ridges' albedo contrast and relief) and the finger (section, cap, taper, tilt, roll, yaw,
position), and the print (a synthetic class, or an image given by the caller).

:data:`RANGES` lists the ranges; :func:`draw_conditions` draws from them reproducibly
(``numpy.random.default_rng(["conditions", seed])``); :meth:`Conditions.rig` and
:meth:`Conditions.finger` build what :func:`~nail2nail.simulation.capture.simulate` takes.
``nail2nail simulate --conditions random --seed N`` is the command line; the drawn values are
recorded in ``capture.json`` (``conditions``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from nail2nail.simulation.fingerprint import PATTERNS
from nail2nail.simulation.rig import Photometry, Rig, default_rig

__all__ = ["RANGES", "Conditions", "draw_conditions"]

#: The ranges each condition is drawn from, uniformly (``(low, high)``), with what they model.
#: The patterns are pre-compensated for a gamma of 2.2; the projector's own gamma is drawn.
RANGES: dict[str, tuple] = {
    # projector
    "projector_sharp_probability": (0.7,),   # chance of a sharp pixel grid (else bilinear, soft)
    "projector_fill_factor": (0.55, 1.0),    # area of a pixel's aperture (sharp grid)
    "projector_blur_px": (0.0, 1.2),         # defocus σ, panel px: sharp to defocused
    "projector_gamma": (1.8, 2.6),           # against the patterns' 2.2 pre-compensation
    "projector_power": (0.6, 1.0),
    "projector_flicker": (0.0, 0.015),       # frame-to-frame brightness RMS (drawn last)
    # camera and light
    "camera_blur_px": (0.2, 1.0),            # defocus σ, camera px
    "ambient": (0.0, 0.15),
    "full_well": (8000.0, 30000.0),          # electrons: shot noise
    "read_noise": (4.0, 20.0),               # electrons
    "specular": (0.0, 0.3),                  # Blinn-Phong strength (0: Lambertian)
    "specular_exponent": (10.0, 80.0),
    "subsurface_mm": (0.0, 0.15),            # σ of the light's spread in the skin
    # skin
    "skin_albedo": (0.4, 0.8),
    "albedo_contrast": (0.05, 0.20),         # ridges' albedo contrast (subsurface lowers it)
    "relief_height": (0.03, 0.08),           # ridge relief peak to valley, mm
    # finger
    "ax": (7.0, 9.5),                        # half width of the section, mm
    "section_ratio": (0.75, 0.95),           # az / ax (elliptic section)
    "ay": (6.0, 10.0),                       # length of the tip's cap, mm
    "taper": (0.0, 0.01),                    # section growth per mm below the cap
    "tilt_deg": (-10.0, 10.0),
    "roll_deg": (-10.0, 10.0),
    "yaw_deg": (-10.0, 10.0),
    "offset_x_mm": (-1.5, 1.5),
    "offset_y_mm": (-1.0, 1.0),
    "offset_z_mm": (-1.5, 1.5),
}


@dataclass(frozen=True)
class Conditions:
    """One drawn condition of the virtual scanner (see :data:`RANGES`).

    Attributes
    ----------
    seed : int
    photometry : dict
        Keyword arguments of :class:`~nail2nail.simulation.rig.Photometry`.
    finger : dict
        Keyword arguments of :class:`~nail2nail.simulation.scenes.Finger` (shape, pose,
        skin, print class).
    """

    seed: int
    photometry: dict
    finger: dict

    def on_rig(self, rig: Rig) -> Rig:
        """`rig`'s geometry (cameras, projector, scale) with this condition's optics: its
        photometry's fields replaced by :attr:`photometry` (the reference distance kept)."""
        photometry = dataclasses.replace(rig.photometry, **self.photometry)
        return dataclasses.replace(rig, photometry=photometry)

    def rig(self, scale: float = 1.0, *, projector_distortion: str = "thesis") -> Rig:
        """:meth:`on_rig` of :func:`~nail2nail.simulation.rig.default_rig` at `scale` (camera
        resolution, 1 = 1280 × 1024 px) and `projector_distortion` (``"thesis"``, ``"none"``)."""
        return self.on_rig(default_rig(scale, projector_distortion=projector_distortion))

    def finger_options(self, *, print_image=None, print_ppi: float = 500.0) -> dict:
        """Keyword arguments of :func:`~nail2nail.simulation.scenes.make_scene` ``"finger"``;
        with `print_image`, the image replaces the synthetic print class."""
        options = dict(self.finger)
        if print_image is not None:
            options.pop("pattern", None)
            options.update(print_image=print_image, print_ppi=print_ppi)
        return options

    def to_dict(self) -> dict:
        """JSON-ready record (``capture.json`` → ``conditions``)."""
        finger = {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.finger.items()}
        return {"seed": self.seed, "photometry": dict(self.photometry), "finger": finger}


def draw_conditions(seed: int, ranges: dict | None = None) -> Conditions:
    """Draw one condition of the virtual scanner.

    Parameters
    ----------
    seed : int
        The same seed draws the same condition (independent of the fingerprint's and the
        noise's streams, which use `seed` as they always do).
    ranges : dict, optional
        Overrides of :data:`RANGES` (same keys; a ``(low, high)`` pair, or ``(value,)``).

    Returns
    -------
    Conditions

    Examples
    --------
    >>> c = draw_conditions(3)
    >>> 1.8 <= c.photometry["projector_gamma"] <= 2.6
    True
    >>> draw_conditions(3) == c
    True
    """
    r = dict(RANGES)
    if ranges:
        unknown = sorted(set(ranges) - set(RANGES))
        if unknown:
            raise ValueError(f"ranges: unknown key(s) {unknown}")
        r.update(ranges)
    rng = np.random.default_rng([0x6E32, int(seed)])  # "n2": a stream of its own

    def u(key: str) -> float:
        lo_hi = r[key]
        return float(lo_hi[0]) if len(lo_hi) == 1 else float(rng.uniform(lo_hi[0], lo_hi[1]))

    sharp = rng.uniform() < u("projector_sharp_probability")
    fill = u("projector_fill_factor")
    photometry: dict[str, Any] = {
        "projector_fill_factor": round(fill, 4) if sharp else None,
        "projector_blur_px": round(u("projector_blur_px"), 4),
        "projector_gamma": round(u("projector_gamma"), 4),
        "projector_power": round(u("projector_power"), 4),
        "camera_blur_px": round(u("camera_blur_px"), 4),
        "ambient": round(u("ambient"), 4),
        "full_well": round(u("full_well"), 1),
        "read_noise": round(u("read_noise"), 2),
        "specular": round(u("specular"), 4),
        "specular_exponent": round(u("specular_exponent"), 2),
        "subsurface_mm": round(u("subsurface_mm"), 4),
    }
    ax = u("ax")
    finger = {
        "ax": round(ax, 3),
        "az": round(ax * u("section_ratio"), 3),
        "ay": round(u("ay"), 3),
        "taper": round(u("taper"), 5),
        "rotation_deg": (round(u("tilt_deg"), 3), round(u("roll_deg"), 3),
                         round(u("yaw_deg"), 3)),
        "offset_mm": (round(u("offset_x_mm"), 3), round(u("offset_y_mm"), 3),
                      round(u("offset_z_mm"), 3)),
        "skin_albedo": round(u("skin_albedo"), 4),
        "albedo_contrast": round(u("albedo_contrast"), 4),
        "relief_height": round(u("relief_height"), 4),
        "pattern": PATTERNS[int(rng.integers(len(PATTERNS)))],
    }
    # drawn after everything else, so that the conditions drawn before it was added keep their
    # values
    photometry["projector_flicker"] = round(u("projector_flicker"), 5)
    Photometry(**photometry)  # checks the overrides' values
    return Conditions(seed=int(seed), photometry=photometry, finger=finger)
