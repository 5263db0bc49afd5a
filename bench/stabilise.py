"""Benchmark: ``stabilise_frames`` per camera, compiled against its NumPy formulation.

Usage::

    .venv/bin/python bench/stabilise.py [--capture DIR] [--repeats 3]

The stabiliser (``nail2nail.scan.stabilise``, ``--stabilise-motion``) registers the skin's
texture images with an affine Gauss–Newton fit and resamples every frame. Its warp and the fit's
normal equations are compiled; the peer, in the same run, is the same stabiliser with those two
pieces in their NumPy formulation (``scipy.ndimage.map_coordinates`` of the displacement images,
``np.gradient`` and the ``(6, P)`` Jacobian), which is what they were before. Per camera: the
seconds of each (medians of `repeats`, after one warm-up) and whether the frames agree (they
must, to the grey level).

Without ``--capture`` it uses ``bench-output/motion/a100_s0/capture`` (``bench/motion.py``'s
demo finger trembling at 100 µm RMS, half resolution) when it is there, else renders that
capture into a temporary directory first (about 4 minutes on one core).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.ndimage as ndi

sys.path.insert(0, str(Path(__file__).resolve().parent))

DEFAULT_CAPTURE = Path("bench-output/motion/a100_s0/capture")


def render(out: Path) -> Path:
    """The demo finger (seed 3) trembling at 100 µm RMS (tremor seed 7), half resolution."""
    from motion import FINGER_SEED, MOTION_SEED

    from nail2nail.scan.patterns import default_pattern_set, make_patterns
    from nail2nail.simulation.capture import simulate, write_capture
    from nail2nail.simulation.motion import tremor
    from nail2nail.simulation.rig import default_rig
    from nail2nail.simulation.scenes import make_scene

    rig = default_rig(0.5)
    scene = make_scene("finger", rig=rig, seed=FINGER_SEED)
    pattern_set = default_pattern_set()
    motion = tremor(24, amplitude_mm=0.1, blur_steps=2, exposure_s=1 / 240, seed=MOTION_SEED)
    sim = simulate(scene, rig=rig, patterns=make_patterns(pattern_set), pattern_set=pattern_set,
                   seed=FINGER_SEED, motion=motion, motion_cache={})
    write_capture(out, sim, seed=FINGER_SEED)
    return out


def numpy_warp(image, params):
    """The warp's NumPy formulation: the displacement images, then ``map_coordinates``."""
    from nail2nail.scan.stabilise import _affine_basis

    d = np.einsum("jb,bhw->jhw", params, _affine_basis(image.shape))
    rows, cols = np.mgrid[0:image.shape[0], 0:image.shape[1]].astype(np.float64)
    return ndi.map_coordinates(image, [rows + d[0], cols + d[1]], order=1, mode="nearest")


def numpy_register(image, reference, weight, iterations=None):
    """The Gauss–Newton fit's NumPy formulation (``np.gradient``, the ``(6, P)`` Jacobian)."""
    from nail2nail.scan.stabilise import ITERATIONS, _affine_basis

    params = np.zeros((2, 3))
    sel = weight > 0
    w = weight[sel]
    b = _affine_basis(image.shape)[:, sel]
    for _ in range(ITERATIONS if iterations is None else iterations):
        moved = numpy_warp(image, params)
        gy, gx = np.gradient(moved)
        jac = np.concatenate([gy[sel] * b, gx[sel] * b])
        normal = (jac * w) @ jac.T
        normal += 1e-6 * np.trace(normal) / 6 * np.eye(6)
        step = np.linalg.solve(normal, (jac * w) @ (reference[sel] - moved[sel])).reshape(2, 3)
        params += np.clip(step, -2.0, 2.0)
        if np.max(np.abs(step)) < 1e-4:
            break
    return params


def timed(run, repeats: int) -> tuple[float, np.ndarray]:
    out = run()  # warm-up: compiled kernels loaded
    seconds = []
    for _ in range(repeats):
        start = time.perf_counter()
        out = run()
        seconds.append(time.perf_counter() - start)
    return statistics.median(seconds), out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--capture", type=Path, help="a capture of a moving finger (default: "
                        f"{DEFAULT_CAPTURE}, rendered when missing)")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)

    import nail2nail.scan.stabilise as stabilise
    from nail2nail.io.capture import read_capture
    from nail2nail.scan.inputs import SATURATION

    with tempfile.TemporaryDirectory(prefix="nail2nail-bench-") as tmp:
        capture_dir = args.capture or DEFAULT_CAPTURE
        if not (capture_dir / "capture.json").is_file():
            if args.capture is not None:
                raise SystemExit(f"{capture_dir}: not a capture (no capture.json)")
            print(f"rendering the trembling demo finger into {tmp} (about 4 minutes)")
            capture_dir = render(Path(tmp) / "capture")
        capture = read_capture(capture_dir, load=False)
        compiled = (stabilise._warp_affine, stabilise._register_affine)
        print(f"capture: {capture_dir}; seconds per camera, medians of {args.repeats}")
        print(f"{'camera':<8}{'compiled':>10}{'NumPy':>10}{'ratio':>8}  frames equal")
        for name in capture.camera_names:
            frames = capture.load_frames(name, raw=True)
            top = 2 ** capture.bit_depth - 1

            def run(frames=frames, top=top):
                return stabilise.stabilise_frames(frames, capture.pattern_set,
                                                  saturation=SATURATION * top)[0]

            t_fast, fast = timed(run, args.repeats)
            stabilise._warp_affine, stabilise._register_affine = numpy_warp, numpy_register
            try:
                t_peer, peer = timed(run, args.repeats)
            finally:
                stabilise._warp_affine, stabilise._register_affine = compiled
            equal = bool(np.array_equal(fast, peer))
            print(f"{name:<8}{t_fast:10.2f}{t_peer:10.2f}{t_peer / t_fast:8.2f}  {equal}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
