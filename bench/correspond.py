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

With ``--merge-calls`` (and ``--scan-dir``): the eight calls of the merge step, as it makes
them: the report's neighbouring pairs (``border_px=2``, one cache) and fusion's every ordered
pair (``border_px=1``, one cache, the view cosine passed in ``quality``), each cache empty at
first, so the per-scan images count; per call, best of ``--repeat``. ``--against FILE`` (a
copy of an earlier ``nail2nail/merge/correspondence.py``, its ``.statistics`` import made
absolute) times that implementation in the same run, interleaved call by call, and checks
that every result is the same bit for bit.

Usage::

    .venv/bin/python bench/correspond.py [--crop 200] [--repeat 3] [--json]
    .venv/bin/python bench/correspond.py --scan-dir SCAN_DIR [--pairs 0-1,1-2] [--json]
    .venv/bin/python bench/correspond.py --scan-dir SCAN_DIR --merge-calls [--against FILE]
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
from nail2nail.scan.results import Scan

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


_PAIR_ARRAYS = ("parent_rc", "child_nearest", "child_rc", "xyz_parent", "xyz_child",
                "residual_px")


def _identical(a, b) -> bool:
    """Two correspondences with the same arrays (values and dtypes), counts and rejections."""
    for x, y in ((a, b), (a.rejected, b.rejected)):
        if (x is None) != (y is None):
            return False
        if x is None:
            continue
        for name in _PAIR_ARRAYS:
            u, v = getattr(x, name), getattr(y, name)
            if u.dtype != v.dtype or not np.array_equal(u, v):
                return False
        if x.dropped != y.dropped or x.n_sampled != y.n_sampled:
            return False
    reasons = [None if m.rejected is None else m.rejected.reason.tolist() for m in (a, b)]
    return reasons[0] == reasons[1]


def merge_calls(scans, modules, *, repeat: int) -> tuple[list[dict], bool]:
    """The merge's eight calls of ``_correspond`` with each module, interleaved; per call the
    best time of each (seconds) and whether all modules agree."""
    from nail2nail.merge.correspondence import _view_cosine

    n = len(scans)
    report = [(i, i + 1) for i in range(n - 1)]
    fusion = [(i, j) for i in range(n) for j in range(n) if i != j]
    options = {"stride": 1, "max_residual_px": 0.5, "max_jump_px": 2.0, "refine": True,
               "method": "grid", "workers": -1, "max_view_angle_deg": 70.0,
               "min_relative_modulation": 1 / 3, "outlier_mm": 0.025, "outlier_mad": 4.0,
               "outlier_block_px": 32}
    times: dict[tuple, list[list[float]]] = {}
    same = True
    for _ in range(repeat + 1):  # the first round warms up (compiled kernels, page faults)
        caches = {m: (m.CorrespondenceCache(), m.CorrespondenceCache()) for m in modules}
        quality = {m: {id(s): [_view_cosine(s, m.valid_mask(s), smooth_px=2.0), None]
                       for s in scans} for m in modules}
        for stage, pairs, border in (("report", report, 2), ("fusion", fusion, 1)):
            for i, j in pairs:
                results = []
                for k, m in enumerate(modules):
                    extra = ({"cache": caches[m][0]} if stage == "report" else
                             {"cache": caches[m][1], "quality": quality[m]})
                    t0 = time.perf_counter()
                    results.append(m._correspond(scans[i], scans[j], border_px=border,
                                                 **options, **extra))
                    times.setdefault((stage, i, j), [[] for _ in modules])[k].append(
                        time.perf_counter() - t0)
                same &= all(_identical(results[0], r) for r in results[1:])
    rows = [{"call": f"{stage} {i}-{j}",
             **{f"s_{k}": round(min(t[1:]), 4) for k, t in enumerate(ts)}}
            for (stage, i, j), ts in times.items()]
    return rows, same


def _load_module(path: Path):
    import importlib.util

    spec = importlib.util.spec_from_file_location("nail2nail.merge._bench_against", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


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
    parser.add_argument("--merge-calls", action="store_true",
                        help="with --scan-dir: the merge step's eight calls (see above)")
    parser.add_argument("--against", type=Path, default=None,
                        help="with --merge-calls: an earlier correspondence.py to compare")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)

    if args.merge_calls:
        import nail2nail.merge.correspondence as current
        from nail2nail.io.scans import load_scans

        if args.scan_dir is None:
            parser.error("--merge-calls needs --scan-dir")
        modules = [current] + ([_load_module(args.against)] if args.against else [])
        rows, same = merge_calls(load_scans(args.scan_dir), modules, repeat=args.repeat)
        totals = [round(sum(r[f"s_{k}"] for r in rows), 3) for k in range(len(modules))]
        if args.json:
            print(json.dumps({"calls": rows, "total_s": totals, "same": same}, indent=2))
            return 0
        names = ["now"] + (["against"] if args.against else [])
        print(f"{'call':>12} " + " ".join(f"{n + ' s':>10}" for n in names))
        for r in rows:
            print(f"{r['call']:>12} " + " ".join(f"{r[f's_{k}']:10.3f}"
                                                  for k in range(len(modules))))
        print(f"{'total':>12} " + " ".join(f"{t:10.3f}" for t in totals)
              + ("" if len(modules) == 1 else f"   identical results: {same}"))
        return 0

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
