"""``nail2nail simulate``: render a scene with the virtual scanner into a capture directory."""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

from nail2nail.calibration.boards import BOARD_KINDS
from nail2nail.cli._print_target import board_from_options
from nail2nail.io._json import dumps_json
from nail2nail.io.prints import read_print_image
from nail2nail.simulation.board_poses import simulate_board_captures
from nail2nail.simulation.capture import _configure_rig, read_pattern_dir, simulate_capture
from nail2nail.simulation.conditions import draw_conditions
from nail2nail.simulation.projectors import LAYOUTS, simulate_projector_captures
from nail2nail.simulation.rig import load_rig
from nail2nail.simulation.scenes import SCENES, make_scene

__all__ = ["MAX_SCALE", "PRINT_PPI_RANGE", "SEED_MAX", "add_parser", "run"]

#: ``--print-ppi`` (and a print file's own resolution), pixels per inch: fingerprint scans are
#: 500 or 1000 ppi; below 100 a ridge period (about 0.5 mm) is under 2 px, and the print's
#: contrast normalisation filters with a 1 mm Gaussian, ``ppi / 25.4`` px wide: 1e6 ppi took
#: minutes, 1e9 gigabytes.
PRINT_PPI_RANGE = (100.0, 2000.0)
#: The largest ``--seed`` and ``--conditions`` seed (seeds are integers >= 0; 32 bits, as
#: NumPy's legacy seeding and most tools record them).
SEED_MAX = 2**32 - 1
#: The largest ``--scale``: cameras of 2048 × 2560 px for the default rig, four times the
#: pixels of scale 1; memory and time grow with the square (scale 1000 asked for 9.5 TiB).
MAX_SCALE = 2.0


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
    p.add_argument("--scale", type=float,
                   help=f"camera resolution scale (default 1, at most {MAX_SCALE:g}; at least "
                   "0.0625 for the default rig: cameras of 64 px or more on a side)")
    p.add_argument("--seed", type=int, default=0,
                   help=f"fingerprint and noise seed, 0..{SEED_MAX} (default 0)")
    p.add_argument("--print", dest="print_image", type=Path, metavar="IMAGE",
                   help="finger only: wrap this fingerprint image (8-bit grayscale PNG or WSQ, "
                   "legacy convention: as an inked roll, tip up) around the finger instead of "
                   "a synthetic print; truth/rolled_print.png is this image")
    p.add_argument("--print-ppi", type=float, metavar="PPI",
                   help="resolution of --print (default: the file's, else 500), "
                   f"{PRINT_PPI_RANGE[0]:g} to {PRINT_PPI_RANGE[1]:g}")
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
                       "spacing; circles 0.5 x spacing; not for a checkerboard)")
    board.add_argument("--dictionary", default=None,
                       help="ChArUco ArUco dictionary (default DICT_5X5_100)")
    board.add_argument("--pose", type=float, nargs=6,
                       metavar=("RX", "RY", "RZ", "TX", "TY", "TZ"),
                       help="board pose: rotation vector in degrees from facing the centre "
                       "camera, and the sheet centre in world mm (default 0 0 0 0 3.175 0)")
    board.add_argument("--poses", type=int, metavar="N",
                       help="write N captures of the board at well-spread poses as "
                       "OUT/pose00 ... OUT/poseNN and OUT/board-poses.json")
    p.add_argument("--projectors", choices=list(LAYOUTS), default=None, metavar="LAYOUT",
                   help="a rig of several projectors (nail2nail.simulation.projectors): one "
                   "capture of the scene per projector, shown in turn, written as OUT/p0, "
                   "OUT/p1 … (each a capture directory with its truth) and OUT/projectors.json "
                   "(with --poses: each OUT/poseKK so); "
                   f"layouts: {', '.join(f'{k} {LAYOUTS[k]}' for k in LAYOUTS)} (azimuths "
                   "about the finger's axis, degrees; the thesis rig's projector is at 0)")
    p.add_argument("--no-truth", action="store_true", help="do not write truth/")
    p.add_argument("--json", action="store_true", help="print the manifest summary as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:

    if args.scale is not None and not 0 < args.scale <= MAX_SCALE:
        raise ValueError(f"--scale: expected a positive number of at most {MAX_SCALE:g}, got "
                         f"{args.scale:g}")
    for flag, seed in (("--seed", args.seed), ("--conditions", args.conditions)):
        if seed is not None and not 0 <= seed <= SEED_MAX:
            raise ValueError(f"{flag}: expected a seed in 0..{SEED_MAX}, got {seed}")
    if args.print_image is not None and args.scene != "finger":
        raise ValueError(f"--print: only with --scene finger, got --scene {args.scene}")
    lo, hi = PRINT_PPI_RANGE
    if args.print_ppi is not None:
        if args.print_image is None:
            raise ValueError(f"--print-ppi {args.print_ppi:g}: only with --print (the "
                             "resolution of that image)")
        if not lo <= args.print_ppi <= hi:
            raise ValueError(f"--print-ppi: expected {lo:g} to {hi:g} pixels per inch, got "
                             f"{args.print_ppi:g}")
    board = _board_from_args(args)
    print_image = None
    print_ppi = args.print_ppi
    if args.print_image is not None:

        print_image, file_ppi = read_print_image(args.print_image)
        if print_ppi is None and file_ppi and not lo <= file_ppi <= hi:
            raise ValueError(f"{args.print_image}: its resolution, {file_ppi:g} ppi, is not "
                             f"{lo:g} to {hi:g}; give the right one with --print-ppi")
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
    if args.projectors is not None and len(LAYOUTS[args.projectors]) > 1:
        return _run_projectors(args, scene, rig, patterns, names, pattern_set, print_image,
                               print_ppi, start)
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


def _run_projectors(args, scene, rig, patterns, names, pattern_set, print_image, print_ppi,
                    start) -> int:
    """``--projectors``: one capture per projector of the layout, OUT written as a whole."""
    rig = _configure_rig(rig, scale=args.scale, projector_distortion=args.projector_distortion)
    if isinstance(scene, str):  # one scene object: every projector sees the same finger
        options = {}
        if print_image is not None:
            options = {"print_image": print_image, "print_ppi": print_ppi or 500.0}
        scene = make_scene(scene, rig=rig, seed=args.seed, **options)
    layout = simulate_projector_captures(
        args.out, scene, args.projectors, rig=rig, seed=args.seed, scene_name=args.scene,
        patterns=patterns, pattern_names=names, pattern_set=pattern_set,
        write_truth=not args.no_truth, progress=True)
    captures = layout["captures"]
    frames = layout["n_frames"]
    azimuths = [c["azimuth_deg"] for c in captures]
    elapsed = time.perf_counter() - start
    summary = {"out": str(args.out), **layout, "seconds": round(elapsed, 2)}
    if args.json:
        print(dumps_json(summary))
    else:
        dirs = ", ".join(c["capture"] for c in captures)
        angles = ", ".join(f"{a:g}" for a in azimuths)
        print(f"wrote {args.out}: {len(captures)} captures ({dirs}; projectors at {angles} "
              f"deg), {frames} frames in all, in {elapsed:.1f} s")
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
    if args.pose is not None and not all(math.isfinite(v) for v in args.pose):
        raise ValueError("--pose: expected 6 finite numbers (rx ry rz in degrees, tx ty tz in "
                         f"mm), got {' '.join(f'{v:g}' for v in args.pose)}")
    # the bounds of print-target: a simulated board is one to print
    return board_from_options(args.board or "checkerboard", rows=args.rows, cols=args.cols,
                              spacing=args.spacing, marker=args.marker,
                              dictionary=args.dictionary)


def _run_poses(args, board, rig, patterns, names, start, pattern_set) -> int:

    summary = simulate_board_captures(
        args.out, args.poses, board=board, rig=rig, scale=args.scale,
        projector_distortion=args.projector_distortion, seed=args.seed, patterns=patterns,
        pattern_set=pattern_set, pattern_names=names, write_truth=not args.no_truth,
        progress=True, projectors=None if args.projectors is None
        or len(LAYOUTS[args.projectors]) == 1 else args.projectors)
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
