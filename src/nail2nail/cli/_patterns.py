"""``nail2nail patterns``: write the projector's pattern frames (8-bit PNG) and their spec."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from nail2nail.calibration.distortion import apply_lut, distortion_lut, load_projector_distortion
from nail2nail.io._atomic import atomic_directory, atomic_path
from nail2nail.io._json import dumps_json, write_json
from nail2nail.scan.patterns import (
    PatternSet,
    default_pattern_set,
    frame_table,
    gray_code_pattern_set,
    gray_line_pattern_set,
    gray_phase_pattern_set,
    grid_pattern,
    make_patterns,
)

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "patterns",
        help="write structured-light patterns (PMP, Gray code + phase, Gray code) as 8-bit PNG",
        description="Render the frames of a pattern set (JSON spec, or a scheme: by default the "
        "24-frame multi-frequency PMP set, 1, 8 and 64 periods in x and y) as 8-bit PNG files "
        "pattern_000.png … with patterns.json (the spec and the frame table) beside them.",
    )
    p.add_argument("--spec", type=Path, help="pattern set JSON (PatternSet.to_dict format)")
    p.add_argument("--scheme", choices=("pmp", "gray-phase", "gray", "gray-code"), default=None,
                   help="without --spec: 'pmp' (default: multi-frequency phase shifting), "
                   "'gray-phase' (Gray code + phase shifting), 'gray' (Gray code + line "
                   "shifting) or 'gray-code' (the Gray code alone, stripes --stripe px wide)")
    p.add_argument("--stripe", type=float, default=2.0,
                   help="gray-code: stripe width, panel px (default 2)")
    p.add_argument("--periods", type=float, default=64,
                   help="gray-phase: periods of the sinusoid across the panel (default 64)")
    p.add_argument("--steps", type=int, default=4,
                   help="gray-phase: phase steps (default 4)")
    p.add_argument("--spacing", type=int, default=8,
                   help="gray: line spacing = code stripe width = line frames, px (default 8)")
    p.add_argument("--no-complementary", action="store_true",
                   help="gray schemes: leave out the complementary Gray-code bit")
    p.add_argument("--reference", choices=("mean", "pair", "inverse"), default=None,
                   help="gray schemes: what code bits are thresholded against (default: mean "
                   "for gray-phase, pair for gray)")
    p.add_argument("--directions", choices=("xy", "x", "y"), default="xy",
                   help="gray schemes: projector directions encoded (default xy)")
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument("--grid", action="store_true",
                   help="also write grid.png, a line grid for projector distortion estimation")
    p.add_argument("--grid-spacing", type=int, default=64, help="grid line spacing, panel px")
    p.add_argument("--predistort", type=Path, metavar="RIG.json",
                   help="pre-distort every pattern (and the grid) with the appendix look-up table "
                   "for the projector distortion {center, rho} of a calibration or rig JSON")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    p.set_defaults(func=run)


def _load_spec(path: Path | None) -> PatternSet:
    if path is None:
        return default_pattern_set()
    try:
        text = path.read_text()
    except FileNotFoundError as exc:
        raise ValueError(f"{path}: spec file not found") from exc
    try:
        return PatternSet.from_json(text)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{path}: {exc}") from exc


def _write_png(path: Path, image: np.ndarray) -> None:
    with atomic_path(path) as tmp:
        Image.fromarray(image).save(tmp, "PNG")


def _scheme_set(args: argparse.Namespace) -> PatternSet:
    """The pattern set of ``--spec`` or ``--scheme`` and its options (checked first)."""
    scheme_options = (args.periods != 64 or args.steps != 4 or args.spacing != 8
                      or args.stripe != 2.0
                      or args.no_complementary or args.reference is not None
                      or args.directions != "xy")
    if args.spec is not None:
        if args.scheme is not None or scheme_options:
            raise ValueError("--spec: the spec file says the scheme; leave out --scheme and its "
                             "options")
        return _load_spec(args.spec)
    scheme = args.scheme or "pmp"
    if scheme == "pmp":
        if scheme_options:
            raise ValueError("--scheme pmp: --periods, --steps, --spacing, --no-complementary, "
                             "--reference and --directions are for the gray schemes (give a "
                             "--spec for another PMP set)")
        return default_pattern_set()
    common: dict[str, Any] = dict(complementary=not args.no_complementary,
                                  directions=tuple(args.directions))
    if args.reference is not None:
        common["reference"] = args.reference
    if scheme == "gray-phase":
        return gray_phase_pattern_set(periods=args.periods, steps=args.steps, **common)
    if scheme == "gray-code":
        if args.no_complementary or args.reference == "mean":
            raise ValueError("--scheme gray-code: no complementary bit to leave out, and its "
                             "reference is 'pair' (default) or 'inverse'")
        return gray_code_pattern_set(stripe=args.stripe, directions=tuple(args.directions),
                                     **({"reference": args.reference} if args.reference else {}))
    return gray_line_pattern_set(spacing=args.spacing, **common)


def run(args: argparse.Namespace) -> int:
    pattern_set = _scheme_set(args)
    frames = make_patterns(pattern_set)
    # Hook: pre-distortion of the frames (``--predistort RIG.json``) is applied here.
    lut = None
    if args.predistort is not None:

        predistortion = load_projector_distortion(args.predistort)
        if predistortion is None or predistortion.rho == 0:
            raise ValueError(f"{args.predistort}: --predistort: the file has no projector "
                             "distortion (nothing to pre-distort); leave --predistort out")
        lut = distortion_lut(pattern_set.panel_size, predistortion.center, predistortion.rho)
        frames = apply_lut(frames, lut)
    out: Path = args.out
    grid = None
    if args.grid:  # every image is made before anything is written
        grid = grid_pattern(panel_size=pattern_set.panel_size, spacing=args.grid_spacing)
        grid = grid if lut is None else apply_lut(grid, lut)
    files = [f"pattern_{i:03d}.png" for i in range(len(frames))]
    manifest = {
        "pattern_set": pattern_set.to_dict(),
        "frames": [
            {"file": files[t.index], "kind": t.kind, "direction": t.direction,
             "periods": t.periods, "step": t.step, "steps": t.steps, "shift": t.shift,
             **({"bit": t.bit} if t.bit >= 0 else {})}
            for t in frame_table(pattern_set)
        ],
    }
    if lut is not None:
        assert predistortion is not None  # lut is made from it
        manifest["predistortion"] = predistortion.to_dict()
    if grid is not None:
        manifest["grid"] = "grid.png"
    with atomic_directory(out, marker="patterns.json") as tmp:  # the directory as a whole
        for name, frame in zip(files, frames, strict=True):
            _write_png(tmp / name, frame)
        if grid is not None:
            _write_png(tmp / "grid.png", grid)
        write_json(tmp / "patterns.json", manifest)
    summary = {"out": str(out), "n_frames": len(files), "panel_size": list(pattern_set.panel_size),
               "scheme": pattern_set.scheme, "spec": "patterns.json", "grid": manifest.get("grid")}
    if args.json:
        print(dumps_json(summary, indent=None))
    else:
        print(f"wrote {len(files)} patterns ({pattern_set.panel_size[0]} x "
              f"{pattern_set.panel_size[1]}) to {out}")
    return 0
