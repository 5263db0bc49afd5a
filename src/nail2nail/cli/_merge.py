"""``nail2nail merge``: merge error between cameras in projector space, and the super scan.

:func:`write_merge` is the whole step on scans already in memory (``nail2nail demo`` calls it
too); :func:`run` reads a scan directory (``io.scans.load_scans``) and prints the summary.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..fusion import fuse_scans, write_super_mat5, write_super_ply
from ..io._atomic import atomic_path
from ..io.scans import load_scans
from ..merge import _check_int, correspond
from ..plots import (
    plot_correspondence_images,
    plot_correspondences_3d,
    plot_merge_heatmap,
    plot_merge_histogram,
    render_points,
)

__all__ = ["add_parser", "parse_pairs", "run", "write_merge"]

#: Views of the super-scan renders: name -> (elev, azim) in degrees.
RENDER_VIEWS = {"front": (10.0, 0.0), "side": (15.0, 70.0)}


def parse_pairs(text: str | None, n_cameras: int) -> list[tuple[int, int]]:
    """Camera pairs from ``"0-1,1-2"`` (parent-child indices in scan order).

    ``None`` or ``""`` gives the neighbouring pairs ``0-1, 1-2, …``.

    Examples
    --------
    >>> parse_pairs("0-1,2-1", 3)
    [(0, 1), (2, 1)]
    >>> parse_pairs(None, 3)
    [(0, 1), (1, 2)]
    """
    if not text:
        return [(i, i + 1) for i in range(n_cameras - 1)]
    pairs = []
    for item in text.split(","):
        parts = item.strip().split("-")
        try:
            i, j = (int(p) for p in parts)
        except ValueError:
            raise ValueError(f"--pairs: expected PARENT-CHILD camera indices like 0-1, got "
                             f"{item.strip()!r}") from None
        if not (0 <= i < n_cameras and 0 <= j < n_cameras) or i == j:
            raise ValueError(f"--pairs: {item.strip()!r} must name two different cameras "
                             f"among 0..{n_cameras - 1}")
        pairs.append((i, j))
    return pairs


def _save_mapping(path: Path, corr) -> Path:
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(
                fh, mapping=corr.mapping, parent_rc=corr.parent_rc, child_rc=corr.child_rc,
                xyz_parent=corr.xyz_parent, xyz_child=corr.xyz_child,
                distance_mm=corr.distance_mm, residual_px=corr.residual_px,
            )
    return path


def write_merge(
    scans,
    out: str | os.PathLike,
    *,
    pairs: list[tuple[int, int]] | None = None,
    stride: int = 1,
    max_residual_px: float = 0.5,
    border_px: int = 2,
    figures: bool = True,
    super_scan: bool = True,
    progress: bool = False,
) -> dict:
    """Merge error of each camera pair and the fused super scan, written under `out`.

    Per pair ``P-C``: ``merge_P-C_mapping.npz`` (the thesis's mapping matrix and the pairs),
    and with `figures` ``merge_P-C_heatmap.png``, ``_histogram.png``, ``_points3d.png``,
    ``_marked.png``. With `super_scan`: ``super.ply``, the super mat5 ``superC.bmp`` …
    (:func:`nail2nail.fusion.super_mat5_scan`), and with `figures` ``super_front.png``,
    ``super_side.png``. Also ``merge.json``, the returned summary.

    Returns
    -------
    dict
        ``{"out", "merge": {"P-C": {parent, child, stride, sampled, pairs, dropped,
        distance_mm: {median, mean, rms, p90, p95, max, frac_below_0_05}, squared_mm2,
        files}}, "super_scan": {...} | None, "outputs": [paths]}``.
    """
    scans = list(scans)
    stride = _check_int(stride, "stride", minimum=1)
    pairs = parse_pairs(None, len(scans)) if pairs is None else pairs
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    outputs: list[str] = []
    summary: dict = {"out": str(out), "merge": {}, "super_scan": None, "outputs": outputs}
    for i, j in tqdm(pairs, desc="merge", unit="pair", disable=not progress):
        corr = correspond(scans[i], scans[j], stride=stride, max_residual_px=max_residual_px,
                          border_px=border_px)
        key = f"{i}-{j}"
        files = {"mapping": _save_mapping(out / f"merge_{key}_mapping.npz", corr)}
        if figures:
            files["heatmap"] = plot_merge_heatmap(corr, out / f"merge_{key}_heatmap.png",
                                                  background=scans[i].albedo)
            files["histogram"] = plot_merge_histogram(
                corr.distance_mm, out / f"merge_{key}_histogram.png",
                title=f"{corr.parent_name} ↔ {corr.child_name}: merge error")
            every = max(20 // stride, 1) * stride
            files["points3d"] = plot_correspondences_3d(corr, out / f"merge_{key}_points3d.png",
                                                        every=every)
            files["marked"] = plot_correspondence_images(
                corr, scans[i].albedo, scans[j].albedo, out / f"merge_{key}_marked.png",
                every=every)
        files = {k: str(v) for k, v in files.items()}
        outputs.extend(files.values())
        summary["merge"][key] = {**corr.statistics(), "files": files}
    if super_scan:
        sup = fuse_scans(scans, max_residual_px=max_residual_px)
        files = {"ply": write_super_ply(out / "super.ply", sup)}
        mat5 = write_super_mat5(out / "super", sup)
        files["mat5"] = out / "super"
        outputs.extend(str(p) for p in mat5)
        if figures:
            for view, (elev, azim) in RENDER_VIEWS.items():
                files[f"render_{view}"] = render_points(
                    sup.vertices, out / f"super_{view}.png", normals=sup.vertex_normals,
                    colors=sup.colors, elev=elev, azim=azim,
                    title=f"super scan ({view}): {sup.n_vertices} points")
        files = {k: str(v) for k, v in files.items()}
        outputs.extend(v for k, v in files.items() if k != "mat5")
        summary["super_scan"] = {**sup.summary(), "files": files}
    report = out / "merge.json"
    outputs.append(str(report))
    with atomic_path(report) as tmp:
        tmp.write_text(json.dumps(summary, indent=2) + "\n")
    return summary


def add_parser(sub) -> None:
    p = sub.add_parser(
        "merge",
        help="merge error between cameras in projector space, and the fused super scan",
        description="For every valid pixel (or every K-th) of the parent camera of each pair, "
        "find the child pixel with the nearest projector coordinates (k-d tree, sub-pixel), "
        "report the world distance of the pairs (thesis chapter four) with figures, and fuse "
        "all cameras into one nail-to-nail point cloud and mesh (super.ply, super mat5).",
    )
    p.add_argument("scan_dir", type=Path, help="scan directory written by `nail2nail scan`")
    p.add_argument("--pairs", default=None,
                   help="camera pairs PARENT-CHILD, comma separated (default: 0-1,1-2,…)")
    p.add_argument("--stride", type=int, default=1,
                   help="sample every K-th parent row and column (the thesis used 5 and 20)")
    p.add_argument("--max-residual", type=float, default=0.5,
                   help="largest projector residual of a pair, panel px (decoding noise)")
    p.add_argument("--border", type=int, default=2,
                   help="erosion of each camera's valid region, px")
    p.add_argument("--no-super", action="store_true", help="skip the super scan")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument("--json", action="store_true", help="print a machine-readable summary")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    scans = load_scans(args.scan_dir)
    if len(scans) < 2:
        raise ValueError(f"{args.scan_dir}: need at least two cameras to merge, got {len(scans)}")
    pairs = parse_pairs(args.pairs, len(scans))
    summary = write_merge(
        scans, args.out, pairs=pairs, stride=args.stride, max_residual_px=args.max_residual,
        border_px=args.border, figures=not args.no_figures, super_scan=not args.no_super,
        progress=not args.json and sys.stderr.isatty(),
    )
    summary = {"scan_dir": str(args.scan_dir), **summary}
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0
    print(f"{'pair':>6} {'pairs':>8} {'median µm':>10} {'p95 µm':>8} {'max µm':>8} "
          f"{'<0.05mm':>8}  dropped (parent border / child border / residual)")
    for key, m in summary["merge"].items():
        d, dr = m["distance_mm"], m["dropped"]
        print(f"{key:>6} {m['pairs']:>8} {1e3 * d['median']:10.2f} {1e3 * d['p95']:8.2f} "
              f"{1e3 * d['max']:8.2f} {100 * d['frac_below_0_05']:7.1f}%  "
              f"{dr['parent_border']} / {dr['child_border']} / {dr['residual']}")
    if summary["super_scan"]:
        s = summary["super_scan"]
        print(f"super scan: {s['vertices']} points, {s['faces']} triangles -> "
              f"{s['files']['ply']}, {s['files']['mat5']}*")
    print(f"wrote {Path(args.out) / 'merge.json'}")
    return 0
