"""``nail2nail calibrate-board POSE_DIR...``: cameras and projector from a flat board in poses."""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

import numpy as np

from nail2nail._progress import Stages
from nail2nail.calibration.board import (
    DISTORTION_TERMS,
    MIN_VIEWS,
    PROJECTOR_MODELS,
    calibrate_board,
    distortion_terms,
)
from nail2nail.calibration.boards import BOARD_KINDS, Board
from nail2nail.calibration.files import check_handedness, save_calibration
from nail2nail.calibration.observe import board_views, check_poses
from nail2nail.cli._options import as_option_error
from nail2nail.io._atomic import atomic_files, check_output_file
from nail2nail.io._json import dumps_json

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:

    p = sub.add_parser(
        "calibrate-board",
        help="calibrate cameras and projector from captures of a flat board in several poses",
        description="Calibrate every camera and the projector from captures of a flat board in "
        "several poses (each a capture directory with the phase patterns): Zhang's method per "
        "camera, the projector's board points by local homographies on the decoded projector "
        "coordinates (Moreno & Taubin 2012), then a joint bundle adjustment. Writes a "
        "calibration of pinhole models (one projector for every camera) and prints the RMS "
        "reprojection errors per camera, of the projector and per pose. A pose where a camera "
        "does not find the board is skipped for that camera with a warning. A rig of several "
        "projectors: each POSE_DIR holds projectors.json and a capture per projector (as "
        "`nail2nail simulate --scene board --poses N --projectors LAYOUT` writes them); every "
        "projector is fitted with the cameras in the one bundle and -o OUT.json becomes "
        "OUT_<capture>.json per projector (the same cameras).",
    )
    p.add_argument("poses", type=Path, nargs="+", metavar="POSE_DIR",
                   help=f"capture directory of one board pose (at least {MIN_VIEWS}, each "
                   "given once), or a directory with projectors.json and a capture per projector")
    p.add_argument("--board", required=True, choices=BOARD_KINDS, help="board kind")
    p.add_argument("--rows", required=True, type=int,
                   help="squares (checkerboard, ChArUco) or circles along the board's y")
    p.add_argument("--cols", required=True, type=int,
                   help="squares or circles along the board's x (asymmetric: circles a row)")
    p.add_argument("--spacing", required=True, type=float,
                   help="square side or circle spacing, mm")
    p.add_argument("--marker", type=float,
                   help="ChArUco marker side or circle diameter, mm (default: the board's)")
    p.add_argument("--projector-model", choices=PROJECTOR_MODELS, default="opencv",
                   help="projector lens: OpenCV distortion (k1, k2, p1, p2, k3) or the thesis's "
                   "radial model (eq. 3.34, written as projector_distortion); default opencv")
    p.add_argument("--camera-distortion", default="radial", metavar="SPEC",
                   help="camera distortion terms fitted: radial (k1, k2; default), none, full "
                   "(all five), or OpenCV's terms by name, e.g. k1 or k1,k2,k3 or k1,k2,p1,p2 "
                   "(the others fixed at 0)")
    p.add_argument("--projector-lens", default="full", metavar="SPEC",
                   help="the projector's OpenCV distortion terms with --projector-model opencv, "
                   "as --camera-distortion (default full; k1 or k1,k2 for a radial model of one "
                   "or two terms)")
    p.add_argument("--fix-aspect-ratio", action="store_true",
                   help="fx = fy for every camera and the projector (OpenCV's "
                   "CALIB_FIX_ASPECT_RATIO)")
    p.add_argument("--fix-principal-point", action="store_true",
                   help="principal points at the image centres ((W-1)/2, (H-1)/2; OpenCV's "
                   "CALIB_FIX_PRINCIPAL_POINT)")
    p.add_argument("--world", default=None,
                   help="world frame: a camera's name (default: the first camera) or 'board' "
                   "(the board in the first pose)")
    p.add_argument("--window", type=float, default=None, metavar="PX",
                   help="half-size of the local homography window, camera px (default: the "
                   "board's spacing in the image)")
    p.add_argument("-o", "--output", type=Path, required=True, help="calibration JSON to write")
    p.add_argument("--allow-mirrored", action="store_true",
                   help="accept a mirrored camera or projector (refused by default)")
    p.add_argument("--json", action="store_true", help="print machine-readable results")
    p.set_defaults(func=run)


#: The board's argument names in its messages, and the command line's options.
BOARD_OPTIONS = {"rows, cols": "--rows, --cols", "marker": "--marker", "spacing": "--spacing",
                 "dictionary": "--board charuco (its ArUco dictionary)"}


def _check_options(args: argparse.Namespace) -> Board:
    """The options checked before any capture is read (bad input first, no warning before)."""
    for option, value in (("--spacing", args.spacing), ("--marker", args.marker)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise ValueError(f"{option}: expected a positive length in mm, got {value}")
    if args.window is not None and not (math.isfinite(args.window) and args.window > 0):
        raise ValueError(f"--window: expected a positive number of pixels, got {args.window}")
    for option, spec in (("--camera-distortion", args.camera_distortion),
                         ("--projector-lens", args.projector_lens)):
        try:
            distortion_terms(spec)
        except ValueError as exc:
            raise ValueError(f"{option}: {str(exc).removeprefix('distortion: ')}") from exc
    try:
        check_output_file(args.output)
    except ValueError as exc:
        raise type(exc)(f"-o/--output: {exc}") from exc
    try:
        return Board(args.board, rows=args.rows, cols=args.cols, spacing=args.spacing,
                     marker=args.marker)
    except ValueError as exc:  # the board's own checks name its arguments
        raise as_option_error(exc, BOARD_OPTIONS) from None


def _check_poses(poses: list[Path], world: str | None) -> None:
    """The pose directories checked from their manifests and first frames (cheap) before any
    is decoded, so that a bad input is refused before the warnings of the poses: each given
    once, a capture with a pattern set coding both directions, one projector panel and one
    image size per camera, at least :data:`MIN_VIEWS`, and `world` one of their cameras (or
    'board')."""
    seen: dict[str, Path] = {}
    for pose in poses:
        key = os.path.realpath(pose)
        if key in seen:
            same = "" if str(seen[key]) == str(pose) else f" (as {seen[key]} and {pose})"
            raise ValueError(f"POSE_DIR: {pose} given more than once{same}; each pose is "
                             "one capture directory")
        seen[key] = pose
    sizes, _ = check_poses(poses)
    names = list(sizes)
    if len(poses) < MIN_VIEWS:
        raise ValueError(f"POSE_DIR: {len(poses)} pose(s) given; need at least {MIN_VIEWS} "
                         "(Zhang's method per camera)")
    if world is not None and world != "board" and world not in names:
        raise ValueError(f"--world: expected 'board' or a camera name ({', '.join(names)}), "
                         f"got {world!r}")


def run(args: argparse.Namespace) -> int:
    board = _check_options(args)
    _check_poses(args.poses, args.world)
    captures = board_views(args.poses, board, window_px=args.window, progress=True)
    Stages(prefix="calibrate-board: ")(  # stderr, a terminal only, not with --quiet
        f"fit the cameras and the projector ({len(captures.views)} views)")
    result = calibrate_board(
        captures.views, board.object_points(), captures.camera_sizes,
        projector_size=captures.projector_size, projector_model=args.projector_model,
        world=args.world, camera_distortion=args.camera_distortion,
        projector_lens=args.projector_lens, fix_aspect_ratio=args.fix_aspect_ratio,
        fix_principal_point=args.fix_principal_point)
    extra = {"board": board.to_dict(), "poses": [str(p) for p in captures.poses]}
    several = len(result.projector_names) > 1
    output = Path(args.output)
    # one file per projector of a rig of several (OUT_<capture>.json, the same cameras)
    outputs = ({name: output.with_name(f"{output.stem}_{name}{output.suffix or '.json'}")
                for name in result.projector_names} if several
               else {result.projector_names[0]: output})
    calibs = result.rig_calibrations(extra=extra)
    if not args.allow_mirrored:
        centre = np.mean([T[:3, 3] for T in result.board_poses.values()], axis=0)
        for name, calib in calibs.items():
            check_handedness(calib, str(outputs[name]), scene_point=centre)
    try:
        with atomic_files(output.parent, [f.name for f in outputs.values()]) as tmp:
            for name, calib in calibs.items():
                save_calibration(tmp / outputs[name].name, calib)
    except OSError as exc:  # named by the user's path, not the temporary file beside it
        raise ValueError(f"-o/--output: {args.output}: cannot write "
                         f"({exc.strerror or exc})") from exc
    summary = result.summary()
    poses = {str(captures.poses[int(k)]): v for k, v in summary.pop("poses").items()}
    used = [[c, str(captures.poses[k])] for c, k in result.views_used]
    refused = [[r["camera"], r["pose"], r["reason"]] for r in captures.refused]
    refused += [[c, str(captures.poses[k]), "too few board features"]
                for c, k in result.views_refused]
    if args.json:
        summary.pop("views_used")
        summary.pop("views_refused")
        files = ({"outputs": {k: str(v) for k, v in outputs.items()}} if several
                 else {"output": str(args.output)})
        print(dumps_json({**files, **summary, "poses": poses,
                          "views_used": used, "views_refused": refused}, indent=2))
        return 0
    for name, rms in result.camera_rms_px.items():
        n = sum(1 for c, _ in result.views_used if c == name)
        print(f"{name}: {n} poses, RMS {rms:.4f} px, projector points through it RMS "
              f"{result.projector_rms_by_camera_px[name]:.4f} px")
    for name in result.projector_names:
        label = "projector" if not several else f"projector {name}"
        rms = result.projector_rms_by_projector_px.get(name, result.projector_rms_px)
        print(f"{label} ({args.projector_model}): RMS {rms:.4f} px")
        d = result.projector_distortions.get(name)
        if d:
            print(f"{label} distortion: centre {np.round(d.center, 2).tolist()} px, "
                  f"rho {d.rho:.6f}")
    for pose, r in poses.items():
        cams = ", ".join(f"{c} {v:.4f}" for c, v in r["camera"].items())
        print(f"pose {pose}: cameras {cams} px; projector {r['projector']:.4f} px")
    for cam, pose, why in refused:
        print(f"refused: {cam} in {pose} ({why})")
    for device in [*result.camera_names, *result.projector_names]:
        stds = {k.split(".", 1)[1]: v for k, v in result.parameter_std.items()
                if k.split(".", 1)[0] == device and k.split(".", 1)[1] in
                ("f", "fx", "fy", "cx", "cy", *DISTORTION_TERMS, "rho")}
        print(f"{device}: standard deviations " + ", ".join(f"{k} {v:.3g}"
                                                            for k, v in stds.items()))
    needed = result.poses_needed()
    if needed > result.n_poses:
        print(f"{result.n_poses} poses leave a focal length above 0.1 % or a principal point "
              f"above 1 px (one standard deviation): about {needed} poses would meet both")
    if result.points_dropped:
        print(f"{result.points_dropped} outlying point(s) dropped before the final fit")
    shared = " (the cameras shared)" if several else ""
    print(f"wrote {', '.join(str(f) for f in outputs.values())}{shared} (world frame: "
          f"{result.world})")
    return 0
