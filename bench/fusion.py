"""Benchmark: the super scan (``fuse_scans``) of a full-resolution finger, step by step.

Usage::

    .venv/bin/python bench/fusion.py [--scale 1.0] [--repeats 5] [--scans DIR]

Renders one virtual finger (3 cameras, 1280 × 1024 px at scale 1), scans it with the rig's
true calibration (or loads the scans of DIR, as written by ``nail2nail scan``), then times in
one process, as medians of `repeats` runs after a first call (which loads the compiled
kernels):

- ``fuse_scans`` in total and per step (:attr:`SuperScan.timings`; ``correspond`` is the
  projector-space matching of the six ordered camera pairs, the rest is the fusion proper);
- ``write_super_ply`` and ``write_super_mat5``;
- the peak RSS of one ``fuse_scans`` in a fresh process, above the memory held before it (the
  interpreter and the scans; Linux ``clear_refs``).

Peers, on the same points in the same run: ``scipy.spatial.cKDTree`` (the former duplicate
search: a tree over the first camera's vertices, queried with the others' within the dedupe
distance) against the grid and dedupe steps; and, where ``open3d`` is installed, its normal
estimation (8 nearest neighbours, ``estimate_normals``) of the super scan's vertices against
the normals step and its voxel down-sampling at the dedupe distance of every valid point
against the grid and dedupe steps.

Target (issue 11): the whole ``fuse_scans`` well under 1 s on a 2-core machine; the whole
merge step within 1.2 GB.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _measure import median_time, reset_peak, status_mb


def _finger_scans(scale: float, seed: int):
    from nail2nail.calibration.files import load_calibration
    from nail2nail.io.capture import read_capture
    from nail2nail.scan.capture import scan_capture
    from nail2nail.simulation.capture import simulate_capture

    with tempfile.TemporaryDirectory(prefix="nail2nail-bench-") as tmp:
        simulate_capture(f"{tmp}/finger", "finger", scale=scale, seed=seed)
        calib = load_calibration(f"{tmp}/finger/truth/calibration.json")
        return scan_capture(read_capture(f"{tmp}/finger"), calib, progress=False)


def _peak_child(scan_dir: Path) -> None:
    """In a fresh process: the RSS after reading the scans, and the peak of one fuse_scans."""
    from nail2nail.io.scans import load_scans
    from nail2nail.merge.fusion import fuse_scans

    scans = load_scans(scan_dir)
    before = status_mb("VmRSS")
    if not reset_peak() or before is None:
        print(json.dumps(None))
        return
    fuse_scans(scans)
    print(json.dumps({"before": before, "peak": status_mb("VmHWM")}))


def _peak(scans, scan_dir: Path | None) -> dict | None:
    with tempfile.TemporaryDirectory(prefix="nail2nail-bench-") as tmp:
        if scan_dir is None:
            from nail2nail.io.scans import save_scans

            scan_dir = Path(tmp) / "scan"
            save_scans(scan_dir, scans, mat5=False, ply=False)
        out = subprocess.run([sys.executable, __file__, "--peak-child", str(scan_dir)],
                             capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scans", type=Path, default=None,
                        help="a folder written by `nail2nail scan` (default: render a finger)")
    parser.add_argument("--peak-child", type=Path, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.peak_child is not None:
        _peak_child(args.peak_child)
        return

    from nail2nail.merge.correspondence import valid_mask
    from nail2nail.merge.fusion import fuse_scans, write_super_mat5, write_super_ply

    t = time.perf_counter()
    if args.scans is not None:
        from nail2nail.io.scans import load_scans

        scans, source = load_scans(args.scans), str(args.scans)
    else:
        scans, source = _finger_scans(args.scale, args.seed), f"virtual finger, scale {args.scale}"
    t_scans = time.perf_counter() - t
    n_valid = [int(valid_mask(s).sum()) for s in scans]
    h, w = scans[0].shape
    print(f"{source}: {len(scans)} cameras of {w} x {h} px, valid pixels {n_valid}; CPUs "
          f"visible: {os.cpu_count()}; medians of {args.repeats} runs (scans ready in "
          f"{t_scans:.1f} s)")

    t = time.perf_counter()
    sup = fuse_scans(scans)
    t_first = time.perf_counter() - t
    steps: dict[str, list[float]] = {}

    def fuse():
        out = fuse_scans(scans)
        for step, seconds in out.timings.items():
            steps.setdefault(step, []).append(seconds)
        return out

    t_fuse, sup = median_time(fuse, args.repeats)
    step = {k: statistics.median(v) for k, v in steps.items()}
    matching = step["correspond"]
    print(f"super scan: {sup.n_vertices} vertices, {sup.faces.shape[0]} faces")
    print(f"fuse_scans, first call:      {t_first:7.3f} s (loads the compiled kernels)")
    print(f"fuse_scans:                  {t_fuse:7.3f} s = correspondences {matching:.3f} s + "
          f"fusion {t_fuse - matching:.3f} s")
    for name, seconds in step.items():
        print(f"  {name:<14} {1e3 * seconds:8.1f} ms")

    with tempfile.TemporaryDirectory(prefix="nail2nail-bench-") as tmp:
        t_ply, path = median_time(lambda: write_super_ply(Path(tmp) / "super.ply", sup),
                                   args.repeats)
        ply_mb = path.stat().st_size / 2**20
        t_mat5, files = median_time(lambda: write_super_mat5(Path(tmp) / "super", sup),
                                     args.repeats)
        mat5_mb = sum(f.stat().st_size for f in files) / 2**20
    print(f"write_super_ply:             {t_ply:7.3f} s ({ply_mb:.0f} MB, "
          f"{ply_mb / t_ply:.0f} MB/s)")
    print(f"write_super_mat5:            {t_mat5:7.3f} s ({mat5_mb:.0f} MB in {len(files)} files)")

    peak = _peak(scans, args.scans)
    if peak is None:
        print("peak RSS of fuse_scans:      not measurable here (no /proc/self/clear_refs)")
    else:
        print(f"peak RSS of fuse_scans:      {peak['peak']:7.0f} MB in a fresh process "
              f"({peak['peak'] - peak['before']:.0f} MB above the {peak['before']:.0f} MB held "
              "before: interpreter and scans)")

    _peers(scans, sup, step)
    print("target: fuse_scans well under 1 s on a 2-core machine")


def _peers(scans, sup, step: dict) -> None:
    """The same searches by scipy's k-d tree and, where installed, by Open3D."""
    import scipy.spatial

    from nail2nail.merge.correspondence import valid_mask

    points = [np.asarray(s.xyz)[valid_mask(s)].astype(np.float64) for s in scans]
    dedupe_mm = 0.5 * float(np.nanmedian(np.linalg.norm(np.diff(scans[0].xyz, axis=1), axis=-1)))
    ours = step["grid"] + step["dedupe"]

    def kdtree():
        tree = scipy.spatial.cKDTree(points[0])
        for p in points[1:]:
            tree.query(p, distance_upper_bound=dedupe_mm)

    t_tree, _ = median_time(kdtree, 3)
    print(f"peer cKDTree duplicate search (build {points[0].shape[0]}, query "
          f"{sum(p.shape[0] for p in points[1:])}): {1e3 * t_tree:.0f} ms; ours (grid + dedupe) "
          f"{1e3 * ours:.0f} ms = {ours / t_tree:.2f} x")
    try:
        import open3d as o3d
    except ImportError:
        print("peer open3d: not installed (pip install open3d for its normal estimation and "
              "voxel down-sampling of the same points)")
        return
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(
        sup.vertices.astype(np.float64)))
    t_normals, _ = median_time(
        lambda: cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(8)), 3)
    print(f"peer open3d estimate_normals (8 nearest, {sup.n_vertices} points): "
          f"{1e3 * t_normals:.0f} ms; ours (normals) {1e3 * step['normals']:.0f} ms = "
          f"{step['normals'] / t_normals:.2f} x")
    every = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.concatenate(points)))
    t_voxel, _ = median_time(lambda: every.voxel_down_sample(dedupe_mm), 3)
    print(f"peer open3d voxel_down_sample ({dedupe_mm * 1e3:.0f} µm, "
          f"{sum(p.shape[0] for p in points)} points): {1e3 * t_voxel:.0f} ms; ours (grid + "
          f"dedupe) {1e3 * ours:.0f} ms = {ours / t_voxel:.2f} x")


if __name__ == "__main__":
    main()
