"""``nail2nail import-calibration`` and ``nail2nail export-calibration``: OpenCV calibrations.

Thin command layer over :mod:`nail2nail.calibration.opencv_files` (``cv2.FileStorage`` XML and
YAML files in the SLStudio, OpenCV ``stereo_calib`` or nail2nail multi-camera layout) and the
rig calibration JSON of :mod:`nail2nail.calibration.files`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from nail2nail.calibration.files import (
    MAX_INTRINSIC_PX,
    MAX_SIZE_PX,
    MAX_TRANSLATION_MM,
    load_calibration,
    save_calibration,
)
from nail2nail.calibration.opencv_files import (
    LAYOUTS,
    MAX_FILE_BYTES,
    MAX_MATRIX_ELEMENTS,
    MAX_NESTING,
    read_opencv_calibration,
    write_opencv_calibration,
)
from nail2nail.cli._options import as_option_error
from nail2nail.io._atomic import check_output_file
from nail2nail.io._json import dumps_json

__all__ = ["add_parser", "run_export", "run_import"]


def _size(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if not 0 < value <= MAX_SIZE_PX:
        raise argparse.ArgumentTypeError(f"expected an integer in 1 … {MAX_SIZE_PX} px, got "
                                         f"{text!r}")
    return value


#: The limits of a file read and of its values, said in the help.
LIMITS = (f"Files are checked before OpenCV parses them: regular files of at most "
          f"{MAX_FILE_BYTES // 2**20} MiB, nested at most {MAX_NESTING} levels, matrices of at "
          f"most {MAX_MATRIX_ELEMENTS:,} numbers, integers within 32 bits; values: image and "
          f"panel sizes integers in 1 … {MAX_SIZE_PX} px, |fx|, |fy|, |cx|, |cy|, |skew| at "
          f"most {MAX_INTRINSIC_PX:g} px, |t| below {MAX_TRANSLATION_MM:g} mm.")


def _check_out(path: Path) -> None:
    """Refuse `--out` naming a directory (or under a file) before anything is read."""
    try:
        check_output_file(path)
    except ValueError as exc:  # OutputRefusedError kept
        raise type(exc)(f"--out: {exc}") from exc


def _write_error(option: str, path: Path, exc: OSError) -> ValueError:
    """A write failure named by the user's path (the temporary file beside it is not)."""
    return ValueError(f"{option}: {path}: cannot write ({exc.strerror or exc})")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "import-calibration",
        help="read an OpenCV calibration (SLStudio, stereo_calib, nail2nail layout) into a "
        "rig calibration JSON",
        description="Read a calibration written with OpenCV's FileStorage (XML or YAML) and "
        "write the rig calibration JSON that scan and process take. Layouts: SLStudio (Kc kc "
        "Kp kp Rp Tp frameWidth frameHeight screenResX screenResY: one camera and the "
        "projector, x_proj = Rp x_cam + Tp, mm), OpenCV's stereo_calib (M1 D1 M2 D2 R T, the "
        "projector as the second device; both of its files may be given) and nail2nail's "
        "multi-camera layout. For the one-camera layouts the world frame is the camera's, "
        "named cam0. Rotations stored as float32 are re-orthonormalised (a warning). "
        + LIMITS,
    )
    p.add_argument("files", type=Path, nargs="+", metavar="FILE",
                   help="the calibration file(s) (keys of several files are joined)")
    p.add_argument("--format", choices=["opencv"], default="opencv",
                   help="file format (OpenCV FileStorage; the only one so far)")
    p.add_argument("--layout", choices=["auto", *LAYOUTS], default="auto",
                   help="keys of the file (default: recognised from them)")
    p.add_argument("--camera-size", type=_size, nargs=2, metavar=("W", "H"),
                   help=f"camera image size in pixels (1 … {MAX_SIZE_PX}), where the file "
                   "holds none")
    p.add_argument("--projector-size", type=_size, nargs=2, metavar=("W", "H"),
                   help=f"projector panel size in pixels (1 … {MAX_SIZE_PX}), where the file "
                   "holds none")
    p.add_argument("--allow-mirrored", action="store_true",
                   help="accept a mirrored camera or projector (refused by default)")
    p.add_argument("-o", "--out", type=Path, required=True, help="rig calibration JSON to write")
    p.add_argument("--json", action="store_true", help="print a machine-readable summary")
    p.set_defaults(func=run_import)

    p = sub.add_parser(
        "export-calibration",
        help="write a rig calibration JSON as an OpenCV FileStorage file",
        description="Write a rig calibration (JSON) as an OpenCV FileStorage file (.xml, .yml, "
        ".yaml) in the nail2nail multi-camera layout (default), SLStudio's or stereo_calib's "
        "(one camera, in its own frame). DLT matrices are decomposed into K, R, t "
        "(pinhole_from_dlt; a warning); a projector radial distortion (the thesis's centre "
        "and rho) has no OpenCV form and is refused. The values import-calibration refuses "
        f"are refused here too (sizes 1 … {MAX_SIZE_PX} px, |fx|, |fy|, |cx|, |cy|, |skew| at "
        f"most {MAX_INTRINSIC_PX:g} px, |t| below {MAX_TRANSLATION_MM:g} mm).",
    )
    p.add_argument("calibration", type=Path, help="rig calibration JSON")
    p.add_argument("-o", "--out", type=Path, required=True,
                   help="file to write: .xml, .yml or .yaml")
    p.add_argument("--layout", choices=list(LAYOUTS), default="nail2nail",
                   help="keys to write (default: nail2nail, every camera)")
    p.add_argument("--camera", default=None,
                   help="the camera of the slstudio and stereo layouts (needed for a rig of "
                   "several cameras)")
    p.add_argument("--projector-size", type=_size, nargs=2, metavar=("W", "H"),
                   help=f"panel size of a DLT projector (default 1280 x 1040; 1 … {MAX_SIZE_PX} "
                   "px)")
    p.add_argument("--allow-mirrored", action="store_true",
                   help="accept a mirrored camera or projector (refused by default)")
    p.add_argument("--json", action="store_true", help="print a machine-readable summary")
    p.set_defaults(func=run_export)


def _summary(calibration) -> dict:
    return {c.name: {"size": list(c.size) if c.size else None} for c in calibration.cameras}


def run_import(args: argparse.Namespace) -> int:
    if args.out.suffix.lower() != ".json":
        raise ValueError(f"--out: {args.out}: expected a .json file name (the rig "
                         "calibration)")
    _check_out(args.out)
    calibration = read_opencv_calibration(
        args.files, layout=args.layout, camera_size=args.camera_size,
        projector_size=args.projector_size, allow_mirrored=args.allow_mirrored)
    try:
        save_calibration(args.out, calibration)
    except OSError as exc:
        raise _write_error("--out", args.out, exc) from exc
    summary = {"out": str(args.out), "layout": calibration.extra.get("source_layout"),
               "world_frame": calibration.extra.get("world_frame", "as stored"),
               "cameras": _summary(calibration)}
    if args.json:
        print(dumps_json(summary))
        return 0
    cams = ", ".join(f"{name} ({v['size'][0]} x {v['size'][1]} px)"
                     for name, v in summary["cameras"].items())
    print(f"{summary['layout']} layout: {cams}; world frame {summary['world_frame']}")
    print(f"wrote {args.out}")
    return 0


#: The writer's argument names in its messages, and the command line's options (the
#: calibration itself is named by its file); a one-camera layout without ``--camera`` is named
#: as given (:func:`run_export`)
EXPORT_OPTIONS = {"camera": "--camera"}


def run_export(args: argparse.Namespace) -> int:
    if args.out.suffix.lower() not in (".xml", ".yml", ".yaml", ".json"):
        raise ValueError(f"--out: {args.out}: expected a .xml, .yml or .yaml file name (the "
                         "suffix picks the FileStorage format)")
    _check_out(args.out)
    calibration = load_calibration(args.calibration, allow_mirrored=args.allow_mirrored)
    try:
        notes = write_opencv_calibration(args.out, calibration, layout=args.layout,
                                         camera=args.camera, projector_size=args.projector_size)
    except ValueError as exc:  # the writer's checks name its arguments
        one_camera = f"layout {args.layout!r} holds one camera"
        raise as_option_error(exc, {**EXPORT_OPTIONS, "calibration": str(args.calibration),
                                    one_camera: f"--layout {args.layout} holds one camera "
                                                "(give --camera)"}) from None
    if args.json:
        print(dumps_json({"out": str(args.out), "layout": args.layout, "notes": notes,
                          "cameras": _summary(calibration)}))
        return 0
    print(f"wrote {args.out} ({args.layout} layout)")
    return 0
