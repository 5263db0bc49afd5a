"""Merge error of the finger: thesis calibration, ICP alignment (Open3D), joint calibration.

Reads the scans of a demo run (``nail2nail demo --out DIR``; by default ``demo-output``, or
makes a half-scale one in a temporary directory if there is none) and prints, for camera pairs
0-1 and 1-2, the merge error measured in projector space (thesis chapter four):

- ``before``:  per-camera DLT (thesis eq. 3.11), plain patterns, projector distortion ignored;
- ``thesis_lut``: the same on patterns corrected with the appendix's look-up table;
- ``*+icp``: those scans rigidly aligned by point-to-plane ICP (cameras 0 and 2 onto 1);
- ``best``: nail2nail's joint calibration with one shared, distorted projector.

Usage: ``python bench/merge_baselines.py [DEMO_DIR]`` (needs ``pip install -e .[icp]``).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

from nail2nail.io.scans import load_scans
from nail2nail.merge import correspond
from nail2nail.merge.alignment import icp_align, transform_scan


def merge_row(scans) -> list[str]:
    cells = []
    for a, b in ((0, 1), (1, 2)):
        s = correspond(scans[a], scans[b], stride=2).statistics()["distance_mm"]
        cells.append(f"{1000 * s['median']:6.1f} / {1000 * s['p95']:6.1f}")
    return cells


def main() -> None:
    demo = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("demo-output")
    if not (demo / "scans").exists():
        from nail2nail.pipeline import run_demo

        demo = Path(tempfile.mkdtemp()) / "demo"
        print(f"no demo output given: running the demo at scale 0.5 into {demo}")
        run_demo(demo, scale=0.5, super_scan=False, figures=False)
    print(f"finger merge error, median / p95 in µm ({demo})")
    print(f"{'configuration':<16}{'0-1':>18}{'1-2':>18}{'ICP time':>10}")
    for config in ("before", "thesis_lut", "best"):
        scans = load_scans(demo / "scans" / config / "finger")
        print(f"{config:<16}" + "".join(f"{c:>18}" for c in merge_row(scans)))
        if config == "best":
            continue
        start = time.perf_counter()
        aligned = [transform_scan(scans[0], icp_align(scans[0], scans[1])), scans[1],
                   transform_scan(scans[2], icp_align(scans[2], scans[1]))]
        elapsed = time.perf_counter() - start
        print(f"{config + '+icp':<16}" + "".join(f"{c:>18}" for c in merge_row(aligned))
              + f"{elapsed:9.1f}s")


if __name__ == "__main__":
    main()
