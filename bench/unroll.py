"""Benchmark: unroll a full-resolution finger, against the scan it comes from.

Usage::

    .venv/bin/python bench/unroll.py [--scale 1.0] [--repeats 5] [--methods rolled,isometric]
    .venv/bin/python bench/unroll.py --scans DIR [--repeats 7]

Renders one virtual finger (3 cameras, 24 frames), scans it with the ideal calibration, then
times in the same process, as medians of `repeats` runs: the scan (`scan_capture`: decode and
triangulate every camera), the super scan (`fuse_scans`) and `unroll_scans` for each method,
with the median of each of the unroll's steps. With ``--scans DIR`` (scans saved by
``nail2nail scan``, e.g. a full-resolution finger) only the unroll is timed, on those scans.
Targets: the default unroll ≤ 2 s on a 2-core machine (issue 9), then ≤ 0.6 s on the
full-resolution finger (3 × 1280 × 1024 px), half its former 1.2 s.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time

from _measure import median_time


def _median_unroll(scans, method: str, repeats: int):
    """Median time of `unroll_scans` and the median of each of its steps (the last print)."""
    from nail2nail.unroll import unroll_scans

    unroll_scans(scans, method=method)  # warm-up (imports, compiled kernels, first calls)
    times, steps, rolled = [], {}, None
    for _ in range(repeats):
        t = time.perf_counter()
        rolled = unroll_scans(scans, method=method)
        times.append(time.perf_counter() - t)
        for k, v in rolled.timings.items():
            steps.setdefault(k, []).append(v)
    return statistics.median(times), {k: statistics.median(v) for k, v in steps.items()}, rolled


def _bench_saved(path: str, methods, repeats: int) -> None:
    from nail2nail.io.scans import load_scans

    scans = load_scans(path)
    n_valid = sum(int(s.mask.sum()) for s in scans)
    print(f"scans {path}: {len(scans)} cameras {[s.xyz.shape[:2] for s in scans]}, {n_valid} "
          f"valid pixels; CPUs visible: {os.cpu_count()}; medians of {repeats} runs")
    for method in methods:
        t_unroll, steps, rolled = _median_unroll(scans, method, repeats)
        text = ", ".join(f"{k} {v:.3f}" for k, v in steps.items())
        print(f"unroll {method:<10} {t_unroll:7.3f} s   [{rolled.image.shape[1]} x "
              f"{rolled.image.shape[0]} px; {text}]")
    print("target: the default unroll (first row) <= 0.6 s on the full-resolution finger")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--methods", default=None, help="comma-separated (default: all)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scans", default=None,
                        help="time the unroll of saved scans (a `nail2nail scan` output folder)")
    args = parser.parse_args()

    from nail2nail.calibration.files import load_calibration
    from nail2nail.io.capture import read_capture
    from nail2nail.merge.fusion import fuse_scans
    from nail2nail.scan.capture import scan_capture
    from nail2nail.simulation.capture import simulate_capture
    from nail2nail.unroll import DEFAULT_METHOD, METHODS

    methods = args.methods.split(",") if args.methods else \
        [DEFAULT_METHOD, *[m for m in METHODS if m != DEFAULT_METHOD]]
    if args.scans:
        _bench_saved(args.scans, methods, args.repeats)
        return
    with tempfile.TemporaryDirectory(prefix="nail2nail-bench-") as tmp:
        t = time.perf_counter()
        simulate_capture(f"{tmp}/finger", "finger", scale=args.scale, seed=args.seed)
        t_sim = time.perf_counter() - t
        capture = read_capture(f"{tmp}/finger")
        calib = load_calibration(f"{tmp}/finger/truth/calibration.json")
        t_scan, scans = median_time(lambda: scan_capture(capture, calib, progress=False),
                                     args.repeats)
        t_fuse, _ = median_time(lambda: fuse_scans(scans), max(1, args.repeats // 2))
        rows = [(method, *_median_unroll(scans, method, args.repeats)) for method in methods]
    n_valid = sum(int(s.mask.sum()) for s in scans)
    print(f"finger at scale {args.scale}: {len(scans)} cameras, {n_valid} valid pixels; "
          f"CPUs visible: {os.cpu_count()}; medians of {args.repeats} runs")
    print(f"render (once):           {t_sim:7.2f} s")
    print(f"scan (scan_capture):     {t_scan:7.2f} s")
    print(f"super scan (fuse_scans): {t_fuse:7.2f} s")
    for method, t_unroll, step_medians, rolled in rows:
        steps = ", ".join(f"{k} {v:.2f}" for k, v in step_medians.items())
        print(f"unroll {method:<10}       {t_unroll:7.2f} s  = {t_unroll / t_scan:5.2f} x scan"
              f"   [{rolled.image.shape[1]} x {rolled.image.shape[0]} px; {steps}]")
    print("target: the default unroll (first row) <= 2 s on a 2-core machine")


if __name__ == "__main__":
    main()
