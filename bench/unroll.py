"""Benchmark: unroll a full-resolution finger, against the scan it comes from.

Usage::

    .venv/bin/python bench/unroll.py [--scale 1.0] [--repeats 5] [--methods rolled,isometric]

Renders one virtual finger (3 cameras, 24 frames), scans it with the ideal calibration, then
times in the same process, as medians of `repeats` runs: the scan (`scan_capture`: decode and
triangulate every camera), the super scan (`fuse_scans`) and `unroll_scans` for each method,
with the unroll's steps. Target (issue 9): the default unroll ≤ 2 s on a 2-core machine.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time


def _median_time(fn, repeats: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--methods", default=None, help="comma-separated (default: all)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    from nail2nail.io.calibration import load_calibration
    from nail2nail.io.capture import read_capture
    from nail2nail.merge.fusion import fuse_scans
    from nail2nail.scanning import scan_capture
    from nail2nail.simulation.capture import simulate_capture
    from nail2nail.unroll import DEFAULT_METHOD, METHODS, unroll_scans

    methods = args.methods.split(",") if args.methods else \
        [DEFAULT_METHOD, *[m for m in METHODS if m != DEFAULT_METHOD]]
    with tempfile.TemporaryDirectory(prefix="nail2nail-bench-") as tmp:
        t = time.perf_counter()
        simulate_capture(f"{tmp}/finger", "finger", scale=args.scale, seed=args.seed)
        t_sim = time.perf_counter() - t
        capture = read_capture(f"{tmp}/finger")
        calib = load_calibration(f"{tmp}/finger/truth/calibration.json")
        t_scan, scans = _median_time(lambda: scan_capture(capture, calib, progress=False),
                                     args.repeats)
        t_fuse, _ = _median_time(lambda: fuse_scans(scans), max(1, args.repeats // 2))
        rows = []
        for method in methods:
            unroll_scans(scans, method=method)  # warm-up (imports, first calls)
            t_unroll, rolled = _median_time(lambda m=method: unroll_scans(scans, method=m),
                                            args.repeats)
            rows.append((method, t_unroll, rolled))
    n_valid = sum(int(s.mask.sum()) for s in scans)
    print(f"finger at scale {args.scale}: {len(scans)} cameras, {n_valid} valid pixels; "
          f"CPUs visible: {os.cpu_count()}; medians of {args.repeats} runs")
    print(f"render (once):           {t_sim:7.2f} s")
    print(f"scan (scan_capture):     {t_scan:7.2f} s")
    print(f"super scan (fuse_scans): {t_fuse:7.2f} s")
    for method, t_unroll, rolled in rows:
        steps = ", ".join(f"{k} {v:.2f}" for k, v in rolled.timings.items())
        print(f"unroll {method:<10}       {t_unroll:7.2f} s  = {t_unroll / t_scan:5.2f} x scan"
              f"   [{rolled.image.shape[1]} x {rolled.image.shape[0]} px; {steps}]")
    print("target: the default unroll (first row) <= 2 s on a 2-core machine")


if __name__ == "__main__":
    main()
