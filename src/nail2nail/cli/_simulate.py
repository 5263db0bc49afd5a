"""``nail2nail simulate``: render a scene with the virtual scanner into a capture directory."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from nail2nail.calibration.boards import BOARD_KINDS, Board, default_board
from nail2nail.io._json import dumps_json
from nail2nail.io.prints import read_print_image
from nail2nail.simulation.board_poses import simulate_board_captures
from nail2nail.simulation.capture import _configure_rig, read_pattern_dir, simulate_capture
from nail2nail.simulation.conditions import draw_conditions
from nail2nail.simulation.rig import load_rig
from nail2nail.simulation.scenes import SCENES, make_scene

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "simulate",
        help="render a capture with the virtual scanner (three cameras, one projector)",
        description="Render what each camera of the virtual scanner sees of a scene under a "
        "sequence of projector images and write a capture directory (capture.json, "
        "cam0/000.png ..., truth/). Format: docs/capture-format.md.",
    )
    p.add_argument("--scene", choices=SCENES, default="finger", help="object (default: finger)")
    p.add_argument("--out", type=Path, required=True, help="capture directory to write")
    p.add_argument("--rig", type=Path, help="rig JSON (default: the thesis-like default rig)")
    p.add_argument("--patterns", type=Path,
                   help="directory of panel PNGs to project: one written by `nail2nail "
                   "patterns` (its frames and pattern set, any scheme, recorded in capture.json "
                   "so that scan decodes it), or any PNGs, sorted by name, recorded without a "
                   "pattern set (default: the default pattern set of nail2nail.scan.patterns)")
    p.add_argument("--projector-distortion", choices=["thesis", "none"],
                   help="projector radial distortion (default: the rig's; thesis for the "
                   "default rig)")
    p.add_argument("--scale", type=float, help="camera resolution scale (default 1)")
    p.add_argument("--seed", type=int, default=0, help="fingerprint and noise seed (default 0)")
    p.add_argument("--print", dest="print_image", type=Path, metavar="IMAGE",
                   help="finger only: wrap this fingerprint image (8-bit grayscale PNG or WSQ, "
                   "legacy convention: as an inked roll, tip up) around the finger instead of "
                   "a synthetic print; truth/rolled_print.png is this image")
    p.add_argument("--print-ppi", type=float, metavar="PPI",
                   help="resolution of --print (default: the file's, else 500)")
    p.add_argument("--conditions", type=int, metavar="SEED",
                   help="finger only: draw the scanner's optics and the finger's shape, pose, "
                   "skin and print class at random from the stated ranges "
                   "(nail2nail.simulation.conditions.RANGES), reproducibly from SEED; the "
                   "values drawn are recorded in capture.json (rig.photometry, scene)")
    board = p.add_argument_group(
        "board scene", "a printed planar calibration board (--scene board; docs/real-scanner.md)")
    board.add_argument("--board", choices=BOARD_KINDS, default=None,
                       help="board kind (default checkerboard)")
    board.add_argument("--rows", type=int, metavar="R",
                       help="squares (checkerboard, charuco) or circles along the board's y "
                       "(default 11)")
    board.add_argument("--cols", type=int, metavar="C",
                       help="squares or circles along x; asymmetric-circles: circles in a row "
                       "(default 8, 4 for asymmetric-circles)")
    board.add_argument("--spacing", type=float, metavar="MM",
                       help="square side or circle spacing, mm (default 2.5)")
    board.add_argument("--marker", type=float, metavar="MM",
                       help="ChArUco marker side or circle diameter, mm (default 0.7 x "
                       "spacing; circles 0.5 x spacing)")
    board.add_argument("--dictionary", default=None,
                       help="ChArUco ArUco dictionary (default DICT_5X5_100)")
    board.add_argument("--pose", type=float, nargs=6,
                       metavar=("RX", "RY", "RZ", "TX", "TY", "TZ"),
                       help="board pose: rotation vector in degrees from facing the centre "
                       "camera, and the sheet centre in world mm (default 0 0 0 0 3.175 0)")
    board.add_argument("--poses", type=int, metavar="N",
                       help="write N captures of the board at well-spread poses as "
                       "OUT/pose00 ... OUT/poseNN and OUT/board-poses.json")
    p.add_argument("--no-truth", action="store_true", help="do not write truth/")
    p.add_argument("--json", action="store_true", help="print the manifest summary as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:

    if args.scale is not None and not args.scale > 0:
        raise ValueError(f"--scale: expected a positive number, got {args.scale}")
    if args.print_image is not None and args.scene != "finger":
        raise ValueError(f"--print: only with --scene finger, got --scene {args.scene}")
    if args.print_ppi is not None and not args.print_ppi > 0:
        raise ValueError(f"--print-ppi: expected a positive number, got {args.print_ppi}")
    board = _board_from_args(args)
    print_image = None
    print_ppi = args.print_ppi
    if args.print_image is not None:

        print_image, file_ppi = read_print_image(args.print_image)
        print_ppi = print_ppi or file_ppi or 500.0
    rig = load_rig(args.rig) if args.rig else None
    conditions = None
    if args.conditions is not None:
        if args.scene != "finger":
            raise ValueError(f"--conditions: only with --scene finger, got --scene {args.scene}")
        conditions = _conditions_rig(args, rig)
        rig, args.scale = conditions[1], None  # the scale is applied
    patterns = names = pattern_set = None
    if args.patterns:  # a `nail2nail patterns` directory carries its pattern set (any scheme)
        patterns, names, pattern_set = read_pattern_dir(args.patterns)
    start = time.perf_counter()
    if args.poses is not None:
        return _run_poses(args, board, rig, patterns, names, start, pattern_set)
    scene = args.scene
    if conditions is not None:

        scene = make_scene("finger", rig=rig, seed=args.seed, **conditions[0].finger_options(
            print_image=print_image, print_ppi=print_ppi or 500.0))
        print_image = None  # wrapped by the scene already
    if board is not None:

        rig = _configure_rig(rig, scale=args.scale,
                             projector_distortion=args.projector_distortion)
        args.scale = args.projector_distortion = None  # applied
        options = {"board": board}
        if args.pose is not None:
            options["pose"] = tuple(args.pose)
        scene = make_scene("board", rig=rig, **options)
    manifest = simulate_capture(
        args.out, scene, rig=rig, scale=args.scale,
        projector_distortion=args.projector_distortion, patterns=patterns, pattern_names=names,
        pattern_set=pattern_set, seed=args.seed, write_truth=not args.no_truth,
        progress=True,
        print_image=print_image, print_ppi=print_ppi or 500.0,
    )
    elapsed = time.perf_counter() - start
    summary = {
        "out": str(args.out),
        "scene": args.scene,
        "n_frames": manifest["n_frames"],
        "cameras": [{"name": c["name"], "size": c["size"]} for c in manifest["cameras"]],
        "truth": manifest.get("truth"),
        "print": None if args.print_image is None else {"image": str(args.print_image),
                                                        "ppi": print_ppi},
        "conditions": None if conditions is None else conditions[0].to_dict(),
        "seconds": round(elapsed, 2),
    }
    if args.json:
        print(dumps_json(summary))
    else:
        cams = ", ".join(f"{c['name']} {c['size'][0]}x{c['size'][1]}" for c in summary["cameras"])
        print(f"wrote {args.out}: scene {args.scene}, {summary['n_frames']} frames x "
              f"{len(summary['cameras'])} cameras ({cams}) in {elapsed:.1f} s")
    return 0


def _conditions_rig(args, rig):
    """``(Conditions, Rig)``: the conditions drawn from ``--conditions`` and the rig with their
    optics (the given ``--rig``'s geometry, else the default rig's), at ``--scale``."""

    drawn = draw_conditions(args.conditions)
    if rig is None:
        rig = drawn.rig(args.scale or 1.0)
        scale = None
    else:
        rig = drawn.on_rig(rig)
        scale = args.scale
    return drawn, _configure_rig(rig, scale=scale, projector_distortion=args.projector_distortion)


def _board_from_args(args):
    """The Board of ``--scene board`` (None for other scenes); options checked first."""

    given = [f"--{k}" for k in ("board", "rows", "cols", "spacing", "marker", "dictionary",
                                "pose", "poses") if getattr(args, k) is not None]
    if args.scene != "board":
        if given:
            raise ValueError(f"{given[0]}: only with --scene board, got --scene {args.scene}")
        return None
    if args.pose is not None and args.poses is not None:
        raise ValueError("--pose: not with --poses (which draws the poses)")
    if args.poses is not None and not 1 <= args.poses <= 99:
        raise ValueError(f"--poses: expected a number of poses in 1..99, got {args.poses}")
    base = default_board(args.board or "checkerboard")
    options = {"kind": base.kind, "rows": base.rows if args.rows is None else args.rows,
               "cols": base.cols if args.cols is None else args.cols,
               "spacing": base.spacing if args.spacing is None else args.spacing}
    if args.marker is not None:
        options["marker"] = args.marker
    if args.dictionary is not None:
        options["dictionary"] = args.dictionary
    try:
        return Board(**options)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"--board {base.kind} --rows {options['rows']} --cols "
                         f"{options['cols']} --spacing {options['spacing']:g}: {exc}") from None


def _run_poses(args, board, rig, patterns, names, start, pattern_set) -> int:

    summary = simulate_board_captures(
        args.out, args.poses, board=board, rig=rig, scale=args.scale,
        projector_distortion=args.projector_distortion, seed=args.seed, patterns=patterns,
        pattern_set=pattern_set, pattern_names=names, write_truth=not args.no_truth,
        progress=True)
    elapsed = time.perf_counter() - start
    if args.json:
        print(dumps_json({"out": str(args.out), "scene": "board", "board": summary["board"],
                          "poses": [{"capture": p["capture"], "pose": p["pose"]}
                                    for p in summary["poses"]],
                          "seconds": round(elapsed, 2)}))
    else:
        b = summary["board"]
        print(f"wrote {args.out}: {len(summary['poses'])} captures of a {b['kind']} board "
              f"({b['rows']} x {b['cols']}, {b['spacing']:g} mm) at pose00 ... "
              f"pose{len(summary['poses']) - 1:02d}, board-poses.json in {elapsed:.1f} s")
    return 0
