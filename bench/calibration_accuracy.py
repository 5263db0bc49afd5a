"""Accuracy of the joint calibration against the virtual scanner's truth, and the merge error it
leaves on the finger (issue 9).

Renders (once) the plane, target and finger at the given scale under the demo's plain patterns,
then calibrates as the demo's ``best`` configuration (projector distortion estimated from the
plane, joint calibration refined on the target's surface) in two ways: with the marks' measured
centroids compared with the projections of their centres (``centres``, the calibration before
issue 9), with the centroids of the marks' projected discs modelled (``mark model``,
``target=TargetGeometry()``), and the same with the marks measured against a local background
(``mark model, refined marks``: ``find_target_marks(refine=True)``). For each, and for the
simulator's true calibration, it prints:

- the calibration time;
- per camera, the error of the calibration alone: true finger surface points (every 4th pixel
  of the truth) reconstructed from their true pixel and panel coordinates, minus the truth
  (median and RMS of the distance, mean and RMS along the true normal, µm);
- per camera pair 0-1 and 1-2, the same error difference of the two cameras at common points
  (calibration only), and the merge error of the scanned finger after the rejection of
  unreliable pairs (median / p95 / max µm, :func:`nail2nail.merge.correspond`).

Usage: ``python bench/calibration_accuracy.py [WORK_DIR] [--scale S] [--no-merge]`` (captures
reused when WORK_DIR has them, e.g. those of ``bench/merge_tail.py``; about 3 minutes at full
scale on two cores with the merge figures).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from _scenes import render_scenes

from nail2nail.calibration.distortion import ideal_from_panel
from nail2nail.calibration.files import RigCalibration
from nail2nail.calibration.markers import TargetGeometry
from nail2nail.calibration.observe import target_observations
from nail2nail.calibration.target import calibrate_from_observations
from nail2nail.io.capture import read_capture, read_truth
from nail2nail.merge import correspond
from nail2nail.pipeline import plane_distortion
from nail2nail.scan.capture import scan_capture
from nail2nail.scan.patterns import default_pattern_set
from nail2nail.scan.triangulation import model_matrix, reconstruct_points_lsq
from nail2nail.simulation.rig import Rig, ideal_calibration


def calibrations(work: Path) -> dict:
    fit = plane_distortion(read_capture(work / "plane", load=False)).fit
    capture = read_capture(work / "target", load=False)
    observations = target_observations(capture)
    # refined mark centroids (find_target_marks(refine=True))
    observations_refined = target_observations(capture, refine_marks=True)
    target = TargetGeometry()
    common = {"model": "joint", "surface": target.signed_distance,
              "projector_size": default_pattern_set().panel_size,
              "initial_distortion": {"center": list(fit.center), "rho": fit.rho}}
    out = {}
    for name, obs, options in (
        ("centres", observations, {}),
        ("mark model", observations, {"target": target}),
        ("mark model, refined marks", observations_refined, {"target": target}),
    ):
        start = time.perf_counter()
        out[name] = calibrate_from_observations(obs, **common, **options)[0]
        print(f"calibration {name!r}: {time.perf_counter() - start:.1f} s")
    finger = read_capture(work / "finger", load=False)
    out["true"] = RigCalibration.from_dict(ideal_calibration(Rig.from_capture(finger)))
    return out


def truth_points(work: Path, rig, step: int = 4) -> dict:
    out = {}
    for name in rig.camera_names:
        t = read_truth(work / "finger", name)
        m = t["mask"][::step, ::step]
        out[name] = (t["xyz"][::step, ::step][m].astype(float),
                     t["normal"][::step, ::step][m].astype(float))
    return out


def reconstruct_true(calib: RigCalibration, rig, name: str, xyz: np.ndarray) -> np.ndarray:
    """Points reconstructed by `calib` from the true pixel and panel coordinates of `xyz`."""
    cam = calib.camera(name)
    xy = rig.cameras[rig.camera_names.index(name)].project(xyz)
    panel = rig.panel_from_world(xyz)
    d = calib.projector_distortion
    ideal = panel if d is None else ideal_from_panel(panel, d["center"], d["rho"])
    return reconstruct_points_lsq(model_matrix(cam.camera), model_matrix(cam.projector),
                                  *xy.T, *ideal.T, camera_weight=1e3)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("work", nargs="?", type=Path)
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--no-merge", action="store_true", help="skip scanning the finger")
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp()) / "calibration_accuracy"
    work.mkdir(parents=True, exist_ok=True)
    render_scenes(work, args.scale)
    rig = Rig.from_capture(read_capture(work / "finger", load=False))
    points = truth_points(work, rig)
    names = rig.camera_names
    for label, calib in calibrations(work).items():
        print(f"\n== calibration: {label} (scale {args.scale}) ==")
        for name in names:
            xyz, normal = points[name]
            e = reconstruct_true(calib, rig, name, xyz) - xyz
            dist = np.linalg.norm(e, axis=1) * 1e3
            along = np.sum(e * normal, axis=1) * 1e3
            print(f"{name}: calibration error |e| median {np.median(dist):5.2f} rms "
                  f"{np.sqrt(np.mean(dist**2)):5.2f} µm; along the normal mean {along.mean():+5.2f}"
                  f" rms {np.sqrt(np.mean(along**2)):5.2f} µm")
        scans = None if args.no_merge else scan_capture(
            read_capture(work / "finger", load=False), calib, max_gradient=2.0 / args.scale)
        for i, j in ((0, 1), (1, 2)):
            xyz, normal = points[names[i]]
            view = rig.cameras[j].center - xyz
            view /= np.linalg.norm(view, axis=1, keepdims=True)
            common = xyz[np.sum(view * normal, axis=1) > 0.5]
            diff = np.linalg.norm(reconstruct_true(calib, rig, names[i], common)
                                  - reconstruct_true(calib, rig, names[j], common), axis=1) * 1e3
            line = (f"pair {i}-{j}: calibration only median {np.median(diff):5.2f} p95 "
                    f"{np.percentile(diff, 95):5.2f} µm")
            if scans is not None:
                d = correspond(scans[i], scans[j]).statistics()["distance_mm"]
                line += (f"; merge median / p95 / max {1e3 * d['median']:5.2f} / "
                         f"{1e3 * d['p95']:5.2f} / {1e3 * d['max']:5.1f} µm")
            print(line)


if __name__ == "__main__":
    main()
