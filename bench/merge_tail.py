"""The tail of the merge error and the distance of the fused surface to the truth (issue 9).

Renders (once) the plane, target and finger at the given scale under the demo's plain patterns,
calibrates as the demo's ``best`` configuration (projector distortion estimated from the plane,
joint calibration refined on the target), scans the finger with it and with the simulator's
true calibration, and prints for each:

- per camera pair 0-1 and 1-2, the merge error (median / p95 / max, µm, pairs above 50 µm)
  before and after the rejection of unreliable pairs, and the rejections per reason;
- the distance of every vertex of the fused super scan to the true surface (along the true
  normal of its pixel; median, p99.9, max, count above 50 µm), with and without the
  rejections, and the time of ``fuse_scans``.

Usage: ``python bench/merge_tail.py [WORK_DIR] [--scale S]`` (default a temporary directory,
scale 1; about 3 minutes at full scale on two cores, captures reused when WORK_DIR has them).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from _scenes import render_scenes

from nail2nail.calibration.files import RigCalibration
from nail2nail.io.capture import read_capture, read_truth
from nail2nail.merge import correspond
from nail2nail.merge.fusion import fuse_scans
from nail2nail.pipeline import best_calibration, plane_distortion
from nail2nail.scan.capture import scan_capture
from nail2nail.scan.patterns import default_pattern_set
from nail2nail.simulation.rig import Rig, ideal_calibration

OFF = {"max_view_angle_deg": None, "max_incidence_deg": None, "min_relative_modulation": None,
       "outlier_mm": None}
FUSE_OFF = {**OFF, "spike_mm": None, "surface_mm": None}


def calibrations(work: Path, scale: float) -> dict:
    render_scenes(work, scale)
    pattern_set = default_pattern_set()
    fit = plane_distortion(read_capture(work / "plane", load=False)).fit
    best = best_calibration(read_capture(work / "target", load=False), center=fit.center,
                            rho=fit.rho, panel_size=pattern_set.panel_size)
    finger = read_capture(work / "finger", load=False)
    true = RigCalibration.from_dict(ideal_calibration(Rig.from_capture(finger)))
    return {"best (joint)": best, "true": true}


def um(stats: dict) -> str:
    d = stats["distance_mm"]
    return f"{1e3 * d['median']:5.2f} / {1e3 * d['p95']:5.2f} / {1e3 * d['max']:6.1f}"


def fused_distance_um(sup, scans, work: Path) -> np.ndarray:
    out = []
    for k, scan in enumerate(scans):
        truth = read_truth(work / "finger", scan.name)
        sel = sup.camera == k
        r, c = sup.pixel[sel].T
        d = np.sum((sup.vertices[sel] - truth["xyz"][r, c]) * truth["normal"][r, c], axis=-1)
        out.append(np.where(truth["mask"][r, c], np.abs(d) * 1e3, np.nan))
    return np.concatenate(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("work", nargs="?", type=Path)
    parser.add_argument("--scale", type=float, default=1.0)
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp()) / "merge_tail"
    work.mkdir(parents=True, exist_ok=True)
    max_gradient = 2.0 / args.scale
    for name, calib in calibrations(work, args.scale).items():
        scans = scan_capture(read_capture(work / "finger", load=False), calib,
                             max_gradient=max_gradient)
        print(f"\n== finger, scale {args.scale}, calibration: {name} ==")
        print(f"{'pair':<5}{'before: median / p95 / max µm':>32}{'>50 µm':>8}"
              f"{'after: median / p95 / max µm':>31}{'>50 µm':>8}  rejected (view angle / "
              f"incidence / modulation / outlier)")
        for i, j in ((0, 1), (1, 2)):
            m = correspond(scans[i], scans[j])
            stats = m.statistics()
            before = m.all_pairs().distance_mm
            r = stats["rejected"]
            print(f"{i}-{j:<3}{um(stats['before_rejection']):>32}{np.sum(before > 0.05):>8}"
                  f"{um(stats):>31}{np.sum(m.distance_mm > 0.05):>8}  {r['view_angle']} / "
                  f"{r['incidence']} / {r['modulation']} / {r['outlier']} of {before.size}")
        for label, options in (("with rejection", {}), ("without", FUSE_OFF)):
            start = time.perf_counter()
            sup = fuse_scans(scans, **options)
            elapsed = time.perf_counter() - start
            d = fused_distance_um(sup, scans, work)
            d = d[np.isfinite(d)]
            print(f"fused ({label}): {sup.n_vertices} vertices, distance to truth median "
                  f"{np.median(d):.2f} µm, p99.9 {np.percentile(d, 99.9):.2f} µm, max "
                  f"{d.max():.1f} µm, {np.sum(d > 50)} above 50 µm; fuse_scans {elapsed:.1f} s")
            if options == {}:
                print(f"  points rejected: {sup.points_rejected}")


if __name__ == "__main__":
    main()
