"""Projector radial distortion: the thesis's model (eq. 3.34), its look-up-table correction
(appendix ``distortion2dlut`` / ``distortionradial``) and its estimation (eq. 3.17–3.42).

Model (``docs/conventions.md``): a panel pixel at radius ``r`` from the optical centre ``c``
appears where an ideal pinhole projector puts radius ``r + ρ³ r³``.
"""

from __future__ import annotations

import numpy as np

from ._validation import as_float_array

__all__ = ["THESIS_CENTER", "THESIS_RHO", "ideal_from_panel", "panel_from_ideal"]

#: Optical centre of the thesis's projector, panel px (chapter three).
THESIS_CENTER = (640.0, 1000.0)
#: Radial distortion parameter of the thesis's projector (chapter three).
THESIS_RHO = -0.004


def ideal_from_panel(xy_panel, center=THESIS_CENTER, rho: float = THESIS_RHO) -> np.ndarray:
    """Ideal (pinhole) coordinates of panel coordinates: ``r ↦ r + ρ³ r³`` (eq. 3.34).

    Parameters
    ----------
    xy_panel : (..., 2) float
        Panel coordinates, projector px.
    center : (2,) float
        Optical centre ``(x, y)``, projector px.
    rho : float
        Distortion parameter ρ; negative is barrel.

    Returns
    -------
    (..., 2) float64
        Ideal coordinates, projector px.

    Examples
    --------
    >>> ideal_from_panel([[640.0, 0.0]]).round(3).tolist()
    [[640.0, 64.0]]
    """
    xy = as_float_array(xy_panel, "xy_panel")
    c = np.asarray(center, dtype=float)
    d = xy - c
    r2 = np.sum(d * d, axis=-1, keepdims=True)
    return c + d * (1.0 + rho**3 * r2)


def panel_from_ideal(xy_ideal, center=THESIS_CENTER, rho: float = THESIS_RHO) -> np.ndarray:
    """Inverse of :func:`ideal_from_panel`: solve ``r + ρ³ r³ = s`` for ``r`` (Newton).

    The cubic is monotonic for ``r < 1 / (√3 |ρ|^{3/2})`` (about 2280 px for the thesis's ρ),
    which covers the panel; radii beyond the turning point have no inverse and give NaN.

    Examples
    --------
    >>> xy = np.array([[100.0, 20.0], [1200.0, 900.0]])
    >>> bool(np.allclose(ideal_from_panel(panel_from_ideal(xy)), xy, atol=1e-9))
    True
    """
    xy = as_float_array(xy_ideal, "xy_ideal")
    c = np.asarray(center, dtype=float)
    d = xy - c
    s = np.sqrt(np.sum(d * d, axis=-1))
    k = rho**3
    if k == 0:
        return xy.astype(float, copy=True)
    r = s.copy()
    with np.errstate(invalid="ignore", divide="ignore"):
        for _ in range(30):
            f = r + k * r**3 - s
            r = r - f / (1 + 3 * k * r**2)
        if k < 0:
            r_max = 1.0 / np.sqrt(-3 * k)
            r = np.where((r > r_max) | (s > r_max + k * r_max**3), np.nan, r)
        scale = np.where(s > 0, r / np.where(s > 0, s, 1), 1.0)
    return c + d * scale[..., None]
