"""``nail2nail batch``: the whole job of ``nail2nail process`` for many captures, on Dask.

Thin command layer over :func:`nail2nail.batch.process_batch`: the processing options are
those of ``process``; a local cluster (``--workers``) or an existing one (``--scheduler``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from nail2nail.batch import (
    check_cameras,
    check_workers,
    close_quietly,
    default_workers,
    find_captures,
    first_calibration,
    local_client,
    process_batch,
)
from nail2nail.batch.memory import check_memory_mb, max_workers
from nail2nail.calibration.files import load_calibration
from nail2nail.cli._process import add_process_options, process_options
from nail2nail.cli._report import add_report_options, check_report_options
from nail2nail.interchange.subjects import export_subjects, read_subject_table
from nail2nail.io._atomic import check_output_directory
from nail2nail.io._json import dumps_json

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "batch",
        help="the whole job (`process`) for many captures, on a Dask cluster",
        description="Run `nail2nail process CAPTURE --out OUT/<capture name>` for every "
        "capture directory that CAPTURES (a glob, quoted) matches, one Dask task each, on a "
        "local cluster or an existing one; skip a capture whose output is complete and whose "
        "inputs (files, calibration, options, nail2nail version) are unchanged, and one that "
        "failed on bad input with the same inputs (its error repeated); write OUT/batch.csv "
        "and OUT/batch.json, one row per capture.",
    )
    p.add_argument("captures", help="glob of capture directories, e.g. 'captures/*' (quoted)")
    p.add_argument("--calib", type=Path, required=True, help="calibration JSON")
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument("--scheduler", default=None,
                   help="address of a running Dask scheduler, e.g. tcp://host:8786 (default: "
                   "a local cluster)")
    p.add_argument("--workers", type=int, default=None,
                   help=f"local cluster: worker processes, 1 to the CPU count ({max_workers()} "
                   "here), capped at the number of captures (a worker more would stay idle); "
                   "default: the CPU count, capped at the number of captures and so that as "
                   "many captures fit in 80%% of the available memory")
    p.add_argument("--memory-per-capture", type=float, default=None, metavar="MB",
                   help="peak memory of one capture, MB (a positive number), for the default "
                   "--workers (default: estimated from the frames; process.json's peak_rss_mb "
                   "measures it)")
    p.add_argument("--retry-failed", action="store_true",
                   help="run again the captures that failed on bad input last time even if "
                   "their inputs are unchanged")
    add_process_options(p)
    p.add_argument("--report", action="store_true",
                   help="also write OUT/<capture name>/report.html, each capture's HTML report")
    add_report_options(p)
    p.add_argument("--subjects", type=Path, default=None, metavar="TABLE.csv",
                   help="also write OUT/transactions/<subject>.an2, one ANSI/NIST-ITL "
                   "transaction per person (`export-nist`), from a CSV table with the header "
                   "capture,subject,finger_position (a row per capture)")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:

    options = process_options(args)
    check_report_options(args)
    if args.scheduler is not None:
        given = [f for f, v in (("--workers", args.workers),
                                ("--memory-per-capture", args.memory_per_capture)) if v is not None]
        if given:
            raise ValueError(f"{given[0]}: for a local cluster only, not with --scheduler")
    if args.memory_per_capture is not None:
        if args.workers is not None:
            raise ValueError("--memory-per-capture: sets the default --workers; not with "
                             "--workers")
        check_memory_mb(args.memory_per_capture, name="--memory-per-capture")
    if args.workers is not None:
        check_workers(args.workers, 1, name="--workers")  # before anything is read
    captures = find_captures(args.captures)
    # the options that name cameras, against the calibration and every capture: a bad one
    # would fail every capture, after the cluster has started
    # (rig.json, or rig_<capture>.json of a capture of several projectors)
    check_cameras(captures, load_calibration(first_calibration(args.calib, captures),
                                             allow_mirrored=args.allow_mirrored),
                  frame=args.frame, masks=options["masks"], pairs=args.pairs,
                  names={"frame": "--frame", "masks": "--mask", "pairs": "--pairs"})
    check_output_directory(args.out)  # not a file, not read-only
    subjects = read_subject_table(args.subjects, captures) if args.subjects else None
    if args.scheduler is not None:
        from distributed import Client

        client, cluster = Client(args.scheduler), None
    else:
        n = (check_workers(args.workers, len(captures), name="--workers")
             if args.workers is not None
             else default_workers(captures, memory_mb=args.memory_per_capture))
        client = local_client(n)
        cluster = client.cluster
    try:
        rows = process_batch(captures, args.calib, args.out, client, progress=True,
                             retry_failed=args.retry_failed,
                             report_points=args.report_points if args.report else None,
                             **options)
    finally:
        close_quietly(client, cluster)
    counts = {s: sum(r["status"] == s for r in rows) for s in ("done", "skipped", "failed")}
    if args.json:
        print(dumps_json(rows))
    else:
        _print_rows(rows, counts, args.out)
    for path in export_subjects(subjects, rows, args.out) if subjects else []:
        if not args.json:
            print(f"wrote {path}")
    if counts["failed"]:  # a capture's bad input: exit 2 as for one capture, the rest written
        print(f"nail2nail batch: error: {counts['failed']} of {len(rows)} captures failed "
              f"(their errors: {Path(args.out) / 'batch.csv'})", file=sys.stderr)
        return 2
    return 0


def _print_rows(rows: list[dict], counts: dict[str, int], out: Path) -> None:
    for row in rows:
        line = f"{row['capture']}: {row['status']}"
        if row["status"] == "failed":
            line += f": {row['error']}"
            if not row["ran"] and row["bad_input"]:
                line += " (inputs unchanged since it failed: not run; --retry-failed)"
        elif row["seconds"]:
            line += f" ({row['seconds'].get('total', 0):.2f} s, {row['worker']}"
            line += f", {row['attempts']} attempts)" if row["attempts"] > 1 else ")"
        print(line)
    print(", ".join(f"{n} {s}" for s, n in counts.items()))
    print(f"wrote {Path(out) / 'batch.csv'} and batch.json")
