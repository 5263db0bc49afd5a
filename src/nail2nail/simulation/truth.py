"""Reading the ground truth of a virtual capture (``truth/`` of ``simulate``) for evaluation.

A finger capture's truth holds, per camera, the rolled-print coordinates ``(u, v)`` (mm) of the
true surface point each pixel sees (``param_u``, ``param_v`` of ``truth/camN.npz``), and the
true rolled print in the legacy convention with its geometry (``truth/rolled_print.png``,
``truth/fingerprint.json``: ``col = (u_of_col0_mm − u) / pitch_mm``,
``row = (v_of_row0_mm − v) / pitch_mm``). For a synthetic print that image covers what a
rolled print records, the friction-ridge skin from nail edge to nail edge and from the tip to
``rolled_length_mm`` (``Finger.rolled_print``); skin seen by the cameras outside it (the sides
beyond the nail edges, the finger below the distal crease) is white in it.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from nail2nail.io._json import read_json
from nail2nail.io._npz import read_npz

__all__ = ["surface_distance", "truth_print_sampler", "truth_skin_coordinates"]


def _truth_entries(capture_dir: Path) -> dict:
    manifest = read_json(capture_dir / "capture.json")
    truth = manifest.get("truth") if isinstance(manifest, dict) else None
    if not truth:
        raise ValueError(f"{capture_dir}: the capture has no truth/ (a virtual capture "
                         "written with truth is needed)")
    return truth


def truth_skin_coordinates(capture_dir: str | os.PathLike, names) -> list[tuple]:
    """Per camera name, the true ``(u, v)`` (each ``(H, W) float32``, mm; NaN off the finger).

    Parameters
    ----------
    capture_dir : path-like
        A virtual capture written with its truth (``nail2nail simulate``).
    names : sequence of str
        Camera names, e.g. ``[s.name for s in scans]``.

    Returns
    -------
    list of (u, v)
        Rolled-print coordinates of the true surface point each pixel sees (``param_u``,
        ``param_v`` of ``truth/camN.npz``; ``u`` around the finger towards ``+X``, ``v``
        towards the tip), NaN where the pixel sees no finger.

    Raises
    ------
    ValueError
        If the capture has no truth, or no skin coordinates for a camera.
    """
    capture_dir = Path(capture_dir)
    cameras = _truth_entries(capture_dir).get("cameras", {})
    out = []
    for name in names:
        if name not in cameras:
            raise ValueError(f"{capture_dir}: no truth for camera {name!r}")
        path = capture_dir / cameras[name]
        data = read_npz(path, required=("param_u", "param_v"), what="truth file")
        surface = data.get("surface", np.ones(data["param_u"].shape, bool))
        u = np.where(surface, data["param_u"], np.nan).astype(np.float32)
        v = np.where(surface, data["param_v"], np.nan).astype(np.float32)
        out.append((u, v))
    return out


def truth_print_sampler(capture_dir: str | os.PathLike):
    """``(image (H, W) uint8, sampler)``: the true print and ``sampler(u, v) -> ridge field``.

    The sampler interpolates the print bilinearly at rolled-print coordinates (mm) and returns
    ``(127.5 − I) / 127.5`` (positive on ridges, which are dark); white paper (−1) outside the
    image, as inside it beyond the rolled extent.

    Parameters
    ----------
    capture_dir : path-like
        A virtual finger capture written with its truth.

    Returns
    -------
    image : (H, W) uint8
        ``truth/rolled_print.png`` (legacy convention).
    sampler : callable
        ``(u (N,), v (N,)) -> (N,) float``, mm in, ridge field out.

    Raises
    ------
    ValueError
        If the capture has no truth or its truth has no rolled print.
    """
    from PIL import Image
    from scipy.ndimage import map_coordinates

    capture_dir = Path(capture_dir)
    truth = _truth_entries(capture_dir)
    if "rolled_print" not in truth or "fingerprint" not in truth:
        raise ValueError(f"{capture_dir}: the truth has no rolled print (not a finger?)")
    geometry = read_json(capture_dir / truth["fingerprint"])
    with Image.open(capture_dir / truth["rolled_print"]) as im:
        image = np.asarray(im.convert("L"))
    u0, v0 = float(geometry["u_of_col0_mm"]), float(geometry["v_of_row0_mm"])
    pitch = float(geometry["pitch_mm"])
    data = image.astype(np.float64)

    def sampler(u, v):
        col = (u0 - np.asarray(u, float)) / pitch
        row = (v0 - np.asarray(v, float)) / pitch
        value = map_coordinates(data, [row, col], order=1, mode="constant", cval=255.0)
        return (127.5 - value) / 127.5

    return image, sampler


def surface_distance(points, camera, pixel, truths) -> np.ndarray:
    """Signed distance of measured points from the true surface, mm.

    Each point is compared with the true point of the camera pixel it was measured at, along
    that point's true outward normal (first order: the surface is flat over the gap), so
    what is measured is the error across the surface, not a slide along it.

    Parameters
    ----------
    points : (N, 3) float
        World points, mm (a super scan's ``vertices``).
    camera : (N,) int
        Index into `truths` of each point's camera (``SuperScan.camera``).
    pixel : (N, 2) int
        ``(row, col)`` of each point in its camera (``SuperScan.pixel``).
    truths : sequence of dict
        Per camera, its truth (:func:`nail2nail.io.capture.read_truth`): ``xyz`` and
        ``normal``, (H, W, 3), world mm and unit vectors.

    Returns
    -------
    (N,) float64
        Positive outside the true surface; NaN where the pixel sees no true surface.

    Examples
    --------
    >>> xyz = np.zeros((1, 2, 3)); normal = np.zeros((1, 2, 3)); normal[..., 2] = 1
    >>> truth = {"xyz": xyz, "normal": normal}
    >>> surface_distance([[0.5, 0, 0.01], [0, 0, -0.02]], [0, 0], [[0, 0], [0, 1]], [truth])
    array([ 0.01, -0.02])
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    camera = np.asarray(camera).reshape(-1)
    pixel = np.asarray(pixel).reshape(-1, 2)
    out = np.full(len(points), np.nan)
    for k, truth in enumerate(truths):
        sel = np.flatnonzero(camera == k)
        r, c = pixel[sel, 0], pixel[sel, 1]
        gap = points[sel] - np.asarray(truth["xyz"], dtype=np.float64)[r, c]
        out[sel] = np.sum(gap * np.asarray(truth["normal"], dtype=np.float64)[r, c], axis=-1)
    return out
