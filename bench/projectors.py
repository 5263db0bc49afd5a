"""Issue 26's evidence: rigs with more than one projector, nail edge to nail edge.

For each projector layout (``nail2nail.simulation.projectors.LAYOUTS``: the thesis rig, then
side projectors) and N synthetic fingers (seeds seed0 … seed0 + N − 1, the default simulator),
the finger is captured once per projector (the projectors shown in turn, 24 frames each), every
``(camera, projector)`` capture scanned with its true calibration, all scans fused
(``fuse_scans(projectors=…, cameras=…)``: pairs of one projector merged in its projector
space, pairs of one camera at the same pixel) and the finger unrolled from all of them.
Measured per layout: frames and capture time at 120 fps; coverage of the true rolled print
(``rolled_coverage`` of the scans' valid pixels: the median and the narrowest body row's
lit fraction of the nail-to-nail width, the area, the cap); merge error median / p95 of the
worst pair of each kind; the largest distance of a fused vertex from the true surface; and
with SourceAFIS (``bench/sourceafis.py``) the unrolled print against the true print as a
fraction of the true print against a re-rendered copy (issue 9's ratio), and the largest
impostor score (every unrolled print against every other finger's true print).

The captures are cached per finger and projector azimuth under ``--out`` (the thesis layout's
projector is the side layouts' first one: rendered once). Calibration (``--calibration``): the
rig's truth (default), or ``joint``: the cylinder target rendered under every projector of the
layout and every projector calibrated with the cameras in one bundle
(``calibrate_projectors_joint``, as ``nail2nail calibrate DIR --model joint`` does), or
``board``: the circle board in 8 poses, each captured under every projector, and every
projector calibrated with the cameras in one bundle (``calibrate_board``, thesis projector
model, as ``nail2nail calibrate-board`` does); made once per layout and cached under
``--out/calibration``. The board calibration's world is cam0's frame: it is moved into the
rig's world by the true pose of cam0 (one known transform) so that the fused vertices can be
compared with the true surface; its own error of cam0's pose stays in that figure.

Usage::

    .venv/bin/python bench/projectors.py [--fingers 6] [--scale 1]
        [--layouts thesis,pair-45,sides-60] [--calibration truth|joint|board] [--out DIR]
        [--no-matcher] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
import sourceafis
from _measure import log
from unroll_matcher import PPI, to_ppi, truth_print

from nail2nail.calibration.files import RigCalibration
from nail2nail.io.capture import read_capture, read_truth
from nail2nail.merge.fusion import fuse_scans
from nail2nail.scan.capture import scan_capture
from nail2nail.simulation.capture import simulate_capture
from nail2nail.simulation.projectors import LAYOUTS, projector_rigs, rolled_coverage
from nail2nail.simulation.rig import Rig, default_rig, ideal_calibration
from nail2nail.simulation.scenes import make_scene
from nail2nail.simulation.truth import surface_distance
from nail2nail.unroll import unroll_scans

FPS = 120.0
FRAMES_PER_PROJECTOR = 24


def capture_for(out: Path, rig: Rig, azimuth: float, scene, seed: int) -> Path:
    """The finger's capture under one projector, rendered once (noise seed per projector)."""
    path = out / "captures" / f"seed{seed}" / f"az{azimuth:+.0f}"
    if not (path / "capture.json").is_file():
        log(f"seed {seed}: render projector at {azimuth:+.0f} deg")
        noise_seed = 1000 * (seed + 1) + round(azimuth) % 360
        simulate_capture(path, scene, rig=rig, seed=noise_seed)
    return path


def joint_calibrations(out: Path, layout: str, scale: float) -> list:
    """Every projector of `layout` calibrated with the cameras in one bundle, from the target
    rendered under each (cached: ``out/calibration/<layout>_p<k>.json``)."""
    from nail2nail.calibration.files import load_calibration, save_calibration
    from nail2nail.calibration.markers import TargetGeometry
    from nail2nail.calibration.observe import projector_target_observations
    from nail2nail.calibration.target import calibrate_projectors_from_observations

    rigs = projector_rigs(layout, default_rig(scale))
    files = [out / "calibration" / f"{layout}_p{k}.json" for k in range(len(rigs))]
    if all(f.is_file() for f in files):
        return [load_calibration(f) for f in files]
    captures = []
    for k, rig in enumerate(rigs):
        path = out / "targets" / layout / f"p{k}"
        if not (path / "capture.json").is_file():
            log(f"{layout}: render the target under projector {k}")
            simulate_capture(path, "target", rig=rig, seed=7 + k)
        captures.append(read_capture(path, load=False))
    t0 = time.perf_counter()
    sets = projector_target_observations(captures, refine_marks=True)
    calibs, _ = calibrate_projectors_from_observations(
        sets, projector_sizes=[rig.panel_size for rig in rigs],
        surface=TargetGeometry().signed_distance, target=TargetGeometry())
    log(f"{layout}: {len(rigs)} projectors calibrated jointly in "
        f"{time.perf_counter() - t0:.0f} s")
    files[0].parent.mkdir(parents=True, exist_ok=True)
    for f, calib in zip(files, calibs, strict=True):
        save_calibration(f, calib)
    return calibs


def board_calibrations(out: Path, layout: str, scale: float, poses: int = 8) -> list:
    """Every projector of `layout` calibrated with the cameras from board poses captured under
    each (``calibrate_board``), moved into the rig's world frame (cached:
    ``out/calibration/<layout>_board_p<k>.json``)."""
    from nail2nail.calibration.board import calibrate_board
    from nail2nail.calibration.boards import default_board
    from nail2nail.calibration.files import CameraCalibration, load_calibration, save_calibration
    from nail2nail.calibration.observe import board_views
    from nail2nail.simulation.board_poses import simulate_board_captures

    base = default_rig(scale)
    rigs = projector_rigs(layout, base)
    files = [out / "calibration" / f"{layout}_board_p{k}.json" for k in range(len(rigs))]
    if all(f.is_file() for f in files):
        return [load_calibration(f) for f in files]
    root = out / "boards" / layout
    board = default_board("circles")
    if not (root / "board-poses.json").is_file():
        log(f"{layout}: render the board in {poses} poses under every projector")
        simulate_board_captures(root, poses, board=board, rig=base, seed=21,
                                projectors=layout if len(rigs) > 1 else None)
    dirs = sorted(p for p in root.iterdir() if p.is_dir())
    t0 = time.perf_counter()
    captures = board_views(dirs, board)
    result = calibrate_board(captures.views, board.object_points(), captures.camera_sizes,
                             projector_size=captures.projector_size, projector_model="thesis")
    log(f"{layout}: {len(rigs)} projectors calibrated on the board in "
        f"{time.perf_counter() - t0:.0f} s; camera rms {result.camera_rms_px}, projector "
        f"rms {result.projector_rms_by_projector_px}")
    # cam0's frame -> the rig's world: X_dev = R_d (R0 X_w + t0) + t_d
    R0, t0_ = base.cameras[0].R, base.cameras[0].t

    def in_world(m):
        return replace(m, R=m.R @ R0, t=m.R @ t0_ + m.t)

    calibs = []
    for calib in result.rig_calibrations().values():
        calib.cameras = [CameraCalibration(c.name, in_world(c.camera), in_world(c.projector),
                                           size=c.size) for c in calib.cameras]
        calibs.append(calib)
    files[0].parent.mkdir(parents=True, exist_ok=True)
    for f, calib in zip(files, calibs, strict=True):
        save_calibration(f, calib)
    return calibs


def run_layout_finger(out: Path, layout: str, seed: int, scale: float,
                      calibrations: list | None = None, kind: str = "joint") -> dict:
    base = default_rig(scale)
    rigs = projector_rigs(layout, base)
    azimuths = LAYOUTS[layout]
    scene = make_scene("finger", rig=base, seed=seed)
    scans, projectors, cameras, truths = [], [], [], []
    t0 = time.perf_counter()
    for k, (rig, az) in enumerate(zip(rigs, azimuths, strict=True)):
        path = capture_for(out, rig, az, scene, seed)
        capture = read_capture(path, load=False)
        calib = (RigCalibration.from_dict(ideal_calibration(Rig.from_capture(capture)))
                 if calibrations is None else calibrations[k])
        for i, s in enumerate(scan_capture(capture, calib)):
            scans.append(replace(s, name=f"{s.name}-p{k}") if len(rigs) > 1 else s)
            projectors.append(k)
            cameras.append(i)
            truths.append(read_truth(path, s.name))
    t_scan = time.perf_counter() - t0
    t0 = time.perf_counter()
    sup = fuse_scans(scans, projectors=projectors, cameras=cameras)
    t_fuse = time.perf_counter() - t0
    far = float(np.nanmax(np.abs(surface_distance(sup.vertices, sup.camera, sup.pixel,
                                                   truths))))
    merge = {"projector": [], "camera": []}
    for (i, j), m in sup.correspondences.items():
        if i < j and m.n_pairs:
            st = m.statistics()["distance_mm"]
            kind = "projector" if projectors[i] == projectors[j] else "camera"
            merge[kind].append((1000 * st["median"], 1000 * st["p95"], f"{i}-{j}"))
    worst = {k: ([round(max(v[0] for v in vals), 2), round(max(v[1] for v in vals), 2)]
                 if vals else None) for k, vals in merge.items()}
    cover = rolled_coverage(scene, [(s.mask, tr["param_u"], tr["param_v"])
                                    for s, tr in zip(scans, truths, strict=True)])
    t0 = time.perf_counter()
    rolled = unroll_scans(scans, ppi=PPI)
    t_unroll = time.perf_counter() - t0
    prints = out / "prints" / (layout if calibrations is None else f"{layout}-{kind}")
    prints.mkdir(parents=True, exist_ok=True)
    png = sourceafis.save_png(prints / f"seed{seed}.png", rolled.image, dpi=PPI)
    truth_dir = out / "captures" / f"seed{seed}" / f"az{azimuths[0]:+.0f}"
    image, geometry = truth_print(truth_dir)
    truth500 = to_ppi(image, 25.4 / float(geometry["pitch_mm"]))
    truth_png = sourceafis.save_png(out / "prints" / f"truth_seed{seed}.png", truth500, dpi=PPI)
    rer_png = sourceafis.save_png(out / "prints" / f"truth_seed{seed}_rerendered.png",
                                  sourceafis.rerender(truth500), dpi=PPI)
    log(f"{layout} seed {seed}: coverage {cover['width_median']:.3f} "
        f"(min {cover['width_min']:.3f}), merge {worst}, far {1000 * far:.1f} um")
    return {"seed": seed, "pattern": geometry.get("pattern"), "coverage": cover,
            "merge_worst_um": worst, "far_um": round(1000 * far, 1),
            "vertices": sup.n_vertices, "png": str(png), "truth_png": str(truth_png),
            "rerendered_png": str(rer_png),
            "seconds": {"scan": round(t_scan, 1), "fuse": round(t_fuse, 1),
                        "unroll": round(t_unroll, 1)}}


def score(results: dict) -> None:
    """SourceAFIS: each layout's prints against every finger's truth, and the reference."""
    if not sourceafis.available():
        log("matcher: skipped (needs java and mvn)")
        return
    sourceafis.build()
    keys, pairs = [], []
    for layout, fingers in results["layouts"].items():
        for i, f in enumerate(fingers):
            for j, g in enumerate(fingers):
                keys.append((layout, i, j))
                pairs.append((f["png"], g["truth_png"]))
            keys.append((layout, i, "ref"))
            pairs.append((f["truth_png"], f["rerendered_png"]))
    got = dict(zip(keys, sourceafis.score_pairs(pairs, dpi=PPI).tolist(), strict=True))
    for layout, fingers in results["layouts"].items():
        n = len(fingers)
        for i, f in enumerate(fingers):
            f["score"] = round(got[(layout, i, i)], 1)
            f["reference"] = round(got[(layout, i, "ref")], 1)
            f["ratio"] = round(f["score"] / f["reference"], 3) if f["reference"] > 0 else None
            f["max_impostor"] = (round(max(got[(layout, i, j)] for j in range(n) if j != i), 1)
                                 if n > 1 else None)


def summary(results: dict) -> list[str]:
    lines = ["| layout | projectors | frames | capture at 120 fps (s) | coverage of the nail-to-"
             "nail width, median [narrowest row] | area [cap] | merge median / p95 µm, "
             "worst pair sharing a projector | … sharing a camera | fused vertex farthest "
             "from the truth µm | matcher ratio median [worst] | max impostor |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for layout, fingers in results["layouts"].items():
        p = len(LAYOUTS[layout])
        frames = FRAMES_PER_PROJECTOR * p
        cov = [f["coverage"]["width_median"] for f in fingers]
        narrow = min(f["coverage"]["width_min"] for f in fingers)
        area = [f["coverage"]["area"] for f in fingers]
        cap = [f["coverage"]["cap_area"] for f in fingers]

        def worst(kind, fingers=fingers):
            vals = [f["merge_worst_um"][kind] for f in fingers if f["merge_worst_um"][kind]]
            if not vals:
                return "—"
            return f"{max(v[0] for v in vals):.1f} / {max(v[1] for v in vals):.1f}"

        ratios = [f.get("ratio") for f in fingers if f.get("ratio") is not None]
        imp = [f.get("max_impostor") for f in fingers if f.get("max_impostor") is not None]
        lines.append(
            f"| {layout} | {p} | {frames} | {frames / FPS:.2f} | {100 * np.median(cov):.1f} % "
            f"[{100 * narrow:.1f} %] | {100 * np.median(area):.1f} % [{100 * np.median(cap):.1f}"
            f" %] | {worst('projector')} | {worst('camera')} | "
            f"{max(f['far_um'] for f in fingers):.1f} | "
            + (f"{np.median(ratios):.2f} [{min(ratios):.2f}]" if ratios else "—")
            + (f" | {max(imp):.1f} |" if imp else " | — |"))
    return lines


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fingers", type=int, default=6)
    ap.add_argument("--seed0", type=int, default=0,
                    help="the fingers' seeds are seed0, seed0 + 1, … (default: 0)")
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--layouts", default="thesis,pair-45,sides-60")
    ap.add_argument("--calibration", choices=["truth", "joint", "board"], default="truth",
                    help="the rig's truth, or every projector calibrated with the cameras "
                    "from the rendered target (joint) or board poses (board); default: truth")
    ap.add_argument("--out", type=Path, default=Path("bench-output/projectors"))
    ap.add_argument("--no-matcher", action="store_true")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    layouts = [s.strip() for s in args.layouts.split(",") if s.strip()]
    for name in layouts:
        if name not in LAYOUTS:
            ap.error(f"--layouts: unknown layout {name!r} (known: {', '.join(LAYOUTS)})")
    start = time.perf_counter()
    results: dict = {"scale": args.scale, "fingers": args.fingers, "seed0": args.seed0,
                     "calibration": args.calibration, "layouts": {}}
    for layout in layouts:
        calibs = {"joint": joint_calibrations, "board": board_calibrations}.get(
            args.calibration, lambda *a: None)(args.out, layout, args.scale)
        results["layouts"][layout] = [run_layout_finger(args.out, layout, seed, args.scale,
                                                        calibs, args.calibration)
                                      for seed in range(args.seed0,
                                                        args.seed0 + args.fingers)]
    if not args.no_matcher:
        score(results)
    results["seconds"] = round(time.perf_counter() - start, 1)
    args.out.mkdir(parents=True, exist_ok=True)
    name = "results.json" if args.calibration == "truth" else f"results_{args.calibration}.json"
    (args.out / name).write_text(json.dumps(results, indent=1))
    if args.json:
        print(json.dumps(results, indent=1))
    else:
        print("\n".join(summary(results)))
        print(f"\n{results['seconds']:.0f} s; results in {args.out / name}")
    return results


if __name__ == "__main__":
    main()
