"""Benchmark: many captures on Dask (``nail2nail batch``) against one process looping over them.

Usage::

    .venv/bin/python bench/batch.py [--scale 0.5] [--captures 8] [--json]

Renders two virtual fingers at `scale` (3 cameras × 24 frames) and copies them into
`captures` capture directories, then times, on the same captures:

- **the peer**: one process calling :func:`nail2nail.process.process_capture` in a loop (what
  ``nail2nail process`` does for each, without the interpreter start), after one warm-up job;
- **the batch** (:func:`nail2nail.batch.process_batch`) on a local cluster of 1 and of 2
  workers, after a warm-up batch of one capture per worker (imports, numba's cached kernels);
  the cluster's start is timed apart;
- **a resumed batch**: the same call again, every capture skipped (the inputs hashed);
- **the scheduler's overhead**: the median round trip of a no-op task, and per capture
  ``(wall × workers − Σ task time) / captures``.

Throughput is in captures per minute; ratios are against the peer of the same run. On a
machine shared with other work the figures move with its load.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path


def make_captures(root: Path, scale: float, n: int) -> tuple[list[Path], Path]:
    from nail2nail.calibration.files import RigCalibration, save_calibration
    from nail2nail.simulation.capture import simulate_capture
    from nail2nail.simulation.rig import default_rig, ideal_calibration

    rig = default_rig(scale, projector_distortion="none")
    calib = root / "rig.json"
    save_calibration(calib, RigCalibration.from_dict(ideal_calibration(rig)))
    seeds = [root / f"seed{s}" for s in (1, 2)]
    for s, path in zip((1, 2), seeds, strict=True):
        simulate_capture(path, "finger", rig=rig, seed=s, write_truth=False)
    captures = []
    for i in range(n):
        captures.append(root / "captures" / f"finger{i:02d}")
        shutil.copytree(seeds[i % 2], captures[-1])
    return captures, calib


def noop() -> None:
    return None


def run_batch(captures, calib, root: Path, n_workers: int, options: dict) -> dict:
    from nail2nail.batch import local_client, process_batch

    start = time.perf_counter()
    client = local_client(n_workers)
    cluster_start = time.perf_counter() - start
    try:
        process_batch(captures[:n_workers], calib, root / f"warm{n_workers}", client, **options)
        round_trips = []
        for _ in range(20):
            t = time.perf_counter()
            client.submit(noop, pure=False).result()
            round_trips.append(time.perf_counter() - t)
        out = root / f"batch{n_workers}"
        t = time.perf_counter()
        rows = process_batch(captures, calib, out, client, **options)
        wall = time.perf_counter() - t
        t = time.perf_counter()
        again = process_batch(captures, calib, out, client, **options)
        resumed = time.perf_counter() - t
    finally:
        cluster = client.cluster
        client.close()
        cluster.close()
    assert all(r["status"] == "done" for r in rows), [r["error"] for r in rows]
    assert all(r["status"] == "skipped" for r in again)
    task_sum = sum(r["task_seconds"] for r in rows)
    return {"workers": n_workers, "cluster_start_s": cluster_start, "wall_s": wall,
            "per_minute": 60 * len(captures) / wall, "resumed_s": resumed,
            "noop_round_trip_ms": 1e3 * statistics.median(round_trips),
            "overhead_per_capture_s": (wall * n_workers - task_sum) / len(captures),
            "task_median_s": statistics.median(r["task_seconds"] for r in rows)}


def run_single(captures, calib, root: Path, options: dict) -> dict:
    from nail2nail.process import process_capture

    process_capture(captures[0], calib, root / "single_warm", **options)
    start = time.perf_counter()
    for c in captures:
        process_capture(c, calib, root / "single" / c.name, **options)
    wall = time.perf_counter() - start
    return {"wall_s": wall, "per_minute": 60 * len(captures) / wall}


def main() -> None:
    from nail2nail.cli._batch import process_options
    from nail2nail.cli._main import build_parser

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=0.5)
    parser.add_argument("--captures", type=int, default=8)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        t = time.perf_counter()
        captures, calib = make_captures(root, args.scale, args.captures)
        render = time.perf_counter() - t
        # the options of `nail2nail process` by default
        options = process_options(build_parser().parse_args(
            ["batch", "*", "--calib", str(calib), "--out", "o"]))
        single = run_single(captures, calib, root, options)
        batches = [run_batch(captures, calib, root, n, options) for n in (1, 2)]
    result = {"scale": args.scale, "captures": args.captures, "cpus": os.cpu_count(),
              "render_s": render, "single": single, "batch": batches}
    if args.json:
        print(json.dumps(result, indent=2))
        return
    print(f"{args.captures} captures at scale {args.scale:g} (rendered in {render:.1f} s), "
          f"{os.cpu_count()} CPUs")
    print(f"single process loop : {single['wall_s']:6.2f} s, "
          f"{single['per_minute']:6.1f} captures/min (the peer)")
    for b in batches:
        print(f"batch, {b['workers']} worker{'s' if b['workers'] > 1 else ' '}    : "
              f"{b['wall_s']:6.2f} s, {b['per_minute']:6.1f} captures/min = "
              f"{b['per_minute'] / single['per_minute']:.2f} x the peer; cluster start "
              f"{b['cluster_start_s']:.1f} s; resumed (all skipped) {b['resumed_s']:.2f} s")
        print(f"  scheduler overhead: no-op round trip {b['noop_round_trip_ms']:.1f} ms, "
              f"{b['overhead_per_capture_s']:.3f} s per capture "
              f"(task median {b['task_median_s']:.2f} s)")


if __name__ == "__main__":
    main()
