"""Benchmark: render the full default rig (3 cameras x 24 frames, full resolution).

Usage::

    .venv/bin/python bench/render.py [--scene finger] [--scale 1.0] [--threads 2]

Prints the time of the ray geometry (intersections, shadows, panel coordinates: once per
camera) and of the frames (projector radiance, bilinear sampling, blur, noise, quantisation).
Target: under 60 s in total on a 2-core machine.
"""

from __future__ import annotations

import argparse
import os
import time


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="finger")
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()


    from nail2nail.scan.patterns import default_pattern_set, make_patterns
    from nail2nail.simulation.render import camera_geometry, projector_radiance, render_frames
    from nail2nail.simulation.rig import default_rig
    from nail2nail.simulation.scenes import make_scene

    t0 = time.perf_counter()
    rig = default_rig(args.scale)
    scene = make_scene(args.scene, rig=rig, seed=args.seed)
    patterns = make_patterns(default_pattern_set())
    t_scene = time.perf_counter() - t0
    t_geom = t_frames = 0.0
    t = time.perf_counter()
    radiance = [projector_radiance(p, rig.photometry) for p in patterns]
    t_rad = time.perf_counter() - t
    n_pixels = 0
    for i in range(len(rig.cameras)):
        t = time.perf_counter()
        geom = camera_geometry(rig, scene, i)
        t_geom += time.perf_counter() - t
        t = time.perf_counter()
        frames = render_frames(geom, patterns, rig.photometry, seed=args.seed, camera_index=i,
                               scale=rig.scale, radiance=radiance)
        t_frames += time.perf_counter() - t
        n_pixels += geom.surface.size
        assert frames.shape == (len(patterns), *geom.shape)
    total = t_geom + t_rad + t_frames
    w, h = rig.cameras[0].size
    print(f"scene {args.scene}, {len(rig.cameras)} cameras x {len(patterns)} frames at "
          f"{w}x{h} (scale {args.scale}), CPUs visible: {os.cpu_count()}")
    print(f"scene setup (fingerprint growth etc.): {t_scene:6.2f} s")
    print(f"geometry (3 cameras):                  {t_geom:6.2f} s")
    print(f"projector radiance ({len(patterns)} patterns):       {t_rad:6.2f} s")
    n_frames = len(rig.cameras) * len(patterns)
    print(f"frames ({n_frames}):                           "
          f"{t_frames:6.2f} s  ({1e3 * t_frames / n_frames:.0f} ms/frame)")
    print(f"render total (geometry + frames):      {total:6.2f} s   [target < 60 s]")
    print(f"with scene setup:                      {total + t_scene:6.2f} s")


if __name__ == "__main__":
    main()
