"""Benchmark: the whole job for one full-resolution finger, stage by stage, against reading it.

Usage::

    .venv/bin/python bench/pipeline.py [--capture DIR --calib RIG.json] [--repeats 5] [--json]

Without ``--capture`` a full-resolution virtual finger is rendered first (3 cameras × 24
frames of 1024 × 1280, 8-bit PNG; about a minute) and scanned with its true calibration. In
one process, as medians of `repeats` runs:

- **reading the frames alone**, the reference: a plain loop of ``PIL.Image.open`` over the
  capture's PNG files (``np.asarray``), and nail2nail's own reader
  (``Capture.load_frames(raw=True)``, with its checks);
- **the job** (:func:`nail2nail.process.process_capture`, what ``nail2nail process`` runs,
  figures off) with the seconds of each stage: ``scan`` (read, decode, triangulate),
  ``write_scans``, ``merge`` (correspondence, super scan, their files), ``unroll``,
  ``write_print``;
- **peak memory** (RSS): of each stage, where Linux lets a process reset its peak
  (``/proc/self/clear_refs``), and of the whole job in a fresh child process.

Targets (issue 11): the job up to the super scan ≤ 3 × the frame reading, with the unroll
≤ 5 ×; the scan ≤ 1.5 ×; peak memory of the whole job ≤ 1.5 GB.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _measure import reset_peak, status_mb

MERGE_STAGES = ("scan", "write_scans", "merge")  # the job up to the super scan
UNROLL_STAGES = ("unroll", "write_print")


def read_plain(files) -> float:
    """Seconds to decode every PNG with a plain PIL loop (the peer: no checks, no stacking)."""
    from PIL import Image

    start = time.perf_counter()
    for f in files:
        with Image.open(f) as im:
            np.asarray(im)
    return time.perf_counter() - start


def read_ours(capture_dir) -> float:
    """Seconds for nail2nail's reader to load every camera's frames (``raw=True``)."""
    from nail2nail.io.capture import read_capture

    start = time.perf_counter()
    capture = read_capture(capture_dir, load=False)
    for name in capture.camera_names:
        capture.load_frames(name, raw=True)
    return time.perf_counter() - start


def stage_peaks(capture_dir, calib, out) -> dict:
    """Peak RSS (MB) of each stage, each stage run alone after a reset of the peak."""
    from nail2nail.calibration.files import load_calibration
    from nail2nail.io.capture import read_capture
    from nail2nail.io.rolled import write_rolled_print
    from nail2nail.io.scans import save_scans
    from nail2nail.merge import write_merge
    from nail2nail.scan.capture import scan_capture
    from nail2nail.unroll import unroll_scans

    if not reset_peak():
        return {}
    calibration = load_calibration(calib)
    peaks = {}
    reset_peak()
    base = status_mb()
    scans = scan_capture(read_capture(capture_dir, load=False), calibration)
    peaks["scan"] = status_mb()
    reset_peak()
    save_scans(out / "scans", scans, mat5=False, ply=False)
    peaks["write_scans"] = status_mb()
    reset_peak()
    write_merge(scans, out / "merge", figures=False)
    peaks["merge"] = status_mb()
    reset_peak()
    rolled = unroll_scans(scans)
    peaks["unroll"] = status_mb()
    reset_peak()
    write_rolled_print(out / "print", rolled)
    peaks["write_print"] = status_mb()
    return {"baseline_mb": round(base, 1),
            **{k: round(v, 1) for k, v in peaks.items() if v is not None}}


_CHILD = """
import json, resource, sys
from nail2nail.process import process_capture
s = process_capture(sys.argv[1], sys.argv[2], sys.argv[3], figures=False)
print(json.dumps({"seconds": s["seconds"],
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def job_in_child(capture_dir, calib, out) -> dict:
    """One whole job in a fresh Python process: its peak RSS and first-run seconds."""
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", _CHILD, str(capture_dir), str(calib), str(out)],
                          check=True, capture_output=True, text=True)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    result["wall_seconds_with_startup"] = round(time.perf_counter() - start, 2)
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--capture", type=Path, help="capture directory (default: render one)")
    parser.add_argument("--calib", type=Path, help="calibration JSON (default: the capture's "
                        "truth/calibration.json)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--scale", type=float, default=1.0, help="when rendering a capture")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)

    from nail2nail.calibration.files import load_calibration
    from nail2nail.io.capture import read_capture
    from nail2nail.process import process_capture

    with tempfile.TemporaryDirectory(prefix="nail2nail-bench-") as tmp:
        tmp = Path(tmp)
        capture_dir = args.capture
        if capture_dir is None:
            from nail2nail.simulation.capture import simulate_capture

            capture_dir = tmp / "finger"
            simulate_capture(capture_dir, "finger", scale=args.scale, seed=0)
        calib = args.calib or capture_dir / "truth" / "calibration.json"
        capture = read_capture(capture_dir, load=False)
        files = [capture.path / f for name in capture.camera_names
                 for f in capture.camera(name)["frames"]]
        calibration = load_calibration(calib)
        first = job_in_child(capture_dir, calib, tmp / "child")  # cold: compiles or loads kernels
        process_capture(capture, calibration, tmp / "warm", figures=False)  # warm-up
        plain, ours, jobs = [], [], []
        for i in range(args.repeats):
            plain.append(read_plain(files))
            ours.append(read_ours(capture_dir))
            summary = process_capture(read_capture(capture_dir, load=False), calibration,
                                      tmp / f"job{i % 2}", figures=False)
            jobs.append({**summary["seconds"], **{f"scan: {k}": v
                                                  for k, v in summary["scan_seconds"].items()}})
        peaks = stage_peaks(capture_dir, calib, tmp / "peaks")
        shape = capture.frame_shape(capture.camera_names[0])

    med = statistics.median
    t_read = med(plain)
    stages = {k: med(j[k] for j in jobs) for k in jobs[0] if k != "total"}
    t_merge_job = med(sum(j[k] for k in MERGE_STAGES) for j in jobs)
    parts = [k for k in stages if k.startswith("scan: ")]  # within the scan, not stages
    t_job = med(j["total"] for j in jobs)
    stages = {k: stages[k] for k in [*[s for s in stages if s not in parts][:1], *parts,
                                     *[s for s in stages if s not in parts][1:]]}
    result = {
        "capture": str(capture_dir), "cameras": len(capture.camera_names),
        "frames": len(files), "camera_shape": list(shape), "repeats": args.repeats,
        "read_frames_plain_pil_s": round(t_read, 3),
        "read_frames_nail2nail_s": round(med(ours), 3),
        "stages_s": {k: round(v, 3) for k, v in stages.items()},
        "job_to_super_scan_s": round(t_merge_job, 3),
        "job_with_unroll_s": round(t_job, 3),
        "ratio_scan_to_read": round(stages["scan"] / t_read, 2),
        "ratio_job_to_read": round(t_merge_job / t_read, 2),
        "ratio_job_with_unroll_to_read": round(t_job / t_read, 2),
        "stage_peak_rss_mb": peaks,
        "first_run_in_fresh_process": first,
    }
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"capture: {result['cameras']} cameras x {len(files) // result['cameras']} frames of "
          f"{shape[1]} x {shape[0]} px; medians of {args.repeats} runs")
    print(f"{'stage':<24}{'seconds':>9}{'x read':>8}{'peak MB':>9}")
    if peaks:
        print(f"{'(held before the stages)':<24}{'':17}{peaks['baseline_mb']:9.0f}")
    print(f"{'read frames (plain PIL)':<24}{t_read:9.3f}{1:8.2f}")
    print(f"{'read frames (nail2nail)':<24}{med(ours):9.3f}{med(ours) / t_read:8.2f}")
    for k, v in stages.items():
        peak = peaks.get(k)
        print(f"{k:<24}{v:9.3f}{v / t_read:8.2f}{'' if peak is None else f'{peak:9.0f}'}")
    print(f"{'job to super scan':<24}{t_merge_job:9.3f}{t_merge_job / t_read:8.2f}"
          f"   (target <= 3)")
    print(f"{'job with unroll':<24}{t_job:9.3f}{t_job / t_read:8.2f}"
          f"{first['peak_rss_mb']:9.0f}   (target <= 5; peak <= 1536 MB)")
    print(f"first run in a fresh process: {first['seconds']['total']:.2f} s of stages, "
          f"{first['wall_seconds_with_startup']:.2f} s with interpreter start and imports")
    return 0


if __name__ == "__main__":
    sys.exit(main())
