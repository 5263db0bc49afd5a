"""``nail2nail report``: one self-contained HTML page for an output directory (issue 13).

Thin command layer over :func:`nail2nail.report.write_report`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from nail2nail.report import write_report

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "report",
        help="one self-contained HTML page of a scan: capture, calibration, merge, 3D, print",
        description="Write an HTML report of the output directory of `process`, `demo`, `scan` "
        "or `merge`: frame thumbnails, decode quality and coverage, calibration tables and "
        "residuals, projector distortion, merge error per camera pair, an interactive 3D viewer "
        "of the super scan (plotly.js, WebGL) and the rolled-equivalent print. Every image and "
        "script is embedded: the page opens offline.",
    )
    p.add_argument("out_dir", type=Path, help="output directory of process, demo, scan or merge")
    p.add_argument("--out", type=Path, default=None,
                   help="report file (default: OUT_DIR/report.html)")
    add_report_options(p)
    p.set_defaults(func=run)


def add_report_options(p: argparse.ArgumentParser) -> None:
    """The report's options, shared by ``report``, ``process --report`` and ``demo``."""
    p.add_argument("--report-points", type=int, default=60_000, metavar="N",
                   help="most super-scan vertices in the report's 3D viewer (decimated by "
                   "vertex clustering; default 60000: opens in about 2 s without a GPU)")


def check_report_options(args: argparse.Namespace) -> None:
    if not args.report_points >= 100:
        raise ValueError(f"--report-points: expected at least 100, got {args.report_points}")


def run(args: argparse.Namespace) -> int:

    check_report_options(args)
    path = write_report(args.out_dir, args.out, max_points=args.report_points, progress=True)
    print(f"wrote {path}")
    return 0
