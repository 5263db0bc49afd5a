"""Rigs with more than one projector: layouts, and the skin they light.

The thesis rig's one projector faces the pad and lights the finger to about ±90° from it; the
friction-ridge skin runs to the nail edges, about ±110° (``Finger.ridge_arc_deg``). Side
projectors light the rest. A rig of ``P`` projectors is described here as ``P`` rigs of one
projector that share their cameras (:func:`projector_rigs`): each ``(cameras, projector k)``
rig is a thesis rig, captured, calibrated and scanned as one, the projectors shown in turn
(time-multiplexed, ``24 P`` frames with the default patterns). The scans of every
``(camera, projector)`` pair are then fused together
(:func:`nail2nail.merge.fusion.fuse_scans` with ``projectors=…``).

A side projector is the thesis projector turned about the finger's axis (world ``Y`` through
the point the cameras look at) by its azimuth: same distance, elevation, optics and
distortion. :data:`LAYOUTS` names the layouts the benchmark compares
(``bench/projectors.py``); :func:`rolled_coverage` measures what a layout lights of the true
rolled print.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from nail2nail.calibration.camera_models import Pinhole
from nail2nail.simulation.rig import Rig, default_rig

__all__ = ["LAYOUTS", "projector_layout", "projector_rigs", "rolled_coverage",
           "simulate_projector_captures", "turned_projector"]

#: Projector azimuths of the named layouts, degrees about the finger's axis from the pad's
#: side (``+Z``) towards ``+X``; the first projector is the thesis rig's.
LAYOUTS: dict[str, tuple[float, ...]] = {
    "thesis": (0.0,),
    "sides-60": (0.0, -60.0, 60.0),
    "sides-75": (0.0, -75.0, 75.0),
    "sides-90": (0.0, -90.0, 90.0),
    "pair-45": (-45.0, 45.0),
}


def turned_projector(rig: Rig, azimuth_deg: float, *, axis_point=None) -> Rig:
    """The rig with its projector turned about the world ``Y`` axis by `azimuth_deg`.

    Parameters
    ----------
    rig : Rig
    azimuth_deg : float
        Rotation about ``+Y`` (from ``+Z`` towards ``+X``), degrees.
    axis_point : (3,) float, optional
        A point of the axis, mm; default the point on ``Y`` nearest the projector's optical
        axis (the point the default rig aims it at).

    Returns
    -------
    Rig
        Same cameras, photometry and projector optics and distortion; the projector's centre
        and orientation turned. ``azimuth_deg = 0`` returns an equal rig.

    Examples
    --------
    >>> rig = default_rig(0.25)
    >>> side = turned_projector(rig, 90.0)
    >>> c = side.projector.center
    >>> bool(abs(c[2]) < 1e-9 and c[0] > 150)
    True
    """
    p = rig.projector
    if axis_point is None:
        axis_point = _axis_point(p)
    c = np.asarray(axis_point, dtype=float).reshape(3)
    a = np.radians(float(azimuth_deg))
    # world rotation about +Y from +Z towards +X
    rot = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    # x_p = R X + t; turned: x_p = R rot^T (X − c) + R c + t
    R = p.R @ rot.T
    t = p.R @ c + p.t - R @ c
    turned = Pinhole(K=p.K.copy(), R=R, t=t, dist=np.asarray(p.dist).copy(), size=p.size)
    return replace(rig, projector=turned, camera_names=list(rig.camera_names))


def _axis_point(projector: Pinhole) -> np.ndarray:
    """The point of the world ``Y`` axis nearest the projector's optical axis."""
    centre = projector.center
    direction = projector.R[2]  # the optical axis in the world frame
    # closest points of the lines centre + s d and (0, y, 0)
    e = np.array([0.0, 1.0, 0.0])
    w = centre
    b = direction @ e
    denom = 1.0 - b * b
    if denom < 1e-12:
        return np.zeros(3)
    s = (b * (e @ w) - direction @ w) / denom
    y = (e @ w) + b * s
    return np.array([0.0, y, 0.0])


def projector_rigs(layout: str | Sequence[float] = "thesis", rig: Rig | None = None) -> list[Rig]:
    """One single-projector rig per projector of a layout, sharing the cameras of `rig`.

    Parameters
    ----------
    layout : str or sequence of float
        A name of :data:`LAYOUTS` or the projector azimuths, degrees.
    rig : Rig, optional
        The thesis rig whose projector is turned (default :func:`default_rig`).

    Returns
    -------
    list of Rig
        In the layout's order; ``projector_rigs("thesis")[0]`` equals `rig`.

    Raises
    ------
    ValueError
        For an unknown layout name, no azimuth, or azimuths that repeat.
    """
    rig = rig or default_rig()
    if isinstance(layout, str):
        if layout not in LAYOUTS:
            raise ValueError(f"layout: expected one of {sorted(LAYOUTS)} or azimuths, "
                             f"got {layout!r}")
        azimuths = LAYOUTS[layout]
    else:
        azimuths = tuple(float(a) for a in layout)
    if not azimuths or not all(np.isfinite(azimuths)):
        raise ValueError(f"layout: expected one or more finite azimuths, got {azimuths}")
    if len(set(azimuths)) != len(azimuths):
        raise ValueError(f"layout: azimuths repeat: {azimuths}")
    return [rig if a == 0 else turned_projector(rig, a) for a in azimuths]


def projector_layout(layout: str, scene: str, captures: list[dict]) -> dict:
    """The content of ``projectors.json`` for a capture of several projectors.

    Parameters
    ----------
    layout : str
        The layout's name (:data:`LAYOUTS`).
    scene : str
        What was captured (``"finger"``, ``"target"``, ``"board"`` …).
    captures : list of dict
        Per projector, in order: ``{"capture": directory name, "azimuth_deg": float,
        "n_frames": int}``.

    Returns
    -------
    dict
        ``{"format": "nail2nail-projectors", "version": 1, "layout", "scene", "captures",
        "n_frames" (all projectors'), "capture_s_at_120_fps", "note"}``
        (``docs/projectors.md``; :func:`nail2nail.io.capture.projector_captures` reads it).
    """
    frames = sum(int(c["n_frames"]) for c in captures)
    return {"format": "nail2nail-projectors", "version": 1, "layout": layout, "scene": scene,
            "captures": captures, "n_frames": frames,
            "capture_s_at_120_fps": round(frames / 120.0, 4),
            "note": "one capture per projector, the projectors shown in turn; scan each with "
                    "its own calibration, then `nail2nail merge` / `unroll` the scan "
                    "directories in this order (or `nail2nail process` this directory)"}


def simulate_projector_captures(out_dir: str | os.PathLike, scene, layout: str, *,
                                rig: Rig | None = None, seed: int = 0,
                                scene_name: str | None = None, **capture_options) -> dict:
    """Render one scene under every projector of a layout: ``OUT/p0``, ``OUT/p1`` … and
    ``OUT/projectors.json`` (what ``nail2nail simulate --projectors`` writes).

    Parameters
    ----------
    out_dir : path-like
        Written as a whole (:func:`nail2nail.io._atomic.atomic_directory`, marker
        ``projectors.json``): a non-empty directory without it is refused.
    scene : Scene
        One scene object, so that every projector lights the same finger or target (a name
        is made into one with `rig` and `seed`).
    layout : str
        A name of :data:`LAYOUTS`.
    rig : Rig, optional
        The one-projector rig whose projector is turned (:func:`projector_rigs`); the default
        rig by default.
    seed : int
        Noise seed; projector ``k``'s capture renders with ``seed + k``.
    scene_name : str, optional
        The scene's name in ``projectors.json`` (default: `scene` when a name, else its
        class's).
    **capture_options
        Passed to :func:`nail2nail.simulation.capture.simulate_capture` (``patterns``,
        ``pattern_set``, ``pattern_names``, ``write_truth``, ``progress`` …).

    Returns
    -------
    dict
        The content of ``projectors.json`` (:func:`projector_layout`).
    """
    from nail2nail.io._atomic import atomic_directory, check_output_directory
    from nail2nail.io._json import write_json
    from nail2nail.simulation.capture import simulate_capture
    from nail2nail.simulation.scenes import make_scene

    rig = rig or default_rig()
    name = scene_name or (scene if isinstance(scene, str) else type(scene).__name__.lower())
    if isinstance(scene, str):
        scene = make_scene(scene, rig=rig, seed=seed)
    rigs = projector_rigs(layout, rig)
    azimuths = list(LAYOUTS[layout]) if isinstance(layout, str) else list(layout)
    check_output_directory(out_dir, marker="projectors.json")
    captures = []
    with atomic_directory(out_dir, marker="projectors.json") as tmp:
        for k, projector_rig in enumerate(rigs):
            # the noise differs between the projectors' captures (seed + k), the scene not
            manifest = simulate_capture(Path(tmp) / f"p{k}", scene, rig=projector_rig,
                                        seed=(seed + k) % 2**32, **capture_options)
            captures.append({"capture": f"p{k}", "azimuth_deg": azimuths[k],
                             "n_frames": manifest["n_frames"]})
        content = projector_layout(str(layout), str(name), captures)
        write_json(Path(tmp) / "projectors.json", content)
    return content


def rolled_coverage(scene, masks_and_params, *, pitch_mm: float = 0.1,
                    body_fraction: float = 0.5) -> dict:
    """What the scans light of the true rolled print, in its ``(u, v)`` plane.

    Parameters
    ----------
    scene : Finger
        The virtual finger (its ``rolled_extent``, ``v_tip``).
    masks_and_params : iterable of ((H, W) bool, (H, W) float, (H, W) float)
        Per ``(camera, projector)`` pair: the pixels with a measurement and the true rolled
        coordinates ``u, v`` (mm) they see (``CameraGeometry.mask`` and ``params["u"]``,
        ``params["v"]``, or a scan's mask with the capture's truth).
    pitch_mm : float
        Cell of the ``(u, v)`` grid, mm: no finer than a pixel's footprint on the skin at the
        most grazing view that counts (0.1 mm for the default rig at full resolution; a
        coarser camera leaves cells between its pixels unlit, which reads as missing width).
    body_fraction : float
        The rows of the print below the tip's cap over which the width is judged, as a fraction
        of the print's length from its lower end (the cap's own coverage is given apart).

    Returns
    -------
    dict
        ``area`` (fraction of the print's cells lit), ``width_median`` and ``width_min``
        (per row of the body, the lit fraction of the row's nail-to-nail width), ``span_mm``
        (median lit width of a body row, mm) and ``extent_mm`` (median nail-to-nail width),
        ``cap_area`` (the fraction lit of the rows above the body).
    """
    extent_u = np.arange(-25.0, 25.0, pitch_mm)
    v_hi = float(scene.v_tip)
    v_lo = v_hi - float(scene.rolled_length_mm)
    extent_v = np.arange(v_lo, v_hi, pitch_mm)
    uu, vv = np.meshgrid(extent_u, extent_v)
    inside = scene.rolled_extent(uu, vv)
    lit = np.zeros(inside.shape, dtype=bool)
    for mask, u, v in masks_and_params:
        m = np.asarray(mask, dtype=bool) & np.isfinite(u) & np.isfinite(v)
        c = np.floor((np.asarray(u)[m] - extent_u[0]) / pitch_mm + 0.5).astype(np.int64)
        r = np.floor((np.asarray(v)[m] - extent_v[0]) / pitch_mm + 0.5).astype(np.int64)
        ok = (c >= 0) & (c < lit.shape[1]) & (r >= 0) & (r < lit.shape[0])
        lit[r[ok], c[ok]] = True
    # a cell between lit pixels is lit: close gaps of one cell left by the pixel sampling
    lit |= (np.roll(lit, 1, 1) & np.roll(lit, -1, 1)) | (np.roll(lit, 1, 0) & np.roll(lit, -1, 0))
    lit &= inside
    body = extent_v < v_lo + body_fraction * (v_hi - v_lo)
    rows = inside[body].sum(axis=1)
    use = rows > 0
    width = lit[body].sum(axis=1)[use] / rows[use]
    cap = ~body[:, None] & inside
    return {
        "area": float(lit.sum() / max(inside.sum(), 1)),
        "width_median": float(np.median(width)) if width.size else 0.0,
        "width_min": float(width.min()) if width.size else 0.0,
        "span_mm": float(np.median(lit[body].sum(axis=1)[use]) * pitch_mm) if width.size else 0.0,
        "extent_mm": float(np.median(rows[use]) * pitch_mm) if width.size else 0.0,
        "cap_area": float((lit & cap).sum() / max(cap.sum(), 1)),
    }
