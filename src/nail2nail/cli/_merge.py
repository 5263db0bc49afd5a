"""``nail2nail merge``: merge error between cameras in projector space, and the super scan.

Thin command layer: :func:`run` reads a scan directory, or one per projector of a rig of
several (:func:`nail2nail.io.scans.load_scan_dirs`), calls
:func:`nail2nail.merge.report.write_merge` and prints the summary.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from nail2nail._validation import as_int
from nail2nail.cli._options import add_pair_by_option
from nail2nail.io._json import dumps_json
from nail2nail.io.scans import load_scan_dirs, read_scan_frame
from nail2nail.merge.report import parse_pairs, write_merge

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "merge",
        help="merge error between cameras in projector space, and the fused super scan",
        description="For every valid pixel (or every K-th) of the parent camera of each pair, "
        "find the child pixel with the nearest projector coordinates (bucket grid, sub-pixel), "
        "report the world distance of the pairs (thesis chapter four) with figures, and fuse "
        "all cameras into one nail-to-nail point cloud and mesh (super.ply, super mat5).",
    )
    p.add_argument("scan_dir", type=Path, nargs="+",
                   help="scan directory written by `nail2nail scan`; with a rig of several "
                   "projectors, one per projector, in projector order (the scans are then "
                   "numbered directory by directory, named CAMERA-pK)")
    p.add_argument("--pairs", default=None,
                   help="camera pairs PARENT-CHILD, comma separated (default: 0-1,1-2,…; with "
                   "several projectors, the neighbouring cameras of each projector and the "
                   "neighbouring projectors of each camera)")
    p.add_argument("--stride", type=int, default=1,
                   help="sample every K-th parent row and column (the thesis used 5 and 20)")
    p.add_argument("--max-residual", type=float, default=0.5,
                   help="largest projector residual of a pair, panel px (decoding noise)")
    p.add_argument("--border", type=int, default=2,
                   help="erosion of each camera's valid region, px")
    add_pair_by_option(p)
    p.add_argument("--no-super", action="store_true", help="skip the super scan")
    p.add_argument("--seamless-mesh", action="store_true",
                   help="mesh super.ply as one surface, the seams between the cameras closed "
                   "(about 10 s more at full resolution; default: the cameras' grids side by "
                   "side)")
    p.add_argument("--figures", action=argparse.BooleanOptionalAction, default=True,
                   help="write the PNG figures (heat maps, histograms, marked pixels, renders "
                   "of the super scan; --no-figures: none)")
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument("--json", action="store_true", help="print a machine-readable summary")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # every option checked before anything is read or written
    as_int(args.stride, "--stride", minimum=1)
    if not args.max_residual > 0:
        raise ValueError(f"--max-residual: expected a positive number, got {args.max_residual}")
    as_int(args.border, "--border", minimum=0)
    # scans written in a camera's frame (scan --frame) come back in the world frame, where the
    # merge computes; the super scan is written in the scans' frame
    dirs = list(args.scan_dir)
    frame, transform = read_scan_frame(dirs[0])
    for d in dirs[1:]:
        other, T = read_scan_frame(d)
        if other != frame or not np.allclose(T, transform, atol=1e-9):
            raise ValueError(f"{d}: its points are in the frame {other!r}, those of {dirs[0]} "
                             f"in {frame!r} (scan every projector's capture in one frame)")
    scans, projectors, cameras = load_scan_dirs(dirs)
    if len(scans) < 2:
        raise ValueError(f"{dirs[0]}: need at least two cameras to merge, got {len(scans)}")
    pairs = None if args.pairs is None else parse_pairs(args.pairs, len(scans))
    summary = write_merge(
        scans, args.out, pairs=pairs, stride=args.stride, max_residual_px=args.max_residual,
        border_px=args.border, figures=args.figures, super_scan=not args.no_super,
        progress=True, frame=frame, transform=transform, seamless_mesh=args.seamless_mesh,
        projectors=projectors, cameras=cameras, pair_by=args.pair_by,
    )
    summary = {"scan_dir": str(dirs[0]) if len(dirs) == 1 else [str(d) for d in dirs],
               **summary}
    if args.json:
        print(dumps_json(summary))
        return 0
    print(f"{'pair':>6} {'pairs':>8} {'median µm':>10} {'p95 µm':>8} {'max µm':>8} "
          f"{'<0.05mm':>8}  dropped (parent border / child border / residual)")
    for key, m in summary["merge"].items():
        d, dr = m["distance_mm"], m["dropped"]
        print(f"{key:>6} {m['pairs']:>8} {1e3 * d['median']:10.2f} {1e3 * d['p95']:8.2f} "
              f"{1e3 * d['max']:8.2f} {100 * d['frac_below_0_05']:7.1f}%  "
              f"{dr['parent_border']} / {dr['child_border']} / {dr['residual']}")
    if summary["super_scan"]:
        s = summary["super_scan"]
        print(f"super scan: {s['vertices']} points, {s['faces']} triangles -> "
              f"{s['files']['ply']}, {s['files']['mat5']}*")
    print(f"wrote {Path(args.out) / 'merge.json'}")
    return 0
