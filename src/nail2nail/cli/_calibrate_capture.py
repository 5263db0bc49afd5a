"""``nail2nail calibrate CAPTURE_DIR``: calibration from a capture of the cylindrical target."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from nail2nail._progress import Stages
from nail2nail.calibration.files import check_handedness, save_calibration
from nail2nail.calibration.markers import TargetGeometry
from nail2nail.calibration.observe import projector_target_observations, target_observations
from nail2nail.calibration.target import (
    calibrate_from_observations,
    calibrate_projectors_from_observations,
)
from nail2nail.io._atomic import atomic_files
from nail2nail.io._json import dumps_json
from nail2nail.io.capture import projector_captures, read_capture
from nail2nail.io.points import PointsTable, write_points

__all__ = ["run_capture", "run_projectors"]


def run_capture(args: argparse.Namespace) -> int:
    if args.output is None:
        raise ValueError("calibrate CAPTURE_DIR: give the calibration file to write with -o")
    if (args.source / "projectors.json").is_file():
        return run_projectors(args)
    capture = read_capture(args.source)
    diameter = _mark_diameter(args, capture, args.source)
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
            write_points(tmp / names[obs.name], _points_table(obs))
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


def _mark_diameter(args: argparse.Namespace, capture, source: Path) -> float | None:
    """``--mark-diameter-px``, or None to take it from the capture's nominal rig; refused
    when there is neither."""
    diameter = getattr(args, "mark_diameter_px", None)
    if diameter is None and "rig" not in capture.manifest:
        raise ValueError(
            f"{source / 'capture.json'}: no nominal 'rig', so the marks' size in the images "
            "is unknown: give --mark-diameter-px PX (the image diameter of a 1.2 mm mark, about "
            "focal length in px x 1.2 / distance to the target in mm) or add a nominal 'rig' "
            "(docs/capture-format.md)")
    return diameter


def _points_table(obs) -> PointsTable:
    """A camera's target observations as the points table written beside a calibration (with
    the marks' grid identities where known)."""
    extra = None if obs.grid is None else {"grid_row": obs.grid[:, 0],
                                             "grid_col": obs.grid[:, 1]}
    return PointsTable.from_arrays(obs.xyz_world, obs.xy_camera, obs.xy_projector, extra=extra)


def run_projectors(args: argparse.Namespace) -> int:
    """A target capture of several projectors (``projectors.json``): every projector and the
    cameras in one bundle adjustment; one calibration file per projector (``OUT_<capture>``)."""
    if args.model != "joint":
        raise ValueError(f"{args.source}: a capture of several projectors is calibrated with "
                         "--model joint (the cameras shared by every projector); the DLT "
                         "model calibrates one projector's capture at a time")
    captures = projector_captures(args.source)
    assert captures is not None  # run_capture's test
    output = Path(args.output)
    out_dir = output.parent
    files = {name: f"{output.stem}_{name}{output.suffix or '.json'}" for name, _ in captures}
    opened = [read_capture(path) for _, path in captures]
    diameter = _mark_diameter(args, opened[0], captures[0][1])
    sets = projector_target_observations(opened, progress=True, refine_marks=True,
                                         mark_diameter_px=diameter)
    sizes = [tuple(c.manifest.get("projector", {}).get("size") or (1280, 1040))
             for c in opened]
    Stages(prefix="calibrate: ")(f"fit the joint model of {len(sets)} projectors")
    calibs, summaries = calibrate_projectors_from_observations(
        sets, projector_sizes=sizes, surface=TargetGeometry().signed_distance,
        target=TargetGeometry())
    for (_, path), calib, obs in zip(captures, calibs, sets, strict=True):
        if not args.allow_mirrored:
            check_handedness(calib, str(path),
                             scene_point=np.mean([o.xyz_world.mean(axis=0) for o in obs], 0))
        calib.extra["source"] = str(path)
    tables = {}
    for (name, _), obs in zip(captures, sets, strict=True):
        for o in obs:
            tables[(name, o.name)] = f"{output.stem}_{name}_points_{o.name}.tsv"
    # the points tables and the calibrations, all or none; the calibrations moved in last
    with atomic_files(out_dir, [*tables.values(), *files.values()]) as tmp:
        for (name, _), obs in zip(captures, sets, strict=True):
            for o in obs:
                write_points(tmp / tables[(name, o.name)], _points_table(o))
        for (name, _), calib in zip(captures, calibs, strict=True):
            save_calibration(tmp / files[name], calib)
    if args.json:
        print(dumps_json({
            "outputs": {name: str(out_dir / f) for name, f in files.items()}, "model": "joint",
            "projectors": {name: {"cameras": summary,
                                  "projector_distortion":
                                      calib.to_dict()["projector_distortion"]}
                           for (name, _), summary, calib in zip(captures, summaries, calibs,
                                                                strict=True)},
            "points_tables": {f"{p}/{c}": str(out_dir / f) for (p, c), f in tables.items()}},
            indent=2))
    else:
        for (name, _), summary, calib in zip(captures, summaries, calibs, strict=True):
            for cam, s in summary.items():
                print(f"{name} {cam}: {s['points']} marks, camera rms "
                      f"{s['camera_rms_px']:.4f} px, projector rms "
                      f"{s['projector_rms_px']:.4f} px")
            if calib.projector_distortion:
                d = calib.projector_distortion
                print(f"{name} projector distortion: centre {np.round(d.center, 2).tolist()} px, "
                      f"rho {d.rho:.6f}")
        print(f"wrote {', '.join(str(out_dir / f) for f in files.values())} (the cameras shared) "
              f"and {len(tables)} points tables")
    return 0
