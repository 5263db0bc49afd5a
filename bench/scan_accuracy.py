"""Scan accuracy on the virtual scanner against its ground truth (issue 4's figures).

Projector distortion off, default noise. Prints, per camera: the decoded projector
coordinates' RMS error and largest error (projector px), and the RMS distance of the scanned
finger to the true surface (µm) after calibrating on the target capture, with the thesis's
per-camera DLT and with the joint calibration.

Usage: ``python bench/scan_accuracy.py [--scale S]`` (default 1.0; about 3 minutes).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from nail2nail.calibration.markers import TargetGeometry
from nail2nail.calibration.observe import target_observations
from nail2nail.calibration.target import calibrate_from_observations
from nail2nail.io.capture import read_capture, read_truth
from nail2nail.scan.capture import scan_capture
from nail2nail.scan.decoding import decode
from nail2nail.simulation.capture import simulate_capture
from nail2nail.simulation.rig import default_rig


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    root = Path(tempfile.mkdtemp())
    rig = default_rig(args.scale, projector_distortion="none")
    for scene in ("target", "finger"):
        simulate_capture(root / scene, scene, rig=rig, seed=args.seed)
    finger = read_capture(root / "finger", load=False)
    print(f"scale {args.scale}: decoded projector coordinates vs truth (finger)")
    for max_gradient in (None, 2.0):  # decode's default, and the one scans use
        print(f" max_gradient={max_gradient}")
        for name in finger.camera_names:
            d = decode(finger.load_frames(name), finger.pattern_set, max_gradient=max_gradient)
            t = read_truth(root / "finger", name)
            ok = d.mask & t["mask"]
            ex, ey = d.xp[ok] - t["xp"][ok], d.yp[ok] - t["yp"][ok]
            print(f"  {name}: valid {ok.sum()} px ({ok.sum() / t['mask'].sum():.0%} of the "
                  f"lit surface), RMS xp {np.sqrt(np.mean(ex**2)):.4f} px, RMS yp "
                  f"{np.sqrt(np.mean(ey**2)):.4f} px, max |error| {np.hypot(ex, ey).max():.3f} px")
    observations = target_observations(read_capture(root / "target", load=False))
    surface = TargetGeometry().signed_distance
    for model in ("dlt", "joint"):
        calib, _ = calibrate_from_observations(observations, model=model, surface=surface)
        cells = []
        for scan in scan_capture(finger, calib):
            t = read_truth(root / "finger", scan.name)
            ok = scan.mask & t["mask"]
            dist = np.sum((scan.xyz[ok] - t["xyz"][ok]) * t["normal"][ok], axis=-1)
            cells.append(f"{scan.name} {1000 * np.sqrt(np.mean(dist**2)):5.1f} µm")
        print(f"finger RMS distance to the true surface, {model:5s} calibration: "
              + ", ".join(cells))


if __name__ == "__main__":
    main()
