"""``nail2nail print-target``: printable calibration boards and the cylinder target's wrap."""

from __future__ import annotations

import argparse
import math
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

__all__ = ["MAX_BOARD_SIDE", "MAX_SHEET_MM", "MIN_SPACING_MM", "add_parser", "board_from_options",
           "run"]

#: The most squares (checkerboard, ChArUco) or circles along a board's side: a 200 × 200 board
#: writes a few MB of SVG (1e6 rows wrote 248 MB, 3001 × 3000 peaked at 2 GB), and OpenCV's
#: detectors are used with boards of tens of squares.
MAX_BOARD_SIDE = 200
#: The smallest square side or circle spacing, mm: the circles of a circle board are half of
#: it (0.25 mm, 6 dots at 600 dpi), about the finest mark an office printer draws true.
MIN_SPACING_MM = 0.5
#: The largest board, pattern and margins, mm: ISO A0 (841 × 1189 mm), either way round; the
#: largest sheet a printer (a plotter) takes.
MAX_SHEET_MM = (841.0, 1189.0)


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
                   help="squares (checkerboard, charuco) or circles along y (default 11, at "
                   f"most {MAX_BOARD_SIDE})")
    p.add_argument("--cols", type=int, metavar="C",
                   help="squares or circles along x; asymmetric-circles: circles in a row "
                   f"(default 8, 4 for asymmetric-circles; at most {MAX_BOARD_SIDE})")
    p.add_argument("--spacing", type=float, metavar="MM",
                   help=f"square side or circle spacing, mm (default 2.5, at least "
                   f"{MIN_SPACING_MM:g}); the board with its margins must fit on A0 "
                   f"({MAX_SHEET_MM[0]:g} x {MAX_SHEET_MM[1]:g} mm)")
    p.add_argument("--marker", type=float, metavar="MM",
                   help="ChArUco marker side or circle diameter, mm (not for a checkerboard)")
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
        board = board_from_options(args.board, rows=args.rows, cols=args.cols,
                                   spacing=args.spacing, marker=args.marker,
                                   dictionary=args.dictionary, margin=args.margin)
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


def board_from_options(kind: str, *, rows: int | None = None, cols: int | None = None,
                       spacing: float | None = None, marker: float | None = None,
                       dictionary: str | None = None, margin: float | None = None) -> Board:
    """The board of the command line's board options (``None``: the kind's default), each
    checked and named as its option (``--rows`` …), for ``print-target`` and ``simulate``.

    Raises
    ------
    ValueError
        Naming the option and its value: ``--rows``/``--cols`` above :data:`MAX_BOARD_SIDE`,
        ``--spacing`` below :data:`MIN_SPACING_MM` or not finite, ``--marker`` for a
        checkerboard (it has none), a board larger than :data:`MAX_SHEET_MM` (A0) with its
        margins, and what :class:`~nail2nail.calibration.boards.Board` refuses.
    """
    base = default_board(kind)
    for flag, count in (("--rows", rows), ("--cols", cols)):
        if count is not None and count > MAX_BOARD_SIDE:
            raise ValueError(f"{flag}: expected at most {MAX_BOARD_SIDE} squares or circles "
                             f"along a side, got {count}")
    if spacing is not None and not (math.isfinite(spacing) and spacing >= MIN_SPACING_MM):
        raise ValueError(f"{flag_value('--spacing', spacing)}: expected a finite length of at "
                         f"least {MIN_SPACING_MM:g} mm (the finest a printer draws true)")
    if marker is not None and kind == "checkerboard":
        raise ValueError(f"{flag_value('--marker', marker)}: a checkerboard has no markers "
                         "(only with --board charuco, circles or asymmetric-circles)")
    options: dict = {"kind": kind, "rows": base.rows if rows is None else rows,
                     "cols": base.cols if cols is None else cols,
                     "spacing": base.spacing if spacing is None else spacing}
    for key, value in (("marker", marker), ("dictionary", dictionary), ("margin", margin)):
        if value is not None:
            options[key] = value
    given = " ".join(flag_value(f"--{k}", v) for k, v in (
        ("board", kind), ("rows", rows), ("cols", cols), ("spacing", spacing),
        ("marker", marker), ("dictionary", dictionary), ("margin", margin)) if v is not None)
    try:
        board = Board(**options)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{given}: {exc}") from None
    width, height = board.size_mm
    short, long = sorted((width, height))
    if short > MAX_SHEET_MM[0] or long > MAX_SHEET_MM[1]:
        raise ValueError(f"{given}: the board is {width:g} x {height:g} mm with its margins; "
                         f"at most A0, {MAX_SHEET_MM[0]:g} x {MAX_SHEET_MM[1]:g} mm (fewer or "
                         "smaller squares)")
    return board


def flag_value(flag: str, value) -> str:
    """``--flag VALUE`` as the user wrote it (floats as ``%g``)."""
    return f"{flag} {value:g}" if isinstance(value, float) else f"{flag} {value}"
