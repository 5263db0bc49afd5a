"""``nail2nail scan``: a capture and a calibration to per-camera 3D scans (mat5, PLY, npz)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..io._json import dumps_json
from ..io.calibration import load_calibration
from ..io.capture import read_capture
from ..io.scans import save_scans
from ..scanning import scan_capture

__all__ = ["add_parser", "add_scan_options", "max_gradient", "run"]


def add_scan_options(p) -> None:
    """The scanning options of ``scan`` and ``process`` (one definition for both)."""
    p.add_argument("--use", choices=["xpyp", "yp", "xp"], default="xpyp",
                   help="projector coordinates for triangulation (default: both)")
    p.add_argument("--min-modulation", type=float, default=0.03,
                   help="smallest accepted fringe amplitude, fraction of full scale")
    p.add_argument("--max-gradient", type=float, default=2.0,
                   help="drop steep pixels (grazing view): those whose projector coordinates "
                   "change faster than this many projector px per camera px of a 1024 x 1280 "
                   "camera, scaled by sqrt(1024*1280 / (W*H)) for W x H cameras, so that it "
                   "limits the viewing obliquity at any resolution (default 2; 'inf' keeps all)")
    p.add_argument("--allow-mirrored", action="store_true",
                   help="accept a calibration with a mirrored camera (a flipped image or a "
                   "left-handed pose; refused by default: its scans are mirrored)")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "scan",
        help="decode a capture and reconstruct each camera's 3D scan",
        description="Decode every camera of CAPTURE_DIR, reconstruct X, Y, Z per pixel with the "
        "calibration, and write per camera the legacy mat5 set, a binary PLY and an .npz, plus "
        "OUT/scan.json.",
    )
    p.add_argument("capture", type=Path, help="capture directory (capture.json)")
    p.add_argument("--calib", type=Path, required=True, help="calibration JSON")
    p.add_argument("--out", type=Path, required=True, help="output directory")
    add_scan_options(p)
    p.add_argument("--no-mat5", action="store_true", help="skip the legacy mat5 files")
    p.add_argument("--no-ply", action="store_true", help="skip the PLY point clouds")
    p.add_argument("--json", action="store_true", help="print a machine-readable summary")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    calibration = load_calibration(args.calib, allow_mirrored=args.allow_mirrored)
    # frames are read (and checked) one camera at a time, while scanning: memory for one
    # camera's frames; the progress bar only on a terminal, so that an error read from a file
    # or pipe is its one line. Warnings (the kept fraction of a camera's lit pixels) become one
    # line each in cli.main.
    capture = read_capture(args.capture, load=False)
    scans = scan_capture(capture, calibration, use=args.use,
                         progress=not args.json and sys.stderr.isatty(),
                         min_modulation=args.min_modulation,
                         max_gradient=max_gradient(args), allow_mirrored=args.allow_mirrored,
                         calibration_name=str(args.calib))
    manifest = save_scans(args.out, scans, mat5=not args.no_mat5, ply=not args.no_ply,
                          extra={"capture": str(args.capture), "calibration": str(args.calib)})
    summary = {"out": str(args.out), "cameras": {}}
    for cam in manifest["cameras"]:
        files = {k: str(args.out / v) for k, v in cam.items() if k in ("npz", "ply")}
        if "mat5" in cam:
            files["mat5"] = str(args.out / cam["mat5"])
        summary["cameras"][cam["name"]] = {"valid_pixels": cam["valid_pixels"], **files}
    if args.json:
        print(dumps_json(summary))
    else:
        for name, s in summary["cameras"].items():
            print(f"{name}: {s['valid_pixels']} valid pixels -> {s.get('mat5', s['npz'])}")
        print(f"wrote {args.out / 'scan.json'}")
    return 0


def max_gradient(args: argparse.Namespace) -> float | None:
    """``--max-gradient`` as the library takes it (``inf``: no limit, ``None``)."""
    return None if args.max_gradient == float("inf") else args.max_gradient
