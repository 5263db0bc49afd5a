"""``nail2nail process``: one capture from frames to the rolled-equivalent print, in one go.

Thin command layer over :func:`nail2nail.process.process_capture` (scan → merge → super scan →
unroll, with per-stage timings); the options are those of ``scan``, ``merge`` and ``unroll``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from nail2nail.cli._options import add_pair_by_option
from nail2nail.cli._report import add_report_options, check_report_options
from nail2nail.cli._scan import (
    add_scan_options,
    as_option_error,
    decode_options,
    masks,
    max_gradient,
)
from nail2nail.cli._unroll import add_unroll_options, check_unroll_options, unroll_options
from nail2nail.io._json import dumps_json
from nail2nail.merge.report import parse_pairs
from nail2nail.process import process_capture
from nail2nail.report import write_report

__all__ = ["add_parser", "add_process_options", "as_option_error", "process_options", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "process",
        help="the whole job for one capture: scans, merge, super scan, rolled print",
        description="Scan every camera of CAPTURE_DIR, merge the scans in projector space, fuse "
        "the super scan and unroll the finger into a rolled-equivalent print, in one process; "
        "write OUT/scans, OUT/merge, OUT/print and OUT/process.json (the summary, with the "
        "seconds of every stage and the peak memory).",
    )
    p.add_argument("capture", type=Path,
                   help="capture directory (capture.json), or a capture of several projectors "
                   "(projectors.json and a capture per projector; docs/projectors.md)")
    p.add_argument("--calib", type=Path, required=True,
                   help="calibration JSON; for a capture of several projectors, DIR/NAME.json "
                   "stands for DIR/NAME_<capture>.json of each (as `nail2nail calibrate` and "
                   "`calibrate-board` write them)")
    p.add_argument("--out", type=Path, required=True, help="output directory")
    add_process_options(p)
    p.add_argument("--report", action="store_true",
                   help="also write OUT/report.html, the HTML report (`nail2nail report`)")
    add_report_options(p)
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=run)


def add_process_options(p: argparse.ArgumentParser) -> None:
    """The processing options of ``process`` (and ``batch``): scan, merge and unroll."""
    add_scan_options(p)
    p.add_argument("--pairs", default=None,
                   help="merge report camera pairs PARENT-CHILD, comma separated "
                   "(default: 0-1,1-2,…)")
    add_pair_by_option(p)
    p.add_argument("--figures", action=argparse.BooleanOptionalAction, default=False,
                   help="write the merge figures (default: off, the data only)")
    p.add_argument("--mat5", action="store_true",
                   help="also write the legacy mat5 sets: each camera's into OUT/scans, the "
                   "super mat5 into OUT/merge")
    p.add_argument("--seamless-mesh", action="store_true",
                   help="mesh OUT/merge/super.ply as one surface, the seams between the "
                   "cameras closed (about 10 s more at full resolution; default: the cameras' "
                   "grids side by side)")
    p.add_argument("--ply", action="store_true",
                   help="also write each camera's PLY point cloud into OUT/scans")
    p.add_argument("--unroll", action=argparse.BooleanOptionalAction, default=True,
                   help="unroll the finger into the rolled-equivalent print (default: on)")
    add_unroll_options(p)
    p.add_argument("--no-wsq", action="store_true", help="skip the compressed print")


def process_options(args: argparse.Namespace) -> dict:
    """The keyword arguments of :func:`nail2nail.process.process_capture` from `args`."""

    check_unroll_options(args)
    options = decode_options(args)
    min_modulation = options.pop("min_modulation")
    if args.pairs is not None:
        try:  # the syntax now; the camera count once the capture is read
            parse_pairs(args.pairs, _ANY_COUNT)
        except ValueError as exc:  # not "among 0..2147483647": the count is not known yet
            raise ValueError(str(exc).split(f" among 0..{_ANY_COUNT - 1}")[0]) from None
    return dict(use=args.use, max_gradient=max_gradient(args), min_modulation=min_modulation,
                decode_options=options, masks=masks(args), allow_mirrored=args.allow_mirrored,
                pairs=args.pairs, pair_by=args.pair_by, figures=args.figures, mat5=args.mat5,
                ply=args.ply,
                seamless_mesh=args.seamless_mesh,
                unroll=args.unroll, method=args.method, ppi=args.ppi,
                tip_direction=args.tip_direction, length_mm=args.length, wsq=not args.no_wsq,
                frame=args.frame, ridge_options=unroll_options(args))


#: A camera count above any rig's, to check the syntax of --pairs before the capture is read.
_ANY_COUNT = 2**31



def run(args: argparse.Namespace) -> int:

    options = process_options(args)  # checks the options before any work
    check_report_options(args)
    try:
        summary = process_capture(args.capture, args.calib, args.out, progress=True,
                                  **options)
    except ValueError as exc:
        error = as_option_error(exc)
        if error is exc:
            raise
        raise error from exc
    if args.report:

        summary["report"] = str(write_report(args.out, max_points=args.report_points,
                                             progress=True))
    if args.json:
        print(dumps_json(summary))
        return 0
    for name, valid in summary["cameras"].items():
        print(f"{name}: {valid} valid pixels")
    for key, m in summary["merge"].items():
        d = m["distance_mm"]
        print(f"merge {key}: {m['pairs']} pairs, median {1e3 * d['median']:.2f} µm, "
              f"p95 {1e3 * d['p95']:.2f} µm")
    s = summary["super_scan"]
    print(f"super scan: {s['vertices']} points, {s['faces']} triangles")
    if "print" in summary:
        p = summary["print"]
        print(f"print: {p['shape'][1]} x {p['shape'][0]} px at {p['ppi']:g} ppi")
    stages = ", ".join(f"{k} {v:.2f} s" for k, v in summary["seconds"].items())
    print(f"seconds: {stages}; peak memory {summary['peak_rss_mb']} MB")
    print(f"wrote {Path(args.out) / 'process.json'}")
    if args.report:
        print(f"wrote {summary['report']}")
    return 0
