"""``nail2nail simulate``: render a scene with the virtual scanner into a capture directory."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ..io._json import dumps_json
from ..simulation.scenes import SCENES

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "simulate",
        help="render a capture with the virtual scanner (three cameras, one projector)",
        description="Render what each camera of the virtual scanner sees of a scene under a "
        "sequence of projector images and write a capture directory (capture.json, "
        "cam0/000.png ..., truth/). Format: docs/capture-format.md.",
    )
    p.add_argument("--scene", choices=SCENES, default="finger", help="object (default: finger)")
    p.add_argument("--out", type=Path, required=True, help="capture directory to write")
    p.add_argument("--rig", type=Path, help="rig JSON (default: the thesis-like default rig)")
    p.add_argument("--patterns", type=Path,
                   help="directory of panel PNGs to project, sorted by name (default: the "
                   "default pattern set of nail2nail.patterns)")
    p.add_argument("--projector-distortion", choices=["thesis", "none"],
                   help="projector radial distortion (default: the rig's; thesis for the "
                   "default rig)")
    p.add_argument("--scale", type=float, help="camera resolution scale (default 1)")
    p.add_argument("--seed", type=int, default=0, help="fingerprint and noise seed (default 0)")
    p.add_argument("--print", dest="print_image", type=Path, metavar="IMAGE",
                   help="finger only: wrap this fingerprint image (8-bit grayscale PNG or WSQ, "
                   "legacy convention: as an inked roll, tip up) around the finger instead of "
                   "a synthetic print; truth/rolled_print.png is this image")
    p.add_argument("--print-ppi", type=float, metavar="PPI",
                   help="resolution of --print (default: the file's, else 500)")
    p.add_argument("--no-truth", action="store_true", help="do not write truth/")
    p.add_argument("--json", action="store_true", help="print the manifest summary as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..simulation.capture import load_pattern_dir, simulate_capture
    from ..simulation.rig import load_rig

    if args.scale is not None and not args.scale > 0:
        raise ValueError(f"--scale: expected a positive number, got {args.scale}")
    if args.print_image is not None and args.scene != "finger":
        raise ValueError(f"--print: only with --scene finger, got --scene {args.scene}")
    if args.print_ppi is not None and not args.print_ppi > 0:
        raise ValueError(f"--print-ppi: expected a positive number, got {args.print_ppi}")
    print_image = None
    print_ppi = args.print_ppi
    if args.print_image is not None:
        from ..io.prints import read_print_image

        print_image, file_ppi = read_print_image(args.print_image)
        print_ppi = print_ppi or file_ppi or 500.0
    rig = load_rig(args.rig) if args.rig else None
    patterns = names = None
    if args.patterns:
        patterns, names = load_pattern_dir(args.patterns)
    start = time.perf_counter()
    manifest = simulate_capture(
        args.out, args.scene, rig=rig, scale=args.scale,
        projector_distortion=args.projector_distortion, patterns=patterns, pattern_names=names,
        seed=args.seed, write_truth=not args.no_truth, progress=sys.stderr.isatty(),
        print_image=print_image, print_ppi=print_ppi or 500.0,
    )
    elapsed = time.perf_counter() - start
    summary = {
        "out": str(args.out),
        "scene": args.scene,
        "n_frames": manifest["n_frames"],
        "cameras": [{"name": c["name"], "size": c["size"]} for c in manifest["cameras"]],
        "truth": manifest.get("truth"),
        "print": None if print_image is None else {"image": str(args.print_image),
                                                   "ppi": print_ppi},
        "seconds": round(elapsed, 2),
    }
    if args.json:
        print(dumps_json(summary))
    else:
        cams = ", ".join(f"{c['name']} {c['size'][0]}x{c['size'][1]}" for c in summary["cameras"])
        print(f"wrote {args.out}: scene {args.scene}, {summary['n_frames']} frames x "
              f"{len(summary['cameras'])} cameras ({cams}) in {elapsed:.1f} s")
    return 0
