"""``nail2nail unroll``: per-camera scans of a finger to a rolled-equivalent print.

Thin command layer: reads the scan directories (:func:`nail2nail.io.scans.load_scan_dirs`),
calls :func:`nail2nail.unroll.unroll_scans` and writes the print with
:func:`nail2nail.io.rolled.write_rolled_print`.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

from nail2nail._progress import Stages
from nail2nail.io._json import dumps_json
from nail2nail.io.rolled import write_rolled_print
from nail2nail.io.scans import load_scan_dirs
from nail2nail.unroll import (
    DEFAULT_LENGTH_MM,
    DEFAULT_METHOD,
    MAX_LENGTH_MM,
    MAX_PPI,
    MAX_SHARPEN,
    METHODS,
    MIN_CLARITY,
    MIN_LENGTH_MM,
    MIN_PPI,
    SHARPEN,
    unroll_scans,
)

__all__ = ["add_parser", "add_unroll_options", "check_unroll_options", "run", "unroll_options"]


class _Number(float):
    """A float that keeps the text the user gave, for the error messages."""

    text = ""


class _Triple(tuple):
    """Three floats that keep the text the user gave, for the error messages."""

    text = ""


def _number(text: str) -> float:
    value = _Number(text)  # ValueError: argparse's "invalid float value"
    value.text = text
    return value


_number.__name__ = "float"  # argparse names the type in its message


def _vector(text: str) -> tuple[float, float, float]:
    try:
        values = _Triple(float(v) for v in text.split(","))
    except ValueError:
        values = _Triple()
    if len(values) != 3:
        raise argparse.ArgumentTypeError(
            f"expected three finite numbers X,Y,Z (not all 0), got {text!r}")
    values.text = text
    return values  # finite and not zero: check_unroll_options


def _given(value) -> str:
    """`value` as the user gave it (its text), else as Python writes it."""
    return getattr(value, "text", "") or (f"{value:g}" if isinstance(value, float)
                                          else ",".join(f"{v:g}" for v in value))


def add_unroll_options(p) -> None:
    """The unrolling options of ``unroll`` and ``process`` (one definition for both)."""
    p.add_argument("--method", choices=METHODS, default=DEFAULT_METHOD,
                   help=f"flattening (default: {DEFAULT_METHOD}, the least distortion; "
                   "docs/unroll.md)")
    p.add_argument("--ppi", type=_number, default=500.0,
                   help=f"resolution, pixels per inch, {MIN_PPI:g} to {MAX_PPI:g} (default 500; "
                   "other values write JPEG 2000 instead of WSQ)")
    p.add_argument("--tip-direction", type=_vector, default=None,
                   help="rough direction of the fingertip in the scans' frame, X,Y,Z: three "
                   "finite numbers, not all 0 (default: up in the cameras' images, measured on "
                   "the scans, whatever the frame: give it when the fingertip does not point to "
                   "the top of the images)")
    length = p.add_mutually_exclusive_group()
    length.add_argument("--length", type=_number, default=DEFAULT_LENGTH_MM, metavar="MM",
                        help="keep only the skin within MM below the fingertip, as an inked "
                        f"roll does, {MIN_LENGTH_MM:g} to {MAX_LENGTH_MM:g} mm (default "
                        f"{DEFAULT_LENGTH_MM:g}: the distal crease of an adult finger)")
    length.add_argument("--full-length", dest="length", action="store_const", const=None,
                        help="keep all the skin the cameras saw below the tip")
    p.add_argument("--min-clarity", type=float, default=MIN_CLARITY, metavar="Q",
                   help="leave out of the print the skin whose ridge clarity (3.2 mm blocks, 0-1) "
                   f"is below Q: no ridges there to print (default {MIN_CLARITY}; 0 keeps all)")
    p.add_argument("--fixed-blend", action="store_true",
                   help="the ridge signal of earlier versions: relief + 0.3 x albedo, no RMS "
                   "floor (default: relief and albedo weighed by their measured clarity)")
    p.add_argument("--no-fringe-fit", action="store_true",
                   help="keep the scanner's phase-locked error (a periodic function of the "
                   "decoded fringe phase) in the ridge signal (default: fitted per camera and "
                   "taken out, docs/unroll.md)")
    p.add_argument("--deshade", action="store_true",
                   help="take the shading of the ridges' own slopes out of the albedo (fitted "
                   "against the relief) before mixing it in: ridges closer to the skin's, no "
                   "matcher gain measured (docs/unroll.md; default: the albedo as seen)")
    p.add_argument("--sharpen", type=_number, default=SHARPEN, metavar="AMOUNT",
                   help="unsharp mask that gives the grey print back the ridges' edges the "
                   f"scanner's optics blurred, 0 to {MAX_SHARPEN:g} (default {SHARPEN:g}; "
                   "0: none; "
                   "docs/unroll.md)")


def check_unroll_options(args: argparse.Namespace) -> None:
    """Refuse a bad ``--ppi``, ``--length``, ``--tip-direction`` or ``--min-clarity`` before
    anything is read (exit 2)."""
    if not MIN_PPI <= args.ppi <= MAX_PPI:
        raise ValueError(f"--ppi: expected {MIN_PPI:g} to {MAX_PPI:g} pixels per inch, got "
                         f"{_given(args.ppi)}")
    if args.length is not None and not MIN_LENGTH_MM <= args.length <= MAX_LENGTH_MM:
        raise ValueError(f"--length: expected {MIN_LENGTH_MM:g} to {MAX_LENGTH_MM:g} mm "
                         f"(--full-length keeps all the skin), got {_given(args.length)}")
    tip = args.tip_direction
    if tip is not None and not (all(math.isfinite(v) for v in tip) and any(tip)):
        raise ValueError("--tip-direction: expected three finite numbers X,Y,Z (not all 0), "
                         f"got {_given(tip)}")
    if not 0 <= args.sharpen <= MAX_SHARPEN:
        raise ValueError(f"--sharpen: expected an amount from 0 to {MAX_SHARPEN:g}, got "
                         f"{_given(args.sharpen)}")
    if not 0 <= args.min_clarity < 1:
        raise ValueError(f"--min-clarity: expected a clarity in [0, 1), got {args.min_clarity}")


def unroll_options(args: argparse.Namespace) -> dict:
    """The ridge-signal keyword arguments of :func:`nail2nail.unroll.unroll_scans`."""
    options = {"mix": not args.fixed_blend,
               "min_clarity": args.min_clarity if args.min_clarity > 0 else None,
               "sharpen": float(args.sharpen)}
    if args.deshade:
        options["deshade"] = True
    if args.no_fringe_fit:
        options["ridge_options"] = {"fringe_harmonics": 0}
    return options


def add_parser(sub) -> None:
    p = sub.add_parser(
        "unroll",
        help="unroll the scanned finger into a rolled-equivalent 2D print (PNG, WSQ)",
        description="Measure the ridges on every camera's scan (relief along the normal plus "
        "albedo), flatten the finger into the print plane, blend the cameras across their "
        "overlaps and write a 500-ppi print in the legacy convention (the image an inked roll "
        "gives: mirror of the pad seen from outside, fingertip up, ridges dark): print.png, "
        "print.wsq, print_binary.png, print_mask.png, print_coverage.png, print_quality.png "
        "and print.json.",
    )
    p.add_argument("scan_dir", type=Path, nargs="+",
                   help="scan directory written by `nail2nail scan`; with a rig of several "
                   "projectors, one per projector (every camera's scan of every projector is "
                   "blended)")
    p.add_argument("--out", type=Path, required=True, help="output directory")
    add_unroll_options(p)
    p.add_argument("--no-wsq", action="store_true", help="skip the compressed print")
    p.add_argument("--json", action="store_true", help="print the metadata as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:

    check_unroll_options(args)
    step = Stages(3, prefix="unroll: ")  # stderr, a terminal only, not with --quiet
    step("read the scans")
    scans, _, _ = load_scan_dirs(args.scan_dir)
    start = time.perf_counter()
    step(f"unroll ({args.method})")
    rolled = unroll_scans(scans, method=args.method, ppi=args.ppi,
                          tip_direction=args.tip_direction, length_mm=args.length,
                          **unroll_options(args))
    step("write the print")
    meta = write_rolled_print(args.out, rolled, wsq=not args.no_wsq,
                              extra={"scan_dir": (str(args.scan_dir[0])
                                                  if len(args.scan_dir) == 1
                                                  else [str(d) for d in args.scan_dir]),
                                     "seconds": round(time.perf_counter() - start, 3)})
    if args.json:
        print(dumps_json(meta))
        return 0
    w, h = meta["print_size_mm"]
    d = meta["distortion"]
    print(f"{args.method} unroll: {meta['shape'][1]} x {meta['shape'][0]} px at "
          f"{meta['ppi']:g} ppi ({w} x {h} mm, {meta['print_area_mm2']} mm² with data)")
    print(f"length distortion p95 {100 * d['length']['p95']:.1f} %, area p95 "
          f"{100 * d['area']['p95']:.1f} %; ridge clarity median "
          f"{meta['quality']['clarity_median']}")
    print(f"wrote {Path(args.out) / meta['files']['print']} and {Path(args.out) / 'print.json'}")
    return 0
