"""Benchmark: pattern schemes compared on the virtual finger against the simulator's truth.

For every scheme (the default multi-frequency PMP set; Gray code + 4-step phase shifting with
and without the complementary Gray-code bit; Gray code + line shifting; a 3-step set with a
1-period cue as other systems use) the virtual scanner renders the same finger (same rays, same
noise seed; projector distortion off, so that only decoding differs) and every camera is
scanned as ``nail2nail scan`` scans it (:func:`nail2nail.scan.capture.scan_frames`, the ideal
calibration, ``max_gradient`` 2 scaled to the camera size, ``use="xpyp"``; the Gray-code schemes
by the NumPy path, PMP by the fused kernel). Printed per scheme, all cameras pooled over the
pixels valid in the scan and in the truth:

- frames: the number of projected frames;
- valid: valid pixels, share of the pixels that see the lit finger in the truth;
- decoded ``xp``/``yp`` error against the truth's projector coordinates (``truth/camN.npz``):
  RMS, 99th percentile and the number of pixels off by 1 projector px or more (Euclidean);
- 3D: RMS distance of the points to the true surface along its normal, µm;
- seconds to decode and triangulate the three cameras.

Usage::

    .venv/bin/python bench/schemes.py               # full resolution (scale 1)
    .venv/bin/python bench/schemes.py --scale 0.5 --json
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from nail2nail.calibration.files import RigCalibration
from nail2nail.scan.capture import gradient_limit, scan_frames
from nail2nail.scan.patterns import (
    PatternSet,
    default_pattern_set,
    gray_code_pattern_set,
    gray_line_pattern_set,
    gray_phase_pattern_set,
)
from nail2nail.simulation.capture import simulate
from nail2nail.simulation.rig import default_rig, ideal_calibration
from nail2nail.simulation.scenes import make_scene


def schemes() -> dict[str, PatternSet]:
    """The pattern sets compared, by label."""
    cue = [(1, 3), (16, 3)]
    return {
        "PMP 1/8/64 (default)": default_pattern_set(),
        "Gray + 4-step phase, complementary": gray_phase_pattern_set(),
        "Gray + 4-step phase, no complementary": gray_phase_pattern_set(complementary=False),
        "Gray + line shift (w = 8)": gray_line_pattern_set(),
        "Gray code alone (w = 2, all-lit + all-dark)": gray_code_pattern_set(stripe=2),
        "Gray code alone (w = 2, inverse frames)": gray_code_pattern_set(stripe=2,
                                                                          reference="inverse"),
        "3-step 16 + 1-period cue": PatternSet(x=cue, y=cue, gamma=2.2),
    }


def measure(scale: float, seed: int) -> list[dict]:
    rig = default_rig(scale, projector_distortion="none")
    scene = make_scene("finger", rig=rig, seed=seed)
    calib = RigCalibration.from_dict(ideal_calibration(rig))
    rows, geometry = [], None
    for label, ps in schemes().items():
        sim = simulate(scene, rig=rig, pattern_set=ps, seed=seed, geometry=geometry)
        geometry = sim.geometry
        errors, distances, valid, lit, seconds = [], [], 0, 0, 0.0
        for name, frames in sim.frames.items():
            truth = sim.geometry[name]
            start = time.perf_counter()
            scan = scan_frames(frames, ps, calib.camera(name),
                               max_gradient=gradient_limit(2.0, frames.shape))
            seconds += time.perf_counter() - start
            ok = scan.mask & truth.mask
            valid += int(ok.sum())
            lit += int(truth.mask.sum())
            errors.append(np.hypot(scan.xp[ok] - truth.xp[ok], scan.yp[ok] - truth.yp[ok]))
            distances.append(1000 * np.sum((scan.xyz[ok] - truth.xyz[ok]) * truth.normal[ok],
                                           axis=-1))
        err = np.concatenate(errors)
        dist = np.concatenate(distances)
        rows.append({
            "scheme": label, "frames": ps.n_frames, "valid_share": valid / lit,
            "rms_px": float(np.sqrt(np.mean(err**2))), "p99_px": float(np.percentile(err, 99)),
            "off_by_1px": int(np.count_nonzero(err >= 1.0)),
            "rms_3d_um": float(np.sqrt(np.mean(dist.astype(np.float64) ** 2))),
            "seconds": seconds,
        })
        print(f"  {label}: done", file=sys.stderr, flush=True)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=1.0, help="camera scale (default 1)")
    parser.add_argument("--seed", type=int, default=3, help="finger and noise seed (default 3)")
    parser.add_argument("--json", action="store_true", help="print JSON rows")
    args = parser.parse_args(argv)
    rows = measure(args.scale, args.seed)
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    print(f"virtual finger, scale {args.scale:g}, seed {args.seed}, projector distortion off, "
          "3 cameras pooled")
    print(f"| {'scheme':39s} | frames | valid | xp/yp RMS px | p99 px | >= 1 px | "
          "3D RMS µm | s |")
    print("|" + "---|" * 8)
    for r in rows:
        print(f"| {r['scheme']:39s} | {r['frames']:6d} | {100 * r['valid_share']:4.1f} % | "
              f"{r['rms_px']:12.4f} | {r['p99_px']:6.3f} | {r['off_by_1px']:7d} | "
              f"{r['rms_3d_um']:9.2f} | {r['seconds']:.1f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
