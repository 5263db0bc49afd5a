"""``nail2nail calibrate CAPTURE_DIR``: calibration from a capture of the cylindrical target."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from nail2nail._progress import Stages
from nail2nail.calibration.files import check_handedness, save_calibration
from nail2nail.calibration.markers import TargetGeometry
from nail2nail.calibration.observe import target_observations
from nail2nail.calibration.target import calibrate_from_observations
from nail2nail.io._atomic import atomic_files
from nail2nail.io._json import dumps_json
from nail2nail.io.capture import read_capture
from nail2nail.io.points import PointsTable, write_points

__all__ = ["run_capture"]


def run_capture(args: argparse.Namespace) -> int:
    if args.output is None:
        raise ValueError("calibrate CAPTURE_DIR: give the calibration file to write with -o")
    capture = read_capture(args.source)
    diameter = getattr(args, "mark_diameter_px", None)
    if diameter is None and "rig" not in capture.manifest:
        raise ValueError(
            f"{args.source / 'capture.json'}: no nominal 'rig', so the marks' size in the images "
            "is unknown: give --mark-diameter-px PX (the image diameter of a 1.2 mm mark, about "
            "focal length in px x 1.2 / distance to the target in mm) or add a nominal 'rig' "
            "(docs/capture-format.md)")
    joint = args.model == "joint"
    # the joint model predicts each mark's projected disc on the cylinder: it takes the marks
    # re-measured against their local background (unbiased centroids)
    observations = target_observations(capture, progress=True, refine_marks=joint,
                                       mark_diameter_px=diameter)
    surface = TargetGeometry().signed_distance if joint else None
    Stages(prefix="calibrate: ")(f"fit the {args.model} model")  # stderr, a terminal only
    calib, summary = calibrate_from_observations(
        observations, model=args.model, method=args.method, use=args.use, surface=surface,
        **({"target": TargetGeometry()} if joint else {}))
    if not args.allow_mirrored:
        check_handedness(calib, str(args.source),
                         scene_point=np.mean([o.xyz_world.mean(axis=0) for o in observations], 0))
    out_dir = Path(args.output).parent
    names = {obs.name: f"{Path(args.output).stem}_points_{obs.name}.tsv" for obs in observations}
    tables = {name: str(out_dir / file) for name, file in names.items()}
    calib.extra["source"] = str(args.source)
    # the points tables and the calibration, all or none; the calibration moved in last
    with atomic_files(out_dir, [*names.values(), Path(args.output).name]) as tmp:
        for obs in observations:
            extra = None if obs.grid is None else {"grid_row": obs.grid[:, 0],
                                                     "grid_col": obs.grid[:, 1]}
            write_points(tmp / names[obs.name], PointsTable.from_arrays(
                obs.xyz_world, obs.xy_camera, obs.xy_projector, extra=extra))
        save_calibration(tmp / Path(args.output).name, calib)
    if args.json:
        print(dumps_json({"output": str(args.output), "model": args.model, "cameras": summary,
                          "points_tables": tables,
                          "projector_distortion": calib.to_dict()["projector_distortion"]},
                         indent=2))
    else:
        for name, s in summary.items():
            print(f"{name}: {s['points']} marks, " + ", ".join(
                f"{k} {np.round(v, 4).tolist()}" for k, v in s.items() if k != "points"))
        if calib.projector_distortion:
            d = calib.projector_distortion
            print(f"projector distortion: centre {np.round(d.center, 2).tolist()} px, "
                  f"rho {d.rho:.6f}")
        print(f"wrote {args.output} and {len(tables)} points tables")
    return 0
