"""``nail2nail print-target``: printable calibration boards and the cylinder target's wrap."""

from __future__ import annotations

import argparse
from pathlib import Path

from nail2nail.calibration.boards import (
    BOARD_KINDS,
    Board,
    board_sheet,
    default_board,
    target_wrap_sheet,
)
from nail2nail.calibration.markers import TargetGeometry
from nail2nail.io._json import dumps_json

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "print-target",
        help="write a printable calibration board or cylinder-target wrap (SVG or PDF, 1:1)",
        description="Write a page to print at 100 %% scale: a planar calibration board "
        "(what = board; nail2nail calibrate-board) or the wrap of the cylindrical calibration "
        "target (what = cylinder; nail2nail calibrate), with every dimension written on the "
        "sheet and a 50 mm scale bar to check the printer's scaling. SVG (mm units) or PDF by "
        "the output's suffix. See docs/real-scanner.md.",
    )
    p.add_argument("what", choices=["board", "cylinder"], help="what to print")
    p.add_argument("-o", "--output", type=Path, required=True,
                   help="file to write: .svg or .pdf")
    p.add_argument("--board", choices=BOARD_KINDS, default="checkerboard",
                   help="board kind (default checkerboard)")
    p.add_argument("--rows", type=int, metavar="R",
                   help="squares (checkerboard, charuco) or circles along y (default 11)")
    p.add_argument("--cols", type=int, metavar="C",
                   help="squares or circles along x; asymmetric-circles: circles in a row "
                   "(default 8, 4 for asymmetric-circles)")
    p.add_argument("--spacing", type=float, metavar="MM",
                   help="square side or circle spacing, mm (default 2.5)")
    p.add_argument("--marker", type=float, metavar="MM",
                   help="ChArUco marker side or circle diameter, mm")
    p.add_argument("--dictionary", help="ChArUco ArUco dictionary (default DICT_5X5_100)")
    p.add_argument("--margin", type=float, metavar="MM",
                   help="white border around the pattern, mm (default one spacing)")
    p.add_argument("--json", action="store_true", help="print the dimensions as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:

    if args.output.suffix.lower() not in (".svg", ".pdf"):
        raise ValueError(f"--output: expected a .svg or .pdf file name, got {args.output}")
    board_options = [f"--{k}" for k in ("rows", "cols", "spacing", "marker", "dictionary",
                                        "margin") if getattr(args, k) is not None]
    if args.what == "cylinder":
        if board_options:
            raise ValueError(f"{board_options[0]}: only with print-target board")

        geometry = TargetGeometry()
        sheet = target_wrap_sheet(geometry)
        summary = {"what": "cylinder", "radius_mm": geometry.radius,
                   "circumference_mm": round(2 * 3.141592653589793 * geometry.radius, 4),
                   "y_range_mm": list(geometry.y_range),
                   "mark_diameter_mm": geometry.mark_diameter, "key": list(geometry.key),
                   "key_outer_diameter_mm": geometry.key_outer_diameter,
                   "key_inner_diameter_mm": geometry.key_inner_diameter}
    else:
        base = default_board(args.board)
        options = {"kind": args.board,
                   "rows": base.rows if args.rows is None else args.rows,
                   "cols": base.cols if args.cols is None else args.cols,
                   "spacing": base.spacing if args.spacing is None else args.spacing}
        for key in ("marker", "dictionary", "margin"):
            if getattr(args, key) is not None:
                options[key] = getattr(args, key)
        board = Board(**options)
        sheet = board_sheet(board)
        summary = {"what": "board", "board": board.to_dict()}
    sheet.save(args.output)
    summary.update(output=str(args.output), page_mm=[round(sheet.width, 3),
                                                     round(sheet.height, 3)])
    if args.json:
        print(dumps_json(summary))
    else:
        print(f"wrote {args.output}: {sheet.title}; page {sheet.width:.1f} x "
              f"{sheet.height:.1f} mm, print at 100 % and check the 50 mm bar")
    return 0
