"""Benchmark: projector-space correspondence, k-d tree against the thesis appendix's brute force.

One million parent pixels are matched against a full child frame (1280 × 1024 valid pixels) with
:func:`nail2nail.merge.correspond` (k-d tree, sub-pixel refinement, overlap tests). The appendix's
``closest_proj_point`` search (every child pixel for every parent pixel, vectorised over the child
here, so already far faster than the MATLAB double loop) is timed on a small crop of parent pixels
against the same full child frame, and its cost per parent pixel extrapolated to the million.

The scans are synthetic: smooth, slightly non-linear projector maps of two views of a gently
curved surface, with decoding noise.

Usage::

    .venv/bin/python bench/correspond.py [--crop 200] [--repeat 3] [--json]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from nail2nail.merge import correspond, nearest_bruteforce, nearest_kdtree
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


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--crop", type=int, default=200, help="parent pixels for the brute force")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--noise", type=float, default=0.05, help="decoding noise, panel px")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)

    n_parent_rows = -(-1_000_000 // W)  # ⌈1e6 / W⌉ rows of valid parent pixels
    parent = _scan("parent", offset_px=150.0, valid_rows=slice(0, n_parent_rows),
                   noise_px=args.noise, seed=1)
    parent.mask[n_parent_rows - 1, 1_000_000 - (n_parent_rows - 1) * W:] = False
    child = _scan("child", offset_px=0.0, valid_rows=slice(0, H), noise_px=args.noise, seed=2)
    n_parent = int(parent.mask.sum())

    correspond(parent, child)  # warm-up (imports, page faults)
    times = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        m = correspond(parent, child)
        times.append(time.perf_counter() - t0)
    t_full = min(times)

    # the appendix's search on a small crop of parent pixels, against the full child frame
    rows, cols = np.nonzero(parent.mask)
    pick = np.linspace(0, rows.size - 1, args.crop).astype(int)
    t0 = time.perf_counter()
    br, bc, _ = nearest_bruteforce(parent, child, rows[pick], cols[pick])
    t_brute = time.perf_counter() - t0
    kr, kc, _ = nearest_kdtree(parent, child, rows[pick], cols[pick])
    agree = float(np.mean((br == kr) & (bc == kc)))
    per_pixel = t_brute / args.crop
    extrapolated = per_pixel * n_parent

    result = {
        "parent_pixels": n_parent,
        "child_pixels": int(child.mask.sum()),
        "kdtree_s": round(t_full, 3),
        "kdtree_runs_s": [round(t, 3) for t in times],
        "pairs": m.n_pairs,
        "dropped": m.dropped,
        "median_distance_mm": float(np.median(m.distance_mm)),
        "bruteforce_crop_pixels": args.crop,
        "bruteforce_crop_s": round(t_brute, 3),
        "bruteforce_per_pixel_ms": round(1e3 * per_pixel, 3),
        "bruteforce_extrapolated_s": round(extrapolated, 1),
        "speedup": round(extrapolated / t_full, 1),
        "nearest_agreement_on_crop": agree,
    }
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(f"k-d tree: {n_parent} parent px vs {result['child_pixels']} child px: "
              f"{t_full:.3f} s (best of {args.repeat}), {m.n_pairs} pairs, dropped {m.dropped}")
        print(f"brute force (appendix): {args.crop} parent px in {t_brute:.3f} s = "
              f"{1e3 * per_pixel:.2f} ms/px -> {extrapolated:.0f} s for {n_parent} px "
              f"(extrapolated)")
        print(f"ratio brute/k-d tree: {extrapolated / t_full:.0f}x; "
              f"nearest pixels agree on the crop: {100 * agree:.1f} %")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
