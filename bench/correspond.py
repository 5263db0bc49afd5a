"""Benchmark: projector-space correspondence per camera pair, against what it replaced.

For each pair, in one run: :func:`nail2nail.merge.correspond` as the merge runs it (bucket-grid
search, with a :class:`~nail2nail.merge.correspondence.CorrespondenceCache` already holding both
scans' images: the per-pair cost), the same with an empty cache (the first pair of a scan), the
same with a k-d tree built per call (``method="kdtree"``: the cKDTree baseline, everything else
equal), and the implementation before issue 11 (``reference_correspond`` of
``tests/test_merge_fast.py``: normals, view cosine and masks in NumPy per call, float64 copies,
a k-d tree per call), with the ratios and a check that all give the same pairs.

Without ``--scan-dir`` the scans are synthetic: one million parent pixels against a full child
frame (1280 × 1024 valid pixels), smooth slightly non-linear projector maps of two views of a
gently curved surface with decoding noise; the appendix's ``closest_proj_point`` search (every
child pixel for every parent pixel, vectorised over the child) is timed on a crop of parent
pixels and extrapolated to the million. With ``--scan-dir`` (a directory written by
``nail2nail scan``, e.g. the full-resolution demo finger) every ordered pair of its cameras.

Usage::

    .venv/bin/python bench/correspond.py [--crop 200] [--repeat 3] [--json]
    .venv/bin/python bench/correspond.py --scan-dir SCAN_DIR [--pairs 0-1,1-2] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_merge_fast import reference_correspond  # the implementation before issue 11

from nail2nail.merge import correspond, nearest_bruteforce, nearest_kdtree
from nail2nail.merge.correspondence import CorrespondenceCache, nearest_grid
from nail2nail.reconstruction import Scan

H, W = 1280, 1024  # camera frame (rows, cols)


def _scan(name: str, *, offset_px: float, valid_rows: slice, noise_px: float, seed: int) -> Scan:
    rng = np.random.default_rng(seed)
    r, c = np.mgrid[0:H, 0:W].astype(np.float64)
    # projector coordinates: an affine map plus a mild perspective-like curvature
    xp = 40.0 + 0.95 * (c + offset_px) + 0.04 * r + 4e-5 * (c + offset_px) ** 2
    yp = 10.0 + 0.78 * r - 0.02 * (c + offset_px) + 1e-5 * r**2
    # world points on a cylinder-like surface, from the (noise-free) projector coordinates
    u, v = xp / 32.0, yp / 32.0
    xyz = np.stack([u, v, 3.0 * np.cos(u / 8.0)], axis=-1)
    mask = np.zeros((H, W), dtype=bool)
    mask[valid_rows] = True
    xp = xp + noise_px * rng.standard_normal(xp.shape)
    yp = yp + noise_px * rng.standard_normal(yp.shape)
    ones = np.ones((H, W), dtype=np.float32)
    return Scan(name, xyz.astype(np.float32), xp.astype(np.float32), yp.astype(np.float32),
                ones, ones, ones, mask, camera_center=None)


def _synthetic(noise: float) -> list[Scan]:
    n_parent_rows = -(-1_000_000 // W)  # ⌈1e6 / W⌉ rows of valid parent pixels
    parent = _scan("parent", offset_px=150.0, valid_rows=slice(0, n_parent_rows),
                   noise_px=noise, seed=1)
    parent.mask[n_parent_rows - 1, 1_000_000 - (n_parent_rows - 1) * W:] = False
    child = _scan("child", offset_px=0.0, valid_rows=slice(0, H), noise_px=noise, seed=2)
    return [parent, child]


def _best(fn, repeat: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def _same(m, ref) -> bool:
    """The pairs, drop counts and rejections of `m` are those of the reference."""
    pairs, reason, dropped, _ = ref
    kept = reason < 0
    return (m.dropped == dropped and np.array_equal(m.parent_rc, pairs["parent_rc"][kept])
            and np.array_equal(m.xyz_child, pairs["xyz_child"][kept])
            and np.array_equal(m.child_nearest, pairs["child_nearest"][kept]))


def bench_pair(parent: Scan, child: Scan, *, repeat: int, old: bool) -> dict:
    """Timings of one ordered pair (seconds) and the agreement of the implementations."""
    cache = CorrespondenceCache()
    t0 = time.perf_counter()
    first = correspond(parent, child, cache=cache)  # per-scan images computed here
    cold = time.perf_counter() - t0
    warm, m = _best(lambda: correspond(parent, child, cache=cache), repeat)
    kdtree, k = _best(lambda: correspond(parent, child, cache=cache, method="kdtree"), repeat)
    row = {"pair": f"{parent.name}-{child.name}", "pairs": m.n_pairs,
           "dropped": m.dropped, "grid_s": round(warm, 3), "grid_cold_s": round(cold, 3),
           "kdtree_s": round(kdtree, 3), "kdtree_ratio": round(kdtree / warm, 1),
           "kdtree_same": bool(np.array_equal(k.parent_rc, m.parent_rc)
                               and k.dropped == m.dropped),
           "first_same": bool(np.array_equal(first.xyz_child, m.xyz_child))}
    if old:
        t0 = time.perf_counter()
        ref = reference_correspond(parent, child)
        t_old = time.perf_counter() - t0
        row |= {"old_s": round(t_old, 3), "old_ratio": round(t_old / warm, 1),
                "old_same": _same(m, ref)}
    return row


def _print_rows(rows: list[dict]) -> None:
    print(f"{'pair':>12} {'pairs':>8} {'grid s':>7} {'1st s':>7} {'kd s':>7} {'kd/grid':>8} "
          f"{'old s':>7} {'old/grid':>9}  same")
    for r in rows:
        old = (f"{r['old_s']:7.2f} {r['old_ratio']:8.1f}x" if "old_s" in r
               else f"{'-':>7} {'-':>9}")
        same = r["kdtree_same"] and r["first_same"] and r.get("old_same", True)
        print(f"{r['pair']:>12} {r['pairs']:>8} {r['grid_s']:7.3f} {r['grid_cold_s']:7.3f} "
              f"{r['kdtree_s']:7.3f} {r['kdtree_ratio']:7.1f}x {old}  {same}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scan-dir", type=Path, default=None,
                        help="a scan directory (nail2nail scan): its camera pairs")
    parser.add_argument("--pairs", default=None,
                        help="with --scan-dir: PARENT-CHILD indices, comma separated "
                        "(default: every ordered pair)")
    parser.add_argument("--crop", type=int, default=200, help="parent pixels for the brute force")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--noise", type=float, default=0.05, help="decoding noise, panel px")
    parser.add_argument("--no-old", action="store_true",
                        help="skip the implementation before issue 11 (seconds per pair)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)

    if args.scan_dir is not None:
        from nail2nail.io.scans import load_scans
        from nail2nail.merge.report import parse_pairs

        scans = load_scans(args.scan_dir)
        pairs = (parse_pairs(args.pairs, len(scans)) if args.pairs else
                 [(i, j) for i in range(len(scans)) for j in range(len(scans)) if i != j])
        correspond(scans[0], scans[1], stride=64)  # warm-up (imports, compiled kernels)
        rows = [bench_pair(scans[i], scans[j], repeat=args.repeat, old=not args.no_old)
                for i, j in pairs]
        result = {"scan_dir": str(args.scan_dir),
                  "valid_pixels": {s.name: int(s.mask.sum()) for s in scans}, "pairs": rows}
        if args.json:
            print(json.dumps(result, indent=2))
        else:
            print(f"{args.scan_dir}: valid pixels {result['valid_pixels']}; seconds per pair "
                  f"(grid: cache warm, best of {args.repeat}; 1st: empty cache; kd: k-d tree "
                  "per call; old: before issue 11)")
            _print_rows(rows)
        return 0

    parent, child = _synthetic(args.noise)
    n_parent = int(parent.mask.sum())
    correspond(parent, child, stride=64)  # warm-up (imports, compiled kernels, page faults)
    row = bench_pair(parent, child, repeat=args.repeat, old=not args.no_old)

    # the appendix's search on a small crop of parent pixels, against the full child frame
    rows, cols = np.nonzero(parent.mask)
    pick = np.linspace(0, rows.size - 1, args.crop).astype(int)
    t0 = time.perf_counter()
    br, bc, _ = nearest_bruteforce(parent, child, rows[pick], cols[pick])
    t_brute = time.perf_counter() - t0
    kr, kc, _ = nearest_kdtree(parent, child, rows[pick], cols[pick])
    gr, gc, _ = nearest_grid(parent, child, rows[pick], cols[pick])
    agree = float(np.mean((br == kr) & (bc == kc) & (br == gr) & (bc == gc)))
    per_pixel = t_brute / args.crop
    extrapolated = per_pixel * n_parent
    result = {
        "parent_pixels": n_parent,
        "child_pixels": int(child.mask.sum()),
        **row,
        "bruteforce_crop_pixels": args.crop,
        "bruteforce_crop_s": round(t_brute, 3),
        "bruteforce_per_pixel_ms": round(1e3 * per_pixel, 3),
        "bruteforce_extrapolated_s": round(extrapolated, 1),
        "bruteforce_ratio": round(extrapolated / row["grid_s"], 1),
        "nearest_agreement_on_crop": agree,
    }
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(f"{n_parent} parent px vs {result['child_pixels']} child px, {row['pairs']} pairs, "
              f"dropped {row['dropped']}")
        _print_rows([row])
        print(f"brute force (appendix): {args.crop} parent px in {t_brute:.3f} s = "
              f"{1e3 * per_pixel:.2f} ms/px -> {extrapolated:.0f} s for {n_parent} px "
              f"(extrapolated), {extrapolated / row['grid_s']:.0f}x the grid; nearest pixels "
              f"agree (brute force, k-d tree, grid) on the crop: {100 * agree:.1f} %")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
