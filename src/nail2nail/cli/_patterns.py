"""``nail2nail patterns``: write the projector's pattern frames (8-bit PNG) and their spec."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image

from ..io._atomic import atomic_directory, atomic_path
from ..io._json import dumps_json, write_json
from ..patterns import PatternSet, default_pattern_set, frame_table, grid_pattern, make_patterns

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "patterns",
        help="write multi-frequency phase-shifted patterns as 8-bit PNG",
        description="Render the frames of a pattern set (JSON spec, or the default 24-frame set: "
        "1, 8 and 64 periods in x and y) as 8-bit PNG files pattern_000.png … with "
        "patterns.json (the spec and the frame table) beside them.",
    )
    p.add_argument("--spec", type=Path, help="pattern set JSON (PatternSet.to_dict format)")
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


def run(args: argparse.Namespace) -> int:
    pattern_set = _load_spec(args.spec)
    frames = make_patterns(pattern_set)
    # Hook: pre-distortion of the frames (``--predistort RIG.json``) is applied here.
    lut = None
    if args.predistort is not None:
        from ..distortion import apply_lut, distortion_lut, load_projector_distortion

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
            {"file": files[t.index], "direction": t.direction, "periods": t.periods,
             "step": t.step, "steps": t.steps, "shift": t.shift}
            for t in frame_table(pattern_set)
        ],
    }
    if lut is not None:
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
               "spec": "patterns.json", "grid": manifest.get("grid")}
    if args.json:
        print(dumps_json(summary, indent=None))
    else:
        print(f"wrote {len(files)} patterns ({pattern_set.panel_size[0]} x "
              f"{pattern_set.panel_size[1]}) to {out}")
    return 0
