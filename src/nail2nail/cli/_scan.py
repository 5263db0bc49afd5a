"""``nail2nail scan``: a capture and a calibration to per-camera 3D scans (mat5, PLY, npz)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from nail2nail.calibration.files import load_calibration
from nail2nail.cli._options import as_option_error as _as_option_error
from nail2nail.frames import frame_transform
from nail2nail.io._json import dumps_json
from nail2nail.io.capture import read_capture
from nail2nail.io.masks import parse_mask_option
from nail2nail.io.scans import save_scans
from nail2nail.scan.capture import MAX_GRADIENT, scan_capture
from nail2nail.scan.inputs import (
    ERODE,
    MAX_ERODE,
    MIN_ALBEDO,
    MIN_MODULATION,
    SATURATION,
    UNWRAP_TOLERANCE,
)

__all__ = ["add_parser", "add_scan_options", "decode_options", "max_gradient", "run"]


def add_scan_options(p) -> None:
    """The scanning options of ``scan`` and ``process`` (one definition for both)."""
    p.add_argument("--use", choices=["xpyp", "yp", "xp"], default="xpyp",
                   help="projector coordinates for triangulation (default: both)")
    g = p.add_argument_group(
        "decoder thresholds",
        "Per-pixel validity checks of the decoder (nail2nail.scan.decoding.decode). "
        "Intensities are fractions of the frames' full scale (255 for 8-bit, 2**bits - 1 for "
        "deeper frames), so the same values hold at every bit depth.")
    g.add_argument("--min-modulation", type=float, default=MIN_MODULATION,
                   help="smallest accepted fringe amplitude B of the phase frequencies, fraction "
                   "of full scale (default 0.03 = 7.7 grey levels of 8-bit amplitude; the phase "
                   "noise is sqrt(2/N) * noise / B for N steps)")
    g.add_argument("--cue-modulation", type=float, default=None,
                   help="smallest accepted amplitude of the coarser frequencies that only unwrap "
                   "(e.g. a 1-period cue) and of Gray-code bits' contrast, fraction of full "
                   "scale (default: --min-modulation)")
    g.add_argument("--min-albedo", type=float, default=MIN_ALBEDO,
                   help="smallest accepted mean intensity over all frames, fraction of full "
                   "scale: darker pixels are shadow (default 0.02)")
    g.add_argument("--saturation", type=float, default=SATURATION,
                   help="a pixel is saturated when any frame reaches this fraction of full "
                   "scale (default 254.5/255: the top grey level)")
    g.add_argument("--unwrap-tolerance", type=float, default=UNWRAP_TOLERANCE / (2 * math.pi),
                   metavar="PERIODS",
                   help="largest accepted disagreement between a frequency and the coarser one "
                   "that unwraps it, in periods of the finer fringe (default 0.25 = pi/2 rad)")
    g.add_argument("--erode", type=int, default=ERODE, metavar="PX",
                   help="drop valid pixels within this many camera pixels of an invalid one "
                   "(blur mixes their signal with the neighbour's; default 1, 0 keeps them; at "
                   f"most {MAX_ERODE}, which empties the smallest camera accepted)")
    g.add_argument("--mask", action="append", default=[], metavar="CAMERA=IMAGE",
                   help="a validity mask for one camera (an image of its size, non-zero = keep), "
                   "applied after decoding; repeat for several cameras")
    p.add_argument("--max-gradient", type=float, default=MAX_GRADIENT,
                   help="drop steep pixels (grazing view): those whose projector coordinates "
                   "change faster than this many projector px per camera px of a 1024 x 1280 "
                   "camera, scaled by sqrt(1024*1280 / (W*H)) for W x H cameras, so that it "
                   "limits the viewing obliquity at any resolution (default 2; 'inf' keeps all)")
    p.add_argument("--max-motion", type=float, default=None, metavar="MM",
                   help="refuse the capture (exit 2, nothing written) when its frames show the "
                   "finger moving by more than MM mm (the spread of the frame groups' "
                   "registration, docs/motion.md); by default a warning above 0.02 mm")
    p.add_argument("--compensate-motion", action="store_true",
                   help="correct a moving finger's frames before decoding: the phase offsets "
                   "between the steps of each phase-shift group of 4 or more steps, then the "
                   "coarser frequencies registered to the finest so that unwrapping holds "
                   "(docs/motion.md)")
    p.add_argument("--stabilise-motion", action="store_true",
                   help="resample a moving finger's frames so that every pixel shows one point "
                   "of skin at the time of one finest group (its motion measured from the "
                   "skin's texture), then compensate as --compensate-motion does; the points "
                   "are triangulated from that group's direction: --use xp or yp chooses it, "
                   "by default the finest group shown last (yp for the default patterns; "
                   "docs/motion.md)")
    p.add_argument("--frame", default="world", metavar="world|CAMERA",
                   help="frame of the points written (scans, super scan): 'world' (the "
                   "calibration's, default) or a camera's name, x_cam = R x_world + t of that "
                   "camera (a DLT camera's pose by RQ decomposition); recorded with its 4x4 "
                   "transform T_frame_world, from which merge and unroll map the points back")
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


#: The library's words for the options :func:`nail2nail.process.process_capture` and
#: :func:`nail2nail.scan.capture.scan_capture` check themselves
#: (``frame: expected …``, ``masks: masks given for unknown camera(s) …``), and the command
#: line's (``--frame: expected …``).
LIBRARY_NAMES = {"frame": "--frame", "masks": "--mask", "method": "--method", "ppi": "--ppi",
                 "length_mm": "--length"}


def as_option_error(exc: ValueError) -> ValueError:
    """`exc` naming the command line's option (:data:`LIBRARY_NAMES`) instead of the
    library's argument."""
    return _as_option_error(exc, LIBRARY_NAMES)


def run(args: argparse.Namespace) -> int:
    options = decode_options(args)
    user_masks = masks(args)
    calibration = load_calibration(args.calib, allow_mirrored=args.allow_mirrored)
    try:
        transform = frame_transform(calibration, args.frame)  # before the capture is read
    except ValueError as exc:
        raise as_option_error(exc) from None
    # frames are read (and checked) one camera at a time, while scanning: memory for one
    # camera's frames; the progress bar only on a terminal and without --quiet
    # (nail2nail._progress), so that an error read from a file or pipe is its one line.
    # Warnings (the kept fraction of a camera's lit pixels) become one line each in cli.main.
    capture = read_capture(args.capture, load=False)
    try:
        scans = scan_capture(capture, calibration, use=args.use,
                             progress=True,
                             max_gradient=max_gradient(args), allow_mirrored=args.allow_mirrored,
                             calibration_name=str(args.calib), masks=user_masks, **options)
    except ValueError as exc:
        raise as_option_error(exc) from None
    manifest = save_scans(args.out, scans, mat5=not args.no_mat5, ply=not args.no_ply,
                          extra={"capture": str(args.capture), "calibration": str(args.calib)},
                          frame=args.frame, transform=transform)
    summary: dict[str, Any] = {"out": str(args.out), "cameras": {}}
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


def decode_options(args: argparse.Namespace) -> dict:
    """The decoder thresholds of ``add_scan_options`` as :func:`nail2nail.scan.decoding.decode`
    takes
    them (``--unwrap-tolerance`` in periods becomes radians), checked."""
    import math

    for name in ("min_modulation", "min_albedo", "saturation", "unwrap_tolerance"):
        value = getattr(args, name)
        if not math.isfinite(value) or value < 0:
            raise ValueError(f"--{name.replace('_', '-')}: expected a finite number >= 0, "
                             f"got {value}")
    if args.cue_modulation is not None and not (math.isfinite(args.cue_modulation)
                                                and args.cue_modulation >= 0):
        raise ValueError(f"--cue-modulation: expected a finite number >= 0, got "
                         f"{args.cue_modulation}")
    if not 0 < args.saturation <= 1:
        raise ValueError(f"--saturation: expected a fraction of full scale in (0, 1], got "
                         f"{args.saturation}")
    if not 0 < args.unwrap_tolerance < 0.5:
        raise ValueError(f"--unwrap-tolerance: expected periods in (0, 0.5), got "
                         f"{args.unwrap_tolerance}")
    if not 0 <= args.erode <= MAX_ERODE:
        raise ValueError(f"--erode: expected a number of pixels in 0..{MAX_ERODE}, got "
                         f"{args.erode}")
    if not args.max_gradient > 0:  # NaN too; checked as given, before any scaling
        raise ValueError(f"--max-gradient: expected a positive number of projector px per "
                         f"camera px ('inf' keeps all), got {args.max_gradient:g}")
    if args.max_motion is not None and not (math.isfinite(args.max_motion)
                                            and args.max_motion > 0):
        raise ValueError(f"--max-motion: expected a positive number of mm, got "
                         f"{args.max_motion}")
    return {"min_modulation": args.min_modulation, "cue_modulation": args.cue_modulation,
            "min_albedo": args.min_albedo,
            "saturation": args.saturation, "unwrap_tolerance": 2 * math.pi * args.unwrap_tolerance,
            "erode": args.erode, "max_motion_mm": args.max_motion,
            "compensate_motion": args.compensate_motion,
            "stabilise_motion": args.stabilise_motion}


def masks(args: argparse.Namespace) -> dict[str, str]:
    """``--mask CAMERA=IMAGE`` entries as ``{camera: path}``, the files checked to exist."""

    out = parse_mask_option(args.mask)
    for name, path in out.items():
        if not Path(path).is_file():
            raise ValueError(f"--mask: {path}: no such file (mask of camera {name!r})")
    return out


def max_gradient(args: argparse.Namespace) -> float | None:
    """``--max-gradient`` as the library takes it (``inf``: no limit, ``None``)."""
    return None if args.max_gradient == float("inf") else args.max_gradient
