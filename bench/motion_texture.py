"""Issue 25's diagnosis: how much of a trembling finger's shape error is its skin sliding under
the pixels, and what stabilising the frames would give if the motion were known.

Within one phase-shift group a pixel's intensities are fitted to ``a + b cos(φ + δ_k)``. On a
moving finger the skin's texture (the albedo's ridges and the relief's shading) slides under
the pixel between the steps, so ``a`` and ``b`` are not constant and the fitted phase takes an
error that follows the ridges; ``--compensate-motion`` corrects the fringes' phase offsets
between the steps (per region) but not that. This bench measures it on the virtual scanner
(the demo's finger, seed 3; tremor seed 7, as ``bench/motion.py``; half resolution; the rig's
true calibration; ``process --compensate-motion``, triangulated from both directions' phases
and from ``yp`` alone):

1. **Texture**: the same finger and trajectory rendered with its ridges (albedo contrast and
   relief, the default), with the relief alone, and with neither (a smooth, uniform skin);
2. **Oracle stabilisation**: the ridged capture's finest groups (the 6-step ones) warped with
   the *true* per-frame image motion of the skin (from ``truth/motion.json``, the true surface
   and the cameras' true models), relative to the group's mean position, then each pixel's
   ``a, b, φ`` fitted with the fringe's shift that the warp itself puts in
   (``∇φ · d_k``) and the frames re-synthesised with the nominal shifts; then the usual
   ``--compensate-motion``. Also with the motion reduced to one affine map per frame and
   camera (six numbers), the model an estimator would fit.

3. **The library's stabilisation** (``--stabilise-motion``, :mod:`nail2nail.scan.stabilise`):
   the motion measured from the frames alone, on the ridged, the textureless and the still
   capture.

Figures per row: all scans' 3D RMS against the true surface after one rigid alignment
(``bench/motion.py``'s ``aligned_rms``, µm) and the worst reported pair's merge median (µm; as
the job paired them, and in brackets by both projector coordinates where it paired by one).

Usage::

    .venv/bin/python bench/motion_texture.py [--amplitude 100] [--scale 0.5]
        [--out bench-output/motion_texture]
    # held out: random conditions, each its own tremor; compensation against stabilisation
    .venv/bin/python bench/motion_texture.py --conditions 6 --seed0 600
    # one camera registered, the others made to skip: the motion transfer against none
    .venv/bin/python bench/motion_texture.py --one-camera

Cost (half resolution, two cores): four captures of every frame intersected anew, about
5 minutes each on one core (two at a time), then ten ``process`` jobs of about a minute.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import scipy.ndimage as ndi

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _measure import log
from motion import (
    FINGER_SEED,
    MOTION_SEED,
    aligned_rms,
    job_pairings,
    merge_by_both_coordinates,
)

#: the captures: name, scene options, tremor on
CAPTURES = {
    "ridged": ({}, True),
    "relief only": ({"albedo_contrast": 0.0}, True),
    "no texture": ({"albedo_contrast": 0.0, "relief_height": 0.0}, True),
    "still": ({}, False),
}


def simulate_one(job: dict) -> str:
    """Render one capture (in a worker process); returns its directory."""
    from nail2nail.scan.patterns import default_pattern_set, make_patterns
    from nail2nail.simulation.capture import simulate, write_capture
    from nail2nail.simulation.motion import tremor
    from nail2nail.simulation.rig import default_rig
    from nail2nail.simulation.scenes import make_scene

    out = Path(job["dir"])
    if (out / "capture.json").is_file():
        return str(out)
    seed, motion_seed = FINGER_SEED, MOTION_SEED
    if job.get("condition") is None:
        rig = default_rig(job["scale"])
        scene = make_scene("finger", rig=rig, seed=seed, **job["scene"])
    else:  # a random condition of the virtual scanner, its own tremor
        from nail2nail.simulation.conditions import draw_conditions

        seed = motion_seed = job["condition"]
        cond = draw_conditions(seed)
        rig = cond.rig(job["scale"])
        scene = make_scene("finger", rig=rig, seed=seed, **cond.finger_options())
    motion = tremor(24, amplitude_mm=job["amplitude_um"] / 1000, blur_steps=2,
                    exposure_s=1 / 240, seed=motion_seed) if job["moving"] else None
    pattern_set = default_pattern_set()
    t0 = time.perf_counter()
    sim = simulate(scene, rig=rig, patterns=make_patterns(pattern_set), pattern_set=pattern_set,
                   seed=seed, motion=motion, motion_cache={})
    write_capture(out, sim, seed=seed)
    log(f"simulated {out.parent.name}: {time.perf_counter() - t0:.0f} s")
    return str(out)


def true_flow(capture_dir: Path, camera: str, *, affine: bool = False) -> np.ndarray:
    """``(n_frames, H, W, 2)`` image motion ``(dx, dy)``, px, of the skin each pixel sees at the
    reference pose, at every frame's pose (``truth/motion.json``), through the camera's true
    pinhole model; pixels off the finger take their nearest finger pixel's. `affine`: each
    frame's motion replaced by its least-squares affine map over the finger's pixels."""
    from scipy.spatial.transform import Rotation

    calib = json.loads((capture_dir / "truth" / "calibration.json").read_text())
    model = next(c["camera"] for c in calib["cameras"] if c["name"] == camera)
    K, R, t = (np.array(model[k], float) for k in ("K", "R", "t"))
    motion = json.loads((capture_dir / "truth" / "motion.json").read_text())
    center = np.array(motion["center_mm"], float)
    truth = np.load(capture_dir / "truth" / f"{camera}.npz")
    on = truth["mask"] & np.isfinite(truth["xyz"]).all(axis=-1)
    X0 = np.where(on[..., None], truth["xyz"], 0.0)

    def project(X):
        p = (X @ R.T + t) @ K.T
        return p[..., :2] / p[..., 2:]

    p0 = project(X0)
    flow = np.stack([
        project((X0 - center) @ Rotation.from_rotvec(f["rotvec_rad"]).as_matrix().T + center
                + np.array(f["translation_mm"])) - p0
        for f in motion["frames"]])
    _, (ri, ci) = ndi.distance_transform_edt(~on, return_indices=True)
    flow = flow[:, ri, ci]
    if affine:
        h, w = on.shape
        yy, xx = np.mgrid[0:h, 0:w].astype(float)
        design = np.stack([np.ones(on.sum()), xx[on], yy[on]], axis=1)
        full = np.stack([np.ones(h * w), xx.ravel(), yy.ravel()], axis=1)
        for k in range(len(flow)):
            coef, *_ = np.linalg.lstsq(design, flow[k][on], rcond=None)  # (3, 2)
            flow[k] = (full @ coef).reshape(h, w, 2)
    return flow


def stabilise_with_flow(frames: np.ndarray, pattern_set, flow: np.ndarray) -> np.ndarray:
    """Frames whose finest (≥ 4-step) groups are warped by `flow` relative to the group's mean
    position and re-synthesised with the nominal shifts (the warp's own fringe shift
    ``∇φ · d_k`` in each pixel's fit): :func:`~nail2nail.scan.stabilise.stabilise_frames`'s
    last step, with the true motion and each group to its own mean time."""
    from nail2nail.scan.motion import dc_groups, fit_pixel_shifts
    from nail2nail.scan.patterns import frame_table
    from nail2nail.scan.stabilise import _warp, phase_gradient

    table = frame_table(pattern_set)
    values = frames.astype(np.float64)
    out = values.copy()
    for _, idx in dc_groups(pattern_set):
        if len(idx) < 4 or table[idx[0]].kind != "phase":
            continue
        nominal = np.array([table[i].shift for i in idx])[:, None, None]
        group = values[idx]
        d = flow[idx] - flow[idx].mean(axis=0, keepdims=True)  # (n, H, W, 2): dx, dy
        warped = np.stack([_warp(g, dk[..., 1], dk[..., 0])
                           for g, dk in zip(group, d, strict=True)])
        _, c, s = fit_pixel_shifts(group, nominal)
        gy, gx = phase_gradient(c, s)
        a2, c2, s2 = fit_pixel_shifts(warped, nominal + gy * d[..., 1] + gx * d[..., 0])
        out[idx] = a2 + c2 * np.cos(nominal) - s2 * np.sin(nominal)
    top = np.iinfo(frames.dtype).max
    return np.clip(np.rint(out), 0, top).astype(frames.dtype)


def oracle_capture(source: Path, target: Path, *, affine: bool) -> Path:
    """A copy of the capture at `source` whose frames are stabilised with the true motion."""
    from PIL import Image

    from nail2nail.io.capture import read_capture

    if (target / "capture.json").is_file():
        return target
    tmp = target.with_name(target.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(source, tmp)
    capture = read_capture(source, load=False)
    manifest = json.loads((source / "capture.json").read_text())
    for camera in manifest["cameras"]:
        frames = capture.load_frames(camera["name"], raw=True)
        flow = true_flow(source, camera["name"], affine=affine)
        for path, image in zip(camera["frames"], stabilise_with_flow(
                frames, capture.pattern_set, flow), strict=True):
            Image.fromarray(image).save(tmp / path)
    tmp.rename(target)
    return target


def process_one(job: dict) -> dict:
    """``process --compensate-motion`` (both directions, or ``yp`` alone) and the figures."""
    from nail2nail.calibration.files import RigCalibration
    from nail2nail.process import process_capture
    from nail2nail.simulation.rig import default_rig, ideal_calibration

    capture_dir, job_dir = Path(job["capture"]), Path(job["dir"])
    if not (job_dir / "process.json").is_file():
        rig = default_rig(job["scale"])
        if job.get("condition") is not None:
            from nail2nail.simulation.conditions import draw_conditions

            rig = draw_conditions(job["condition"]).rig(job["scale"])
        calib = RigCalibration.from_dict(ideal_calibration(rig))
        options: dict = {"decode_options": {"compensate_motion": True}}
        if job["use"] == "yp":
            options["use"] = "yp"
        elif job["use"] == "stabilised":
            options = {"decode_options": {"stabilise_motion": True}}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the motion warning
            process_capture(str(capture_dir), calib, job_dir, unroll=False, **options)
    summary = json.loads((job_dir / "process.json").read_text())
    merge = [v["distance_mm"]["median"] for v in summary["merge"].values()]
    thesis = [m["median"] for m in merge_by_both_coordinates(job_dir, job_dir.parent / (
        job_dir.name + "_merge_xpyp"))]
    return {"row": job["row"], "use": job["use"],
            "aligned": aligned_rms(capture_dir, job_dir),
            "merge_median_um": round(1000 * max(merge), 1),
            "pair_by": job_pairings(job_dir),
            "merge_xpyp_median_um": round(1000 * max(thesis), 1)}


def forced_skip_one(job: dict) -> dict:
    """``--stabilise-motion`` with the cameras ``job["skip"]`` (indices) made to skip, as a
    camera whose texture does not register does; ``job["transfer"]``: whether they take the
    registered cameras' motion (the library's default) or keep their frames (as before)."""
    import nail2nail.scan.capture as capture_module

    real, calls = capture_module.stabilise_frames, {"n": 0}

    def stabilise(frames, pattern_set, **options):
        out, info = real(frames, pattern_set, **options)
        if options.get("motion") is None:  # the first pass, one call per camera in order
            k, calls["n"] = calls["n"], calls["n"] + 1
            if k in job["skip"]:
                return frames.copy(), {**{key: info[key] for key in ("reference", "direction")},
                                       "skipped": "made to skip (bench)"}
        return out, info

    capture_module.stabilise_frames = stabilise
    if not job["transfer"]:
        capture_module._motion_from_other_cameras = lambda scans, calibration: []
    return process_one(job)


def merge_cell(result: dict) -> str:
    """The worst pair's merge median, µm, and in brackets the thesis's pairing by both projector
    coordinates where the job paired by one."""
    cell = f"{result['merge_median_um']:.1f}"
    if result.get("pair_by", ["xpyp"]) != ["xpyp"]:
        cell += f" [{result['merge_xpyp_median_um']:.1f}]"
    return cell


def run_jobs(work: list[dict], workers: int, path: Path, one=process_one) -> dict:
    """`one` (:func:`process_one`) of every job, written to `path`; ``{(row, use): result}``."""
    with ProcessPoolExecutor(workers, max_tasks_per_child=1) as pool:
        results = list(pool.map(one, work))
    path.write_text(json.dumps(results, indent=1))
    return {(r["row"], r["use"]): r for r in results}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--amplitude", type=float, default=100.0, help="tremor RMS, µm")
    p.add_argument("--scale", type=float, default=0.5)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("bench-output/motion_texture"))
    p.add_argument("--conditions", type=int, default=0,
                   help="instead: this many random conditions of the virtual scanner (seeds "
                   "from --seed0, each its own tremor), the compensation against the "
                   "stabilisation")
    p.add_argument("--seed0", type=int, default=600)
    p.add_argument("--one-camera", action="store_true",
                   help="instead: the ridged capture stabilised with all but one camera made "
                   "to skip, with and without the motion taken from the registered camera")
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.conditions:
        return held_out(args)
    if args.one_camera:
        return one_camera(args)
    jobs = [{"dir": str(args.out / name.replace(" ", "_") / "capture"), "scene": scene,
             "moving": moving, "amplitude_um": args.amplitude, "scale": args.scale}
            for name, (scene, moving) in CAPTURES.items()]
    with ProcessPoolExecutor(args.workers) as pool:
        captures = dict(zip(CAPTURES, pool.map(simulate_one, jobs), strict=True))
    ridged = Path(captures["ridged"])
    for tag, affine in (("oracle", False), ("oracle_affine", True)):
        captures[tag] = str(oracle_capture(ridged, ridged.parent.parent / tag / "capture",
                                           affine=affine))
    labels = {"ridged": "ridged (default finger)", "relief only": "relief, no albedo contrast",
              "no texture": "no relief, no albedo contrast", "still": "ridged, still",
              "oracle": "ridged, stabilised with the true motion",
              "oracle_affine": "ridged, stabilised with the true motion's affine map per frame"}
    work = [{"row": key, "capture": path, "use": use, "scale": args.scale,
             "dir": str(Path(path).parent / f"job_{use}")}
            for key, path in captures.items() for use in ("xpyp", "yp")]
    # the library's stabilisation, the motion measured from the frames (``--stabilise-motion``)
    work += [{"row": key, "capture": captures[key], "use": "stabilised", "scale": args.scale,
              "dir": str(Path(captures[key]).parent / "job_stabilised")}
             for key in ("ridged", "no texture", "still")]
    by = run_jobs(work, args.workers, args.out / "results.json")
    print(f"\nTremor {args.amplitude:g} µm RMS (10 Hz band, 120 fps), scale {args.scale:g}, "
          "`--compensate-motion`:\n")
    print("| capture | 3D RMS after alignment, µm: xpyp / yp | merge median, worst pair, µm: "
          "xpyp / yp |")
    print("| --- | --- | --- |")
    for key in captures:
        a, b = by[(key, "xpyp")], by[(key, "yp")]
        print(f"| {labels[key]} | {a['aligned']['rms_um']:.1f} / {b['aligned']['rms_um']:.1f} "
              f"| {merge_cell(a)} / {merge_cell(b)} |")
    for key in ("ridged", "no texture", "still"):
        c = by[(key, "stabilised")]
        used = "/".join(c.get("pair_by", ["xpyp"]))  # auto: what they were triangulated from
        print(f"| {labels[key]}, `--stabilise-motion` ({used}) | {c['aligned']['rms_um']:.1f} "
              f"(p95 {c['aligned']['p95_um']:.1f}) | {merge_cell(c)} |")
    return 0


def one_camera(args) -> int:
    """The ridged capture (made first if missing) with one camera registered and the other two
    made to skip: the motion taken from the one against frames left to the compensation."""
    job = {"dir": str(args.out / "ridged" / "capture"), "scene": CAPTURES["ridged"][0],
           "moving": True, "amplitude_um": args.amplitude, "scale": args.scale}
    capture = simulate_one(job)
    work = [{"row": kept, "capture": capture, "use": "stabilised", "scale": args.scale,
             "skip": [k for k in range(3) if k != kept], "transfer": transfer,
             "dir": str(args.out / "one_camera" / f"cam{kept}_{'on' if transfer else 'off'}")}
            for kept in range(3) for transfer in (True, False)]
    with ProcessPoolExecutor(args.workers, max_tasks_per_child=1) as pool:
        results = list(pool.map(forced_skip_one, work))
    (args.out / "one_camera.json").write_text(json.dumps(results, indent=1))
    print("\n| camera registered | motion taken from it: aligned / worst merge µm | "
          "frames left to the compensation |")
    print("| --- | --- | --- |")
    for kept in range(3):
        a, b = results[2 * kept], results[2 * kept + 1]
        print(f"| cam{kept} | {a['aligned']['rms_um']:.1f} / {merge_cell(a)} | "
              f"{b['aligned']['rms_um']:.1f} / {merge_cell(b)} |")
    return 0


def held_out(args) -> int:
    """Random conditions (optics, skin, finger, print, pose) each trembling with its own
    trajectory: ``--compensate-motion`` (both directions and ``yp``) against
    ``--stabilise-motion``."""
    seeds = range(args.seed0, args.seed0 + args.conditions)
    jobs = [{"dir": str(args.out / f"c{seed}" / "capture"), "scene": {}, "moving": True,
             "condition": seed, "amplitude_um": args.amplitude, "scale": args.scale}
            for seed in seeds]
    with ProcessPoolExecutor(args.workers) as pool:
        captures = list(pool.map(simulate_one, jobs))
    work = [{"row": seed, "capture": path, "use": use, "scale": args.scale, "condition": seed,
             "dir": str(Path(path).parent / f"job_{use}")}
            for seed, path in zip(seeds, captures, strict=True)
            for use in ("xpyp", "yp", "stabilised")]
    by = run_jobs(work, args.workers, args.out / "held_out.json")
    print(f"\nRandom conditions {args.seed0}–{args.seed0 + args.conditions - 1}, tremor "
          f"{args.amplitude:g} µm RMS, scale {args.scale:g}: 3D RMS after alignment / merge "
          "median of the worst pair, µm\n")
    print("| condition | --compensate-motion | --compensate-motion --use yp | "
          "--stabilise-motion |")
    print("| --- | --- | --- | --- |")
    for seed in seeds:
        rows = [by[(seed, u)] for u in ("xpyp", "yp", "stabilised")]
        cells = [f"{r['aligned']['rms_um']:.1f} / {merge_cell(r)}" for r in rows]
        print(f"| {seed} | " + " | ".join(cells) + " |")
    for u in ("xpyp", "yp", "stabilised"):
        a = [by[(seed, u)]["aligned"]["rms_um"] for seed in seeds]
        m = [by[(seed, u)]["merge_median_um"] for seed in seeds]
        t = [by[(seed, u)].get("merge_xpyp_median_um", np.nan) for seed in seeds]
        print(f"{u}: aligned median {np.median(a):.1f} worst {max(a):.1f}; merge median "
              f"{np.median(m):.1f} worst {max(m):.1f} (paired by xp, yp: median "
              f"{np.median(t):.1f} worst {max(t):.1f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
