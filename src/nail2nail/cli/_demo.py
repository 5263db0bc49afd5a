"""``nail2nail demo``: the whole pipeline as far as it exists, on the bundled/virtual data."""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from nail2nail.calibration.dlt import calibrate_points, crosscheck
from nail2nail.cli._calibrate import format_table
from nail2nail.cli._report import add_report_options, check_report_options
from nail2nail.cli._simulate import MAX_SCALE
from nail2nail.io._atomic import check_output_directory
from nail2nail.io._json import dumps_json
from nail2nail.io.points import thesis_table
from nail2nail.pipeline import format_summary, run_demo
from nail2nail.report import write_report

__all__ = ["MIN_DEMO_SCALE", "add_parser", "run", "thesis_part"]

#: The smallest ``--scale``: the demo calibrates from the virtual cylinder target, whose key
#: mark (a ring) must be found in every camera; measured, cam0 finds it at 0.4 (the whole demo
#: ran) and not at 0.375 nor 0.25 (the demo failed after 100 s, at step 7 of 16). 0.5, the
#: scale of the demo's own test, keeps a margin.
MIN_DEMO_SCALE = 0.5


def add_parser(sub) -> None:
    p = sub.add_parser(
        "demo",
        help="run the whole pipeline on the virtual scanner and print a summary",
        description="Run the pipeline end to end: thesis calibration tables, then (virtual "
        "scanner) simulate, distortion, calibrate, scan, merge.",
    )
    p.add_argument("--out", type=Path, default=Path("demo-output"), help="output directory")
    p.add_argument("--scale", type=float, default=1.0,
                   help=f"camera resolution scale, {MIN_DEMO_SCALE:g} to {MAX_SCALE:g} (default "
                   "1; below, the calibration target's key mark is too small to be found)")
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

    if not MIN_DEMO_SCALE <= args.scale <= MAX_SCALE:
        raise ValueError(f"--scale: expected {MIN_DEMO_SCALE:g} to {MAX_SCALE:g}, got "
                         f"{args.scale:g} (below {MIN_DEMO_SCALE:g} the calibration target's key "
                         "mark is too small for its cameras to find)")
    check_report_options(args)
    # an earlier demo (summary.json) or an empty directory; not a read-only one
    out = check_output_directory(args.out, marker="summary.json")
    thesis = thesis_part(args.json)
    if not args.json:
        print(f"\n== Virtual scanner: the whole pipeline (scale {args.scale}) -> {args.out} ==")
    with _whole(out):
        result = run_demo(out, scale=args.scale, progress=True)
        result["thesis"] = thesis
        if args.report:

            result["report"] = str(write_report(out, max_points=args.report_points,
                                                progress=True))
    if args.json:
        print(dumps_json(result, default=float))
    else:
        print(format_summary(result))
        if args.report:
            print(f"report: {result['report']}")
    return 0


@contextlib.contextmanager
def _whole(out: Path) -> Iterator[None]:
    """The demo's output directory as a whole: the new result, or what was there before.

    The demo writes where its files name each other (``summary.json``, the scans' capture and
    calibration paths), so it runs in `out` itself: an earlier result is moved aside to a
    hidden sibling first and put back if the demo fails or is interrupted, and what the failed
    run wrote is removed (a directory that was empty is left empty); on success the earlier
    result is deleted.
    """
    existed = out.is_dir()
    old = None
    if existed and any(out.iterdir()):
        out.parent.mkdir(parents=True, exist_ok=True)
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
        os.replace(out, old)  # onto the empty directory just made
    try:
        yield
    except BaseException:
        if existed and old is None:  # it was empty: empty again
            for child in list(out.iterdir()) if out.is_dir() else []:
                if child.is_dir() and not child.is_symlink():
                    shutil.rmtree(child, ignore_errors=True)
                else:
                    child.unlink(missing_ok=True)
        else:
            shutil.rmtree(out, ignore_errors=True)
            if old is not None:
                os.replace(old, out)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
