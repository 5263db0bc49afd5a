"""``nail2nail demo``: the whole pipeline as far as it exists, on the bundled/virtual data."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from nail2nail.calibration.dlt import calibrate_points, crosscheck
from nail2nail.cli._calibrate import format_table
from nail2nail.cli._report import add_report_options, check_report_options
from nail2nail.io._json import dumps_json
from nail2nail.io.points import thesis_table
from nail2nail.pipeline import format_summary, run_demo
from nail2nail.report import write_report

__all__ = ["add_parser", "run", "thesis_part"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "demo",
        help="run the whole pipeline on the virtual scanner and print a summary",
        description="Run the pipeline end to end: thesis calibration tables, then (virtual "
        "scanner) simulate, distortion, calibrate, scan, merge.",
    )
    p.add_argument("--out", type=Path, default=Path("demo-output"), help="output directory")
    p.add_argument("--scale", type=float, default=1.0, help="camera resolution scale")
    p.add_argument("--json", action="store_true", help="print a machine-readable summary")
    p.add_argument("--report", action=argparse.BooleanOptionalAction, default=True,
                   help="write OUT/report.html, the HTML report of the finger (default: on)")
    add_report_options(p)
    p.set_defaults(func=run)


def thesis_part(quiet: bool) -> dict:
    """Calibrate the thesis's two tables and cross-check their common points."""
    tables = [thesis_table(0), thesis_table(1)]
    summary: dict = {}
    for use in ("yp", "xpyp"):
        reports = [calibrate_points(t.xyz_world, t.xy_camera, t.xy_projector, use=use)
                   for t in tables]
        cc = crosscheck(reports[0], tables[0].xyz_world, reports[1], tables[1].xyz_world)
        summary[use] = {
            "rms_mm": [r.rms_mm.round(4).tolist() for r in reports],
            "pairs": int(cc.distance_mm.size),
            "distance_mm_median": float(np.median(cc.distance_mm)),
            "squared_mm2_max": float(cc.squared_mm2.max()),
        }
        if not quiet and use == "yp":
            print("== Thesis Table 2 (camera 0), DLT calibration, reconstruction from yp ==")
            print(format_table(reports[0], tables[0]))
        if not quiet:
            print(f"Cross-check camera 0 vs 1 ({use}): {cc.distance_mm.size} common points, "
                  f"median {np.median(cc.distance_mm):.4f} mm, "
                  f"max squared {cc.squared_mm2.max():.4f} mm²")
    return summary


def run(args: argparse.Namespace) -> int:

    if not args.scale > 0:
        raise ValueError(f"--scale: expected a positive number, got {args.scale}")
    check_report_options(args)
    thesis = thesis_part(args.json)
    if not args.json:
        print(f"\n== Virtual scanner: the whole pipeline (scale {args.scale}) -> {args.out} ==")
    result = run_demo(args.out, scale=args.scale, progress=True)
    result["thesis"] = thesis
    if args.report:

        result["report"] = str(write_report(args.out, max_points=args.report_points,
                                            progress=True))
    if args.json:
        print(dumps_json(result, default=float))
    else:
        print(format_summary(result))
        if args.report:
            print(f"report: {result['report']}")
    return 0
