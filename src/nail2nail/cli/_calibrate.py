"""``nail2nail calibrate``: DLT calibration from a points table (or from a target capture)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from nail2nail.calibration.dlt import calibrate_points
from nail2nail.calibration.files import (
    CameraCalibration,
    RigCalibration,
    check_handedness,
    save_calibration,
)
from nail2nail.cli._calibrate_capture import run_capture
from nail2nail.io._atomic import check_output_file
from nail2nail.io._json import dumps_json
from nail2nail.io.points import read_points

__all__ = ["add_parser", "format_table", "report_dict", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "calibrate",
        help="fit camera and projector matrices (eq. 3.1-3.11)",
        description="Fit DLT matrices from a points table (Xw Yw Zw xc yc xp yp) or from a "
        "capture of the calibration target, write a calibration JSON and print the per-point "
        "reconstruction errors (thesis Tables 2 and 3).",
    )
    p.add_argument("source", type=Path,
                   help="points table (.tsv/.csv) or capture directory; a directory with "
                   "projectors.json (one target capture per projector) calibrates every "
                   "projector with the cameras (--model joint), writing OUT_<capture>.json "
                   "per projector")
    p.add_argument("-o", "--output", type=Path, help="calibration JSON to write")
    p.add_argument(
        "--use",
        choices=["yp", "xpyp"],
        default="yp",
        help="projector coordinate(s) for reconstruction (default: yp, as the thesis)",
    )
    p.add_argument(
        "--method",
        choices=["thesis", "normalized"],
        default="thesis",
        help="least-squares estimator (default: thesis eq. 3.11)",
    )
    p.add_argument("--model", choices=["dlt", "joint"], default="dlt",
                   help="capture only: per-camera DLT (thesis) or joint pinhole calibration "
                   "with one shared, distorted projector (default: dlt)")
    p.add_argument("--mark-diameter-px", type=float, metavar="PX",
                   help="capture only: approximate image diameter of a plain 1.2 mm mark, px "
                   "(default: from the nominal rig in capture.json; required without one)")
    p.add_argument("--allow-mirrored", action="store_true",
                   help="accept a mirrored camera (a flipped image or a left-handed pose; "
                   "refused by default: its scans would be mirrored)")
    p.add_argument("--json", action="store_true", help="print machine-readable results")
    p.set_defaults(func=run)


def report_dict(report, labels) -> dict:
    """JSON summary of a :class:`~nail2nail.calibration.dlt.CalibrationReport`."""
    return {
        "method": report.method,
        "use": report.use,
        "camera_matrix": report.camera_matrix.tolist(),
        "projector_matrix": report.projector_matrix.tolist(),
        "points": [
            {
                "point": label,
                "error_mm": err.round(6).tolist(),
                "camera_residual_px": res.round(6).tolist(),
            }
            for label, err, res in zip(
                labels, report.error_mm, report.camera_residual_px, strict=True
            )
        ],
        "rms_mm": report.rms_mm.round(6).tolist(),
        "camera_rms_px": float(np.sqrt(np.mean(report.camera_residual_px**2))),
    }


def format_table(report, table) -> str:
    """The per-point error table, laid out like the thesis's Tables 2 and 3."""
    head = (
        f"{'point':>5} {'Xw':>9} {'Yw':>9} {'Zw':>9} {'xc':>10} {'yc':>10} "
        f"{'err_Xw':>8} {'err_Yw':>8} {'err_Zw':>8} {'reproj_px':>9}"
    )
    lines = [head, "-" * len(head)]
    xyz, xy = table.xyz_world, table.xy_camera
    for i, label in enumerate(table.labels):
        e = report.error_mm[i]
        r = np.linalg.norm(report.camera_residual_px[i])
        lines.append(
            f"{label:>5} {xyz[i, 0]:9.4f} {xyz[i, 1]:9.4f} {xyz[i, 2]:9.4f} "
            f"{xy[i, 0]:10.3f} {xy[i, 1]:10.3f} {e[0]:8.3f} {e[1]:8.3f} {e[2]:8.3f} "
            f"{r:9.3f}"
        )
    rms = report.rms_mm
    lines.append("-" * len(head))
    lines.append(
        f"RMS error (mm): X {rms[0]:.4f}  Y {rms[1]:.4f}  Z {rms[2]:.4f}   "
        f"(method {report.method}, reconstruction from {report.use})"
    )
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    if args.mark_diameter_px is not None and not args.mark_diameter_px > 2:
        raise ValueError(f"--mark-diameter-px: expected a diameter > 2 px, got "
                         f"{args.mark_diameter_px:g}")
    if args.output is not None:  # before anything is read or written (a capture's tables)
        try:
            check_output_file(args.output)
        except ValueError as exc:  # OutputRefusedError kept
            raise type(exc)(f"-o/--output: {exc}") from exc
    if args.source.is_dir():
        return run_capture(args)
    table = read_points(args.source)
    results = {}
    for method in ("thesis", "normalized"):
        try:
            results[method] = calibrate_points(
                table.xyz_world, table.xy_camera, table.xy_projector, method=method, use=args.use
            )
        except (ValueError, TypeError) as exc:  # the table's points: say which table
            raise ValueError(f"{args.source}: {exc}") from exc
    report = results[args.method]
    calib = RigCalibration(
        cameras=[
            CameraCalibration(args.source.stem, report.camera_matrix, report.projector_matrix)
        ],
        extra={"source": str(args.source), "method": args.method},
    )
    if not args.allow_mirrored:  # depth sign taken at the table's points
        check_handedness(calib, str(args.source), scene_point=table.xyz_world.mean(axis=0))
    if args.output:
        try:
            save_calibration(args.output, calib)
        except OSError as exc:  # named by the user's path, not the temporary file beside it
            raise ValueError(f"-o/--output: {args.output}: cannot write "
                             f"({exc.strerror or exc})") from exc
    if args.json:
        out = report_dict(report, table.labels)
        out["compare"] = {m: {"rms_mm": r.rms_mm.round(6).tolist()} for m, r in results.items()}
        if args.output:
            out["output"] = str(args.output)
        print(dumps_json(out))
    else:
        print(f"Calibration of {args.source} ({len(table)} points)\n")
        print(format_table(report, table))
        other = "normalized" if args.method == "thesis" else "thesis"
        rms = results[other].rms_mm
        print(f"Compare, method {other}: RMS X {rms[0]:.4f}  Y {rms[1]:.4f}  Z {rms[2]:.4f} mm")
        if args.output:
            print(f"wrote {args.output}")
    return 0
