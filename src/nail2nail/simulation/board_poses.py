"""Poses of a planar calibration board in front of a rig, for simulated board captures."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, cast

import numpy as np

from nail2nail._progress import progress_bar
from nail2nail.calibration.boards import Board
from nail2nail.calibration.camera_models import Pinhole
from nail2nail.io._atomic import atomic_directory, check_output_directory
from nail2nail.io._json import write_json
from nail2nail.simulation.capture import _configure_rig, simulate, write_capture
from nail2nail.simulation.projectors import LAYOUTS, projector_layout, projector_rigs
from nail2nail.simulation.rig import Rig, default_rig
from nail2nail.simulation.scenes import (
    BoardScene,
    _default_board,
    _rotation_from_vector,
    make_scene,
)

__all__ = ["board_pose_checks", "board_poses", "rig_working_point", "simulate_board_captures"]

_GOLDEN_ANGLE_DEG = 180.0 * (3.0 - np.sqrt(5.0))


def rig_working_point(rig: Rig) -> np.ndarray:
    """World point ``(3,)`` closest (least squares) to the optical axes of the rig's cameras, mm.

    The point the cameras look at: ``(0, 3.175, 0)`` for the default rig.
    """
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for cam in rig.cameras:
        axis = cam.R[2]  # the camera's z axis in the world frame
        proj = np.eye(3) - np.outer(axis, axis)
        a += proj
        b += proj @ cam.center
    return np.linalg.solve(a, b)


def board_pose_checks(scene: BoardScene, rig: Rig, *, max_obliquity_deg: float = 65.0,
                      border: float = 0.03) -> dict:
    """Whether a board pose is usable: every camera and the projector see its whole pattern.

    Parameters
    ----------
    scene : BoardScene
    rig : Rig
    max_obliquity_deg : float
        Largest angle between the board's normal and the direction to a camera or to the
        projector, degrees.
    border : float
        Fraction of the image (panel) size kept clear at its edges.

    Returns
    -------
    dict
        ``{"ok": bool, "obliquity_deg": {camera or "projector": angle}, "inside": {…: bool}}``;
        the pattern is its extent grown by half a spacing (the quiet zone detectors need).
    """
    board = scene.board
    x0, x1, y0, y1 = board.pattern_extent()
    pad = 0.5 * board.spacing
    xs = np.linspace(x0 - pad, x1 + pad, 9)
    ys = np.linspace(y0 - pad, y1 + pad, 9)
    edge = np.concatenate([np.column_stack([xs, np.full(9, y0 - pad)]),
                           np.column_stack([xs, np.full(9, y1 + pad)]),
                           np.column_stack([np.full(9, x0 - pad), ys]),
                           np.column_stack([np.full(9, x1 + pad), ys])])
    world = scene.world_from_board(np.column_stack([edge, np.zeros(len(edge))]))
    centre = scene.world_from_board(board.center[None])[0]
    normal = -scene.R_world_board[:, 2]
    out: dict[str, Any] = {"obliquity_deg": {}, "inside": {}}
    viewers: list[tuple[str, np.ndarray, Pinhole | None]] = [
        (name, cam.center, cam) for name, cam in zip(rig.camera_names, rig.cameras, strict=True)]
    viewers.append(("projector", rig.projector.center, None))
    ok = True
    for name, position, cam in viewers:
        view = position - centre
        cos = float(normal @ view / np.linalg.norm(view))
        angle = float(np.degrees(np.arccos(np.clip(cos, -1, 1))))
        if cam is None:
            xy = rig.panel_from_ideal(rig.projector.project(world))
            width, height = rig.panel_size
        else:
            xy = cam.project(world)
            width, height = cam.size
        inside = bool(np.all(np.isfinite(xy))
                      and np.all((xy[:, 0] >= border * width) & (xy[:, 0] <= (1 - border) * width)
                                 & (xy[:, 1] >= border * height)
                                 & (xy[:, 1] <= (1 - border) * height)))
        out["obliquity_deg"][name] = round(angle, 3)
        out["inside"][name] = inside
        ok &= inside and angle <= max_obliquity_deg
    out["ok"] = bool(ok)
    return out


def board_poses(
    n: int,
    rig: Rig | None = None,
    *,
    board: Board | None = None,
    seed: int = 0,
    tilt_deg: tuple[float, float] = (15.0, 30.0),
    max_obliquity_deg: float = 65.0,
    spin_deg: float = 10.0,
    shift_mm: tuple[float, float, float] = (2.0, 2.0, 3.0),
    projectors: str | None = None,
) -> list[tuple[float, float, float, float, float, float]]:
    """`n` well-spread board poses in front of a rig, each seen whole by every camera.

    Pose ``k`` tilts the board (from facing the centre camera, :class:`BoardScene`) by an angle
    between ``tilt_deg`` (evenly spread over the poses, alternately) about an axis in the
    world ``XY`` plane whose direction turns by the golden angle (137.5°) from pose to pose, so
    the tilts are about both axes and spread in direction; it adds a spin of up to
    ``±spin_deg`` about the board's normal and moves its centre by up to ``shift_mm`` (X, Y,
    Z) about the rig's working point (:func:`rig_working_point`). A pose whose pattern is not
    inside every camera's image and the projector's panel, or is seen more obliquely than
    `max_obliquity_deg` (:func:`board_pose_checks`), is drawn again with the random parts
    redrawn and, after 20 tries, with a tilt 2° smaller.

    Parameters
    ----------
    n : int
        Number of poses (≥ 1).
    rig : Rig, optional
        :func:`~nail2nail.simulation.rig.default_rig` by default.
    board : Board, optional
        The board (its size matters); that of ``make_scene("board")`` by default.
    seed : int
        Random seed of the spins and shifts.
    tilt_deg : (float, float)
        Smallest and largest tilt, degrees.
    max_obliquity_deg, spin_deg, shift_mm
        See above.
    projectors : str, optional
        A layout of several projectors (:data:`nail2nail.simulation.projectors.LAYOUTS`):
        every pose is checked against each projector of it (seen whole, not too obliquely).

    Returns
    -------
    list of (rx, ry, rz, tx, ty, tz)
        Poses as :class:`BoardScene` takes them: rotation vector (degrees) and the sheet
        centre (mm).

    Raises
    ------
    ValueError
        When no usable pose is found for some ``k`` (a board too large for the rig's view).

    Examples
    --------
    >>> poses = board_poses(3)
    >>> len(poses), len(poses[0])
    (3, 6)
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"n: expected a positive number of poses, got {n!r}")
    lo, hi = (float(v) for v in tilt_deg)
    if not 0 <= lo <= hi < 80:
        raise ValueError(f"tilt_deg: expected 0 <= low <= high < 80 degrees, got {tilt_deg!r}")
    rig = rig or default_rig()
    board = board or _default_board()
    rigs = [rig] if projectors is None else projector_rigs(projectors, rig)
    centre = rig_working_point(rig)
    rng = np.random.default_rng(seed)
    poses = []
    for k in range(n):
        fraction = 0.5 if n == 1 else (k * 0.618034) % 1.0
        tilt = lo + (hi - lo) * fraction
        direction = np.radians(45.0 + k * _GOLDEN_ANGLE_DEG)
        found: tuple[float, float, float, float, float, float] | None = None
        for attempt in range(200):
            current = max(tilt - 2.0 * (attempt // 20), 0.0)
            axis = np.array([np.cos(direction), np.sin(direction), 0.0])
            spin = rng.uniform(-spin_deg, spin_deg)
            shift = rng.uniform(-1, 1, 3) * np.asarray(shift_mm, dtype=float)
            # the spin about the board's normal (world Z at rest) composed as a rotation vector:
            # a tilt about an in-plane axis after a spin about Z is close to their sum for
            # the small angles used; the pose is checked as built
            rvec = _compose(current * axis, np.array([0.0, 0.0, spin]))
            rx, ry, rz = (float(v) for v in rvec)
            tx, ty, tz = (float(v) for v in centre + shift)
            pose = (rx, ry, rz, tx, ty, tz)
            scene = BoardScene(board=board, pose=pose)
            if all(board_pose_checks(scene, r, max_obliquity_deg=max_obliquity_deg)["ok"]
                   for r in rigs):
                found = (round(rx, 6), round(ry, 6), round(rz, 6), round(tx, 6), round(ty, 6),
                         round(tz, 6))
                break
        if found is None:
            who = "the projector" if projectors is None else "every projector"
            raise ValueError(f"board: no pose {k} found in which every camera and {who} "
                             f"see the whole {board.size_mm[0]:g} x {board.size_mm[1]:g} mm "
                             "board; use a smaller board")
        poses.append(found)
    return poses


def _compose(first_deg, then_deg) -> np.ndarray:
    """Rotation vector (degrees) of ``R(first) · R(then)`` (``then`` applied first)."""

    r = _rotation_from_vector(first_deg) @ _rotation_from_vector(then_deg)
    angle = np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))
    if angle < 1e-12:
        return np.zeros(3)
    axis = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    return np.degrees(angle) * axis / (2 * np.sin(angle))


def simulate_board_captures(
    out_dir: str | os.PathLike,
    n: int,
    *,
    board: Board | None = None,
    rig: Rig | None = None,
    scale: float | None = None,
    projector_distortion: str | None = None,
    seed: int = 0,
    patterns=None,
    pattern_set=None,
    pattern_names: list[str] | None = None,
    write_truth: bool = True,
    poses: list | None = None,
    progress: bool = False,
    projectors: str | None = None,
) -> dict:
    """Simulate `n` captures of a board at :func:`board_poses` into ``OUT/pose00`` … .

    Each ``poseKK`` is a normal capture directory (``docs/capture-format.md``: frames of the
    pattern set, ``capture.json`` with the rig and, in ``scene``, the board and its pose
    ``R_world_board``, ``t_world_board``; ``truth/`` with the ideal calibration and per
    camera the board coordinates ``param_x``, ``param_y`` of every pixel).
    ``OUT/board-poses.json`` lists them (board, rig, poses; not named ``pose…`` so that
    ``OUT/pose*`` lists the captures only). `OUT` is written as a whole
    (:func:`nail2nail.io._atomic.atomic_directory`, marker ``board-poses.json``). Pose ``k``
    renders with noise seed ``seed + k``. With `projectors`, each ``poseKK`` is a capture of
    several projectors instead: ``projectors.json`` and one capture per projector, ``p0``,
    ``p1`` … (projector ``j`` rendered with noise seed ``seed + k + 1000 j``), as ``nail2nail
    simulate --projectors`` writes a finger's.

    Parameters
    ----------
    out_dir : path-like
    n : int
        Number of poses (ignored when `poses` is given).
    board : Board, optional
        That of ``make_scene("board")`` by default.
    rig, scale, projector_distortion, patterns, pattern_set, pattern_names, write_truth
        As :func:`nail2nail.simulation.capture.simulate_capture`.
    seed : int
        Seed of the poses (:func:`board_poses`) and of the noise.
    poses : list of (6,) float, optional
        Explicit poses instead of :func:`board_poses`.
    progress : bool
        Show a progress bar of the poses on stderr (a terminal only: :mod:`nail2nail._progress`).
    projectors : str, optional
        A layout of several projectors (:data:`nail2nail.simulation.projectors.LAYOUTS`).

    Returns
    -------
    dict
        The content of ``board-poses.json``.
    """

    check_output_directory(out_dir, marker="board-poses.json")
    rig = _configure_rig(rig, scale=scale, projector_distortion=projector_distortion)
    board = board or _default_board()
    if projectors is not None and projectors not in LAYOUTS:
        raise ValueError(f"projectors: expected one of {', '.join(LAYOUTS)}, got {projectors!r}")
    rigs = [rig] if projectors is None else projector_rigs(projectors, rig)
    if poses is None:
        poses = board_poses(n, rig, board=board, seed=seed, projectors=projectors)
    entries = []
    with atomic_directory(out_dir, marker="board-poses.json") as tmp:
        for k, pose in enumerate(progress_bar(poses, desc="simulate", unit="pose",
                                              enabled=progress)):
            scene = cast(BoardScene, make_scene("board", rig=rig, board=board, pose=tuple(pose)))
            name = f"pose{k:02d}"
            captures = []
            for j, projector_rig in enumerate(rigs):
                where = Path(tmp) / name if projectors is None else Path(tmp) / name / f"p{j}"
                sim = simulate(scene, rig=projector_rig, patterns=patterns,
                               pattern_set=pattern_set, seed=seed + k + 1000 * j)
                manifest = write_capture(where, sim, seed=seed + k + 1000 * j,
                                         pattern_names=pattern_names, write_truth=write_truth)
                captures.append({"capture": f"p{j}", "azimuth_deg": LAYOUTS[projectors][j]
                                 if projectors else 0.0, "n_frames": manifest["n_frames"]})
            if projectors is not None:
                write_json(Path(tmp) / name / "projectors.json",
                           projector_layout(projectors, "board", captures))
            checks = board_pose_checks(scene, rig)
            entries.append({"capture": name, "pose": list(scene.pose),
                            "R_world_board": scene.R_world_board.tolist(),
                            "t_world_board": scene.t_world_board.tolist(),
                            "obliquity_deg": checks["obliquity_deg"]})
        summary = {"format": "nail2nail-board-poses", "version": 1,
                   "created_by": "nail2nail simulate", "board": board.to_dict(),
                   "rig": rig.to_dict(), "seed": seed, "poses": entries,
                   **({"projectors": projectors} if projectors is not None else {})}
        write_json(Path(tmp) / "board-poses.json", summary)
    return summary
