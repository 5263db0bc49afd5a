"""``nail2nail crosscheck``: two cameras' reconstructions of common reference points (Fig. 22)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from nail2nail.calibration.dlt import calibrate_points, crosscheck
from nail2nail.io._json import dumps_json
from nail2nail.io.points import read_points

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "crosscheck",
        help="distance between two cameras' reconstructions of common points (thesis Fig. 22)",
        description="Calibrate each camera from its own table, reconstruct the reference points "
        "common to both (same ideal world coordinates within 0.01 mm) and report the distance "
        "between the two reconstructions: Euclidean (mm) and the thesis's squared figure (mm²).",
    )
    p.add_argument("table_a", type=Path)
    p.add_argument("table_b", type=Path)
    p.add_argument("--use", choices=["yp", "xpyp"], default="yp")
    p.add_argument("--method", choices=["thesis", "normalized"], default="thesis")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=run)


def _stats(values: np.ndarray) -> dict:
    return {
        "median": float(np.median(values)),
        "max": float(values.max()),
        "mean": float(values.mean()),
        "values": values.round(6).tolist(),
    }


def _calibrate(table, path, args):
    """Calibrate from one table; an error says which table."""
    try:
        return calibrate_points(
            table.xyz_world, table.xy_camera, table.xy_projector, method=args.method, use=args.use
        )
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{path}: {exc}") from exc


def run(args: argparse.Namespace) -> int:
    ta, tb = read_points(args.table_a), read_points(args.table_b)
    ra, rb = (_calibrate(table, path, args) for table, path in ((ta, args.table_a),
                                                                (tb, args.table_b)))
    try:
        cc = crosscheck(ra, ta.xyz_world, rb, tb.xyz_world)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{args.table_a} and {args.table_b}: {exc}") from exc
    if args.json:
        out = {
            "pairs": int(cc.distance_mm.size),
            "use": args.use,
            "method": args.method,
            "points": [
                {"point_a": ta.labels[i], "point_b": tb.labels[j], "xyz_world": x.tolist()}
                for i, j, x in zip(cc.index_a, cc.index_b, cc.xyz_world, strict=True)
            ],
            "distance_mm": _stats(cc.distance_mm),
            "squared_mm2": {
                "max": float(cc.squared_mm2.max()),
                "values": cc.squared_mm2.round(6).tolist(),
            },
        }
        print(dumps_json(out))
        return 0
    print(f"{'A':>4} {'B':>4} {'Xw':>8} {'Yw':>8} {'Zw':>8} {'dist_mm':>8} {'sq_mm2':>8}")
    for i, j, x, d in zip(cc.index_a, cc.index_b, cc.xyz_world, cc.distance_mm, strict=True):
        print(
            f"{ta.labels[i]:>4} {tb.labels[j]:>4} {x[0]:8.3f} {x[1]:8.3f} {x[2]:8.3f} "
            f"{d:8.4f} {d * d:8.4f}"
        )
    d = cc.distance_mm
    print(
        f"\n{d.size} common points, reconstruction from {args.use}: distance median "
        f"{np.median(d):.4f} mm, mean {d.mean():.4f} mm, max {d.max():.4f} mm; "
        f"thesis's squared figure max {cc.squared_mm2.max():.4f} mm²"
    )
    return 0
