"""Benchmark: decode + unwrap + triangulate throughput on a full default capture, vs ``fringes``.

A full default capture is 3 cameras x 24 frames of 1280 x 1024 (portrait) 8-bit images. The
frames come from the virtual scanner (finger scene, projector distortion off) when it is
available, else from an analytic synthetic scene (``--source synthetic``). For every camera the
fused numba kernel (:func:`nail2nail.scan.kernels.decode_fast`) reads the 24 frames as stored,
unwraps
the 1/8/64-period phases in x and y, runs the neighbourhood checks and triangulates what
``nail2nail scan`` triangulates: both projector coordinates in least squares on the camera rays,
float64 (:func:`nail2nail.scan.triangulation.ray_table`, once per calibration) -- ``ours``. Also
timed: decoding alone, and ``yp`` through the per-pixel rational table of
:func:`nail2nail.scan.triangulation.triangulation_table` (the look-up table of Liu et al., Opt.
Express 18 (2010) 5229). Throughput counts every camera pixel processed (Mpoints/s); the valid
share is printed too, and the fast path's deviations from the NumPy reference on camera 0
(decoded coordinates; points against the float64 reference triangulation of the same
coordinates).

In the same run the PyPI package ``fringes`` (2.1.0, ``pip install -e .[bench]``) decodes the same
frames with the same frequency/step structure (its temporal unwrapping; no triangulation); the
ratios of its decoding time to ours are printed.

Usage::

    .venv/bin/python bench/decode.py                # simulator frames, 7 repeats, fringes too
    .venv/bin/python bench/decode.py --source synthetic --no-fringes --json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

from nail2nail.scan.decoding import decode
from nail2nail.scan.kernels import decode_fast, planar_table
from nail2nail.scan.patterns import default_pattern_set, frame_table, make_patterns
from nail2nail.scan.triangulation import ray_table, reconstruct_image, triangulation_table

SHAPE = (1280, 1024)  # camera (H, W)


def synthetic_capture(pattern_set, n_cameras=3, shape=SHAPE, seed=0):
    """Frames of an analytic smooth surface, photometry like the virtual scanner's, plus tables.

    Returns frames (list of (24, H, W) uint8) and per-camera DLT pairs (camera, projector).
    """
    rng = np.random.default_rng(seed)
    h, w = shape
    wp, hp = pattern_set.panel_size
    r, c = np.mgrid[0:h, 0:w].astype(np.float32)
    frames, matrices = [], []
    for cam in range(n_cameras):
        s, t = c / (w - 1), r / (h - 1)
        xp = 40 + (wp - 80) * (s + 0.03 * np.sin(3 * t + cam)) / 1.03
        yp = 30 + (hp - 60) * (t + 0.02 * np.cos(2 * s + cam)) / 1.02
        albedo = 0.5 + 0.1 * np.cos(9 * s) * np.sin(7 * t)
        stack = np.empty((pattern_set.n_frames, h, w), np.uint8)
        for info in frame_table(pattern_set):
            size = pattern_set.axis_size(info.direction)
            u = xp if info.direction == "x" else yp
            phi = 2 * np.pi * info.periods * (u + 0.5) / size
            value = 0.85 * albedo * (0.03 + 0.5 + 0.5 * np.cos(phi - info.shift))
            noisy = value + np.sqrt(value / 20000.0) * rng.standard_normal(value.shape, np.float32)
            stack[info.index] = np.clip(np.rint(255 * noisy), 0, 255).astype(np.uint8)
        frames.append(stack)
        mc = np.array([[3200.0, 0, 0, 512 + 40 * cam], [0, -3200, 0, 640], [0, 0, 0.0, 1.0]])
        mc[2, 2] = -1 / 150.0
        mp = np.array([[2000.0, 0, 600, 640], [0, -2000, 900, 520], [0, 0, -1 / 160.0, 1.0]])
        matrices.append((mc, mp))
    return frames, matrices, None


def simulator_capture(pattern_set, seed=0):
    """Frames of the virtual scanner's finger (full scale, projector distortion off)."""
    from nail2nail.calibration.camera_models import dlt_from_pinhole
    from nail2nail.simulation.render import camera_geometry, projector_radiance, render_frames
    from nail2nail.simulation.rig import default_rig
    from nail2nail.simulation.scenes import make_scene

    rig = default_rig(1.0, projector_distortion="none")
    scene = make_scene("finger", rig=rig, seed=seed)
    patterns = make_patterns(pattern_set)
    radiance = [projector_radiance(p, rig.photometry) for p in patterns]
    frames, matrices, truth = [], [], []
    for i, camera in enumerate(rig.cameras):
        geometry = camera_geometry(rig, scene, i)
        frames.append(render_frames(geometry, patterns, rig.photometry, seed=seed,
                                    camera_index=i, radiance=radiance))
        matrices.append((dlt_from_pinhole(camera), dlt_from_pinhole(rig.projector)))
        truth.append(geometry)
    return frames, matrices, truth


def time_ours(frames, pattern_set, variants, repeat, **options):
    """Best times of each variant (name -> tables per camera), interleaved repeat by repeat so
    that a busy machine slows them alike: ``{name: (outputs, wall times, cpu times)}``."""
    outs = {name: [decode_fast(f, pattern_set, table=t, **options)
                   for f, t in zip(frames, tables, strict=True)]
            for name, tables in variants.items()}
    times = {name: ([], []) for name in variants}
    for _ in range(repeat):
        for name, tables in variants.items():
            t0, c0 = time.perf_counter(), time.process_time()
            for f, t, o in zip(frames, tables, outs[name], strict=True):
                decode_fast(f, pattern_set, table=t, out=o, **options)
            times[name][0].append(time.perf_counter() - t0)
            times[name][1].append(time.process_time() - c0)
    return {name: (outs[name], *times[name]) for name in variants}


def time_fringes(frames, pattern_set, n_cameras):
    import logging

    logging.getLogger("fringes").setLevel(logging.ERROR)
    import fringes

    x = pattern_set.frequencies("x")
    f = fringes.Fringes(
        X=pattern_set.panel_size[0], Y=pattern_set.panel_size[1], K=len(x),
        N=tuple(tuple(q.steps for q in pattern_set.frequencies(d)) for d in ("x", "y")),
        v=tuple(tuple(q.periods for q in pattern_set.frequencies(d)) for d in ("x", "y")),
    )
    f.decode(frames[0][:, :32, :32, None])  # compile (numba, cached by fringes)
    t0 = time.perf_counter()
    for stack in frames[:n_cameras]:
        f.decode(stack[..., None])
    return (time.perf_counter() - t0) * len(frames) / n_cameras


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", choices=["auto", "simulator", "synthetic"], default="auto")
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--no-fringes", action="store_true")
    parser.add_argument("--fringes-cameras", type=int, default=3,
                        help="cameras fringes decodes (its time is scaled to all cameras)")
    parser.add_argument("--max-gradient", type=float, default=2.0,
                        help="decode option (panel px per camera px); default 2 (full scale)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)

    ps = default_pattern_set()
    t0 = time.perf_counter()
    source = args.source
    if source in ("auto", "simulator"):
        try:
            frames, matrices, truth = simulator_capture(ps)
            source = "simulator"
        except ImportError:
            if source == "simulator":
                raise
            source = "synthetic"
    if source == "synthetic":
        frames, matrices, truth = synthetic_capture(ps)
    t_frames = time.perf_counter() - t0
    shape = frames[0].shape[1:]
    rays = [ray_table(mc, mp, shape) for mc, mp in matrices]  # what scan triangulates
    tables = [planar_table(triangulation_table(mc, mp, shape, axis="y")) for mc, mp in matrices]
    n_points = sum(f.shape[1] * f.shape[2] for f in frames)

    options = {"max_gradient": args.max_gradient}
    timed = time_ours(frames, ps, {"rays": rays, "decode": [None] * len(frames),
                                   "table": tables}, args.repeat, **options)
    outs, times, cpu = timed["rays"]
    best, best_dec, best_tab = (min(timed[k][1]) for k in ("rays", "decode", "table"))
    valid = int(sum(o.mask.sum() for o in outs))

    # fast path against the NumPy reference (camera 0)
    ref = decode(frames[0], ps, **options)
    fast = outs[0]
    both = ref.mask & fast.mask
    max_dev = float(max(np.abs(ref.xp - fast.xp)[both].max(),
                        np.abs(ref.yp - fast.yp)[both].max()))
    points = reconstruct_image(*matrices[0], fast.xp, fast.yp)  # float64 reference, same input
    result = {
        "source": source, "cameras": len(frames), "frames_per_camera": ps.n_frames,
        "camera_shape": list(shape), "threads": _threads(),
        "cpu_count": os.cpu_count(), "frames_seconds": round(t_frames, 1),
        "ours_seconds_best": best, "ours_seconds_median": float(np.median(times)),
        "ours_mpoints_per_s": n_points / best / 1e6,
        "ours_cpu_seconds_best": min(cpu),
        "ours_decode_only_seconds_best": best_dec,
        "ours_decode_only_mpoints_per_s": n_points / best_dec / 1e6,
        "ours_table_yp_seconds_best": best_tab,
        "ours_table_yp_mpoints_per_s": n_points / best_tab / 1e6,
        "valid_fraction": valid / n_points,
        "fast_vs_reference_mask_differences": int(np.count_nonzero(ref.mask != fast.mask)),
        "fast_vs_reference_max_px": max_dev,
        "fast_vs_reference_triangulation_max_mm": float(
            np.abs(fast.xyz[fast.mask] - points[fast.mask]).max()),
    }
    if truth is not None:
        errs = []
        for o, g in zip(outs, truth, strict=True):
            m = o.mask & g.mask
            errs.append([float(np.sqrt(np.mean((o.xp - g.xp)[m] ** 2))),
                         float(np.sqrt(np.mean((o.yp - g.yp)[m] ** 2))),
                         float(max(np.abs(o.xp - g.xp)[m].max(), np.abs(o.yp - g.yp)[m].max()))])
        result["rms_xp_yp_maxabs_vs_truth_px"] = errs
    if not args.no_fringes:
        t_fr = time_fringes(frames, ps, max(1, min(args.fringes_cameras, len(frames))))
        result["fringes_seconds"] = t_fr
        result["fringes_mpoints_per_s"] = n_points / t_fr / 1e6
        result["speedup_vs_fringes"] = t_fr / best
        result["speedup_vs_fringes_decode_only"] = t_fr / best_dec
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        for key, value in result.items():
            print(f"{key:40s} {value:.4g}" if isinstance(value, float) else f"{key:40s} {value}")
    return 0


def _threads() -> int:
    import numba

    return numba.get_num_threads()


if __name__ == "__main__":
    sys.exit(main())
