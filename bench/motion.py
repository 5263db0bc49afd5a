"""Issue 25's evidence: a trembling finger, what it does to the scans and the print, and the check.

Two parts, both on the virtual scanner with the rig's true calibration (so that the figures
measure motion, not calibration):

1. **Strategies against tremor amplitude.** One finger (the demo's, seed 3) trembles rigidly
   (:func:`nail2nail.simulation.motion.tremor`: 8–12 Hz, translation RMS 0, 25, 50, 100, 200 µm,
   rotation by default, 120 frames per second, exposure 1/240 s in 2 sub-steps for the motion
   blur, reference pose at the middle frame). Each pattern set (*strategy*) is shown from the
   first frame on, so the shorter ones see less of the same trajectory; the per-frame geometry
   is shared between them. Per amplitude and strategy: ``process`` (scan, merge, unroll), then
   the 3D RMS of every camera's points against the true surface at the reference pose (the
   same pixel's ray, pixels valid in both; and after one rigid alignment of all the scans to
   the truth, which takes out the pose the finger had at the frames' mean time), the points
   kept (fraction of the still capture's),
   the merge median and p95 (pairs that share the projector; as the job paired them, and
   by both projector coordinates, the thesis's pairing), the motion the check measured,
   and SourceAFIS score(unrolled print, true print) as a fraction of the still finger's under
   the same strategy.
2. **No false alarm.** Still captures under random conditions (seeds that no tuning used,
   :func:`nail2nail.simulation.conditions.draw_conditions`), wearing synthetic prints and
   (``--still-real``) the real impression ``probe.png`` of ``../shared/data/prints``, whose
   skin below and beside the impression has no ridges: the largest motion the check reads,
   against its threshold (0.02 mm).

Usage::

    .venv/bin/python bench/motion.py [--scale 0.5] [--amplitudes 0,25,50,100,200]
        [--still 20] [--still-real 10] [--workers 2] [--out bench-output/motion]
        [--plot docs/img/motion.png]

``--amplitudes none`` runs the still captures alone (about 15 s each).

Cost (half resolution, two cores): every moving frame is intersected anew (3 cameras × 24
frames × 2 sub-steps, about 1.5 s each), about 4 minutes of one core per amplitude; the jobs
and the matcher about 2 minutes; the still captures about 15 s each.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import sourceafis
from _measure import log
from sourceafis import PRINTS

FINGER_SEED = 3
MOTION_SEED = 7
STILL_SEED0 = 500
STILL_REAL_SEED0 = 540


def strategies() -> dict:
    """``name: (pattern set, process_capture options, index of the strategy whose capture it
    reuses)``."""
    from nail2nail.scan.patterns import Frequency, PatternSet, default_pattern_set

    three = (Frequency(1, 3), Frequency(8, 3), Frequency(64, 3))
    return {
        "pmp-24 (default: 1/8/64 periods, 3/3/6 steps, x and y)":
            (default_pattern_set(), {}, 0),
        "pmp-18 (1/8/64 periods, 3 steps each, x and y)":
            (PatternSet(x=three, y=three, gamma=2.2), {}, 1),
        "pmp-18 + compensation (frequencies registered, --compensate-motion)":
            (PatternSet(x=three, y=three, gamma=2.2),
             {"decode_options": {"compensate_motion": True}}, 1),
        "pmp-24 + compensation (per-frame offsets, frequencies registered, --compensate-motion)":
            (default_pattern_set(), {"decode_options": {"compensate_motion": True}}, 0),
        "pmp-24, yp only (triangulated from one direction's phase: one time, --use yp)":
            (default_pattern_set(), {"use": "yp"}, 0),
        "pmp-24 + compensation, yp only (--compensate-motion --use yp)":
            (default_pattern_set(), {"use": "yp", "decode_options": {"compensate_motion": True}},
             0),
        "pmp-24 + stabilisation (frames resampled to one time from the skin's texture, "
        "then compensated, yp: --stabilise-motion)":
            (default_pattern_set(), {"decode_options": {"stabilise_motion": True}}, 0),
    }


def scan_rms(capture_dir: Path, job_dir: Path) -> dict:
    """3D RMS of each camera's points against the true surface (same pixel), and points kept."""
    from nail2nail.io.capture import read_truth
    from nail2nail.io.scans import load_scans

    out = {}
    for scan in load_scans(job_dir / "scans"):
        truth = read_truth(capture_dir, scan.name)
        both = scan.mask & truth["mask"] & np.isfinite(truth["xyz"]).all(axis=-1)
        d = np.linalg.norm(scan.xyz[both].astype(np.float64) - truth["xyz"][both], axis=-1)
        out[scan.name] = {"rms_um": round(1000 * float(np.sqrt(np.mean(d**2))), 2),
                          "p95_um": round(1000 * float(np.percentile(d, 95)), 2),
                          "valid": int(scan.mask.sum())}
    out["aligned"] = aligned_rms(capture_dir, job_dir)
    return out


def aligned_rms(capture_dir: Path, job_dir: Path, *, n_fit: int = 30000,
                n_eval: int = 300000, iterations: int = 10) -> dict:
    """RMS point-to-plane distance of all the scans' points to the true surface after one rigid
    alignment (point-to-plane ICP against the truth's points and normals): the scans' shape
    error without the pose the finger had at the frames' time, µm."""
    from scipy.spatial import cKDTree

    from nail2nail.io.capture import read_truth
    from nail2nail.io.scans import load_scans

    pts, tru, nrm = [], [], []
    for scan in load_scans(job_dir / "scans"):
        truth = read_truth(capture_dir, scan.name)
        ok = truth["mask"] & np.isfinite(truth["xyz"]).all(axis=-1)
        tru.append(truth["xyz"][ok])
        nrm.append(truth["normal"][ok].astype(np.float64))
        pts.append(scan.xyz[scan.mask].astype(np.float64))
    T, N, S = np.concatenate(tru), np.concatenate(nrm), np.concatenate(pts)
    tree = cKDTree(T)
    rng = np.random.default_rng(0)
    fit = S[rng.choice(len(S), min(n_fit, len(S)), replace=False)]
    R, t = np.eye(3), np.zeros(3)
    for _ in range(iterations):
        moved = fit @ R.T + t
        _, j = tree.query(moved)
        n, q = N[j], T[j]
        r = np.einsum("ij,ij->i", moved - q, n)
        A = np.column_stack([np.cross(moved, n), n])
        x, *_ = np.linalg.lstsq(A, -r, rcond=None)
        w, dt = x[:3], x[3:]
        dR = np.array([[1, -w[2], w[1]], [w[2], 1, -w[0]], [-w[1], w[0], 1]])
        u, _, vt = np.linalg.svd(dR)
        dR = u @ vt
        R, t = dR @ R, dR @ t + dt
    ev = S[rng.choice(len(S), min(n_eval, len(S)), replace=False)] @ R.T + t
    _, j = tree.query(ev)
    d = np.einsum("ij,ij->i", ev - T[j], N[j])
    angle = np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))
    return {"rms_um": round(1000 * float(np.sqrt(np.mean(d**2))), 2),
            "p95_um": round(1000 * float(np.percentile(np.abs(d), 95)), 2),
            "pose_shift_um": round(1000 * float(np.linalg.norm(t)), 1),
            "pose_turn_deg": round(float(angle), 4)}


def run_amplitude(job: dict) -> list[dict]:
    """Every strategy under one amplitude (in a worker process)."""
    from nail2nail.calibration.files import RigCalibration
    from nail2nail.process import process_capture
    from nail2nail.scan.patterns import make_patterns
    from nail2nail.simulation.capture import simulate, write_capture
    from nail2nail.simulation.motion import tremor
    from nail2nail.simulation.rig import default_rig, ideal_calibration
    from nail2nail.simulation.scenes import make_scene

    rig = default_rig(job["scale"])
    scene = make_scene("finger", rig=rig, seed=FINGER_SEED)
    calib = RigCalibration.from_dict(ideal_calibration(rig))
    amplitude = job["amplitude_um"] / 1000
    motion = tremor(24, amplitude_mm=amplitude, blur_steps=2, exposure_s=1 / 240,
                    seed=MOTION_SEED) if amplitude > 0 else None
    cache: dict = {}
    rows = []
    for k, (name, (pattern_set, options, source)) in enumerate(strategies().items()):
        base = Path(job["out"]) / f"a{job['amplitude_um']:03d}_s{k}"
        capture_dir = Path(job["out"]) / f"a{job['amplitude_um']:03d}_s{source}" / "capture"
        job_dir = base / "job"
        t0 = time.perf_counter()
        if not (capture_dir / "capture.json").is_file():
            patterns = make_patterns(pattern_set)
            sim = simulate(scene, rig=rig, patterns=patterns, pattern_set=pattern_set,
                           seed=FINGER_SEED, motion=motion, motion_cache=cache)
            write_capture(capture_dir, sim, seed=FINGER_SEED)
        t_sim = time.perf_counter() - t0
        if not (job_dir / "process.json").is_file():
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the motion warning: measured below
                process_capture(str(capture_dir), calib, job_dir, **options)
        summary = json.loads((job_dir / "process.json").read_text())
        merge = [v["distance_mm"] for key, v in summary["merge"].items()]
        thesis = merge_by_both_coordinates(job_dir, base / "merge_xpyp")
        rows.append({
            "amplitude_um": job["amplitude_um"], "strategy": name, "strategy_index": k,
            "frames": pattern_set.n_frames, "span_s": round(pattern_set.n_frames / 120, 4),
            "simulate_s": round(t_sim, 1),
            "scan": scan_rms(capture_dir, job_dir),
            "merge_median_um": [round(1000 * m["median"], 2) for m in merge],
            "merge_p95_um": [round(1000 * m["p95"], 2) for m in merge],
            "pair_by": job_pairings(job_dir),
            "merge_xpyp_median_um": [round(1000 * m["median"], 2) for m in thesis],
            "merge_xpyp_p95_um": [round(1000 * m["p95"], 2) for m in thesis],
            "motion": summary.get("motion"),
            "print": str(job_dir / "print" / "print.png"),
            "truth": str(capture_dir / "truth" / "rolled_print.png"),
        })
        log(f"{job['amplitude_um']} µm, {name.split(' ')[0]}: motion "
            f"{(summary.get('motion') or {}).get('motion_mm')} mm, 3D RMS "
            f"{[c['rms_um'] for c in rows[-1]['scan'].values()]} µm")  # the last: aligned
    return rows


def job_pairings(job_dir: Path) -> list[str]:
    """What the job's merge paired its cameras by (``merge.json`` → ``pair_by`` of each pair;
    a merge written before the field paired by both coordinates, ``"xpyp"``)."""
    merged = json.loads((job_dir / "merge" / "merge.json").read_text())["merge"]
    return sorted({v.get("pair_by", "xpyp") for v in merged.values()})


def merge_by_both_coordinates(job_dir: Path, out: Path) -> list[dict]:
    """The job's merge statistics with the thesis's pairing, by both projector coordinates
    (``pair_by="xpyp"``), whatever the job paired by: its pairs' ``distance_mm``."""
    from nail2nail.io.scans import load_scans
    from nail2nail.merge import write_merge

    merged = write_merge(load_scans(job_dir / "scans"), out, figures=False, data=False,
                         super_scan=False, pair_by="xpyp")
    return [v["distance_mm"] for v in merged["merge"].values()]


def run_still(job: dict) -> dict:
    """The motion check on a still capture under random conditions (in a worker process)."""
    from nail2nail.calibration.files import RigCalibration
    from nail2nail.io.capture import read_capture
    from nail2nail.scan.capture import motion_summary, scan_capture
    from nail2nail.simulation.capture import simulate_capture
    from nail2nail.simulation.conditions import draw_conditions
    from nail2nail.simulation.rig import ideal_calibration
    from nail2nail.simulation.scenes import make_scene

    seed = job["seed"]
    cond = draw_conditions(seed)
    rig = cond.rig(job["scale"])
    real = bool(job.get("real"))
    capture_dir = Path(job["out"]) / f"still{'_real' if real else ''}{seed}"
    if not (capture_dir / "capture.json").is_file():
        image = None
        if real:
            from nail2nail.io.prints import read_print_image

            image, _ = read_print_image(PRINTS / "probe.png")
        scene = make_scene("finger", rig=rig, seed=seed,
                           **cond.finger_options(print_image=image))
        simulate_capture(capture_dir, scene, rig=rig, seed=seed, write_truth=False)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scans = scan_capture(read_capture(capture_dir, load=False),
                             RigCalibration.from_dict(ideal_calibration(rig)))
    summary = motion_summary(scans) or {}
    return {"seed": seed, "print": "probe.png" if real else "synthetic", **summary,
            "cameras": {s.name: (s.motion or {}).get("motion_mm") for s in scans}}


def score_prints(rows: list[dict]) -> None:
    """SourceAFIS score of every print against its truth, and the fraction of the still's."""
    if not sourceafis.available():
        log("SourceAFIS: Java or Maven missing, no scores")
        return
    pairs = [(r["print"], r["truth"]) for r in rows]
    scores = sourceafis.score_pairs(pairs, dpi=500)
    still = {r["strategy"]: s for r, s in zip(rows, scores, strict=True)
             if r["amplitude_um"] == 0}
    for r, s in zip(rows, scores, strict=True):
        r["score"] = round(float(s), 1)
        base = still.get(r["strategy"])
        r["score_fraction"] = round(float(s) / base, 3) if base else None


def plot(path: Path, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 4.6))
    names = list(dict.fromkeys(r["strategy"] for r in rows))
    colours = plt.get_cmap("tab10")
    for i, name in enumerate(names):
        mine = sorted((r for r in rows if r["strategy"] == name), key=lambda r: r["amplitude_um"])
        a = [r["amplitude_um"] for r in mine]
        style = {"color": colours(i), "marker": "o", "label": name.split(" (")[0]}
        axes[0].plot(a, [max(c["rms_um"] for k, c in r["scan"].items() if k != "aligned")
                         for r in mine], "-", **style)
        style.pop("label")
        axes[0].plot(a, [r["scan"]["aligned"]["rms_um"] for r in mine], "--", **style)
        axes[1].plot(a, [max(r["merge_median_um"]) for r in mine], "-", **style)
        if any(r.get("pair_by", ["xpyp"]) != ["xpyp"] for r in mine):  # and the thesis's
            axes[1].plot(a, [max(r["merge_xpyp_median_um"]) for r in mine], ":", **style)
        axes[2].plot(a, [r.get("score_fraction") or 0 for r in mine], "-", **style)
    axes[0].set_ylabel("3D RMS (µm): worst camera vs truth (solid),\nall scans after a rigid "
                       "alignment (dashed)")
    axes[0].set_yscale("log")
    axes[1].set_ylabel("merge median, worst pair (µm): as paired (solid),\nby both "
                       "projector coordinates (dotted, scans of yp)")
    axes[2].set_ylabel("print score / the still finger's")
    for ax in axes:
        ax.set_xlabel("tremor RMS (µm; 8–12 Hz, 120 fps)")
        ax.grid(alpha=0.3)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="lower center", ncol=3, fontsize=8,
               frameon=False)
    fig.tight_layout(rect=(0, 0.12, 1, 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def markdown(rows: list[dict], still: list[dict]) -> str:
    lines = ["| strategy | frames (s at 120 fps) | tremor RMS µm | motion read (mm) | 3D RMS µm "
             "(cameras) | points kept | merge median / p95 µm (paired by) | the same paired by "
             "(xp, yp) | print score (of still) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    valid0 = {r["strategy"]: {c: v["valid"] for c, v in r["scan"].items() if c != "aligned"}
              for r in rows if r["amplitude_um"] == 0}
    for r in sorted(rows, key=lambda r: (r["strategy_index"], r["amplitude_um"])):
        cams = {c: v for c, v in r["scan"].items() if c != "aligned"}
        kept = min(v["valid"] / max(valid0[r["strategy"]][c], 1) for c, v in cams.items())
        rms = " / ".join(f"{c['rms_um']:.1f}" for c in cams.values())
        rms += f" ({r['scan']['aligned']['rms_um']:.1f} aligned)"
        lines.append(
            f"| {r['strategy'].split(' (')[0]} | {r['frames']} ({r['span_s']:.3f}) "
            f"| {r['amplitude_um']} | {(r['motion'] or {}).get('motion_mm')} "
            f"| {rms} "
            f"| {100 * kept:.0f} % "
            f"| {max(r['merge_median_um']):.1f} / {max(r['merge_p95_um']):.1f} "
            f"({', '.join(r['pair_by'])}) "
            f"| {max(r['merge_xpyp_median_um']):.1f} / {max(r['merge_xpyp_p95_um']):.1f} "
            f"| {r.get('score', '—')} ({r.get('score_fraction', '—')}) |")
    for kind in ("synthetic", "probe.png"):
        group = [s for s in still if s.get("print", "synthetic") == kind]
        if not group:
            continue
        mm = [s.get("motion_mm") or 0.0 for s in group]
        flagged = sum(bool(s.get("moving")) for s in group)
        lines += ["", f"Still captures wearing {kind} under {len(group)} random conditions "
                  f"(seeds {group[0]['seed']}–{group[-1]['seed']}): motion read median "
                  f"{1000 * float(np.median(mm)):.1f} µm, largest {1000 * max(mm):.1f} µm "
                  f"(threshold 20 µm); flagged {flagged}."]
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scale", type=float, default=0.5)
    p.add_argument("--amplitudes", default="0,25,50,100,200", help="tremor RMS, µm")
    p.add_argument("--still", type=int, default=20, help="still captures under random conditions")
    p.add_argument("--still-real", type=int, default=10,
                   help="still captures wearing probe.png under random conditions")
    p.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1))
    p.add_argument("--out", type=Path, default=Path("bench-output/motion"))
    p.add_argument("--plot", type=Path, help="write the figure here (PNG)")
    p.add_argument("--replot", action="store_true",
                   help="only redraw --plot from OUT/results.json")
    args = p.parse_args(argv)
    if args.replot:
        plot(args.plot, json.loads((args.out / "results.json").read_text())["rows"])
        return 0
    amplitudes = [] if args.amplitudes.strip().lower() in ("", "none") \
        else [int(a) for a in args.amplitudes.split(",")]
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    jobs = [{"amplitude_um": a, "scale": args.scale, "out": str(args.out)}
            for a in sorted(amplitudes, reverse=True)]  # the slowest first
    still_jobs = [{"seed": STILL_SEED0 + i, "scale": args.scale, "out": str(args.out)}
                  for i in range(args.still)]
    still_jobs += [{"seed": STILL_REAL_SEED0 + i, "scale": args.scale, "out": str(args.out),
                    "real": True} for i in range(args.still_real)]
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=max(1, args.workers), mp_context=context) as pool:
        futures = [pool.submit(run_amplitude, j) for j in jobs]
        still_futures = [pool.submit(run_still, j) for j in still_jobs]
        rows = [r for f in futures for r in f.result()]
        still = [f.result() for f in still_futures]
    score_prints(rows)
    result = {"rows": rows, "still": still, "seconds": round(time.perf_counter() - t0, 1),
              "scale": args.scale}
    (args.out / "results.json").write_text(json.dumps(result, indent=1))
    if args.plot and rows:
        plot(args.plot, rows)
    print(markdown(rows, still))
    print(f"\n{result['seconds']:.0f} s in all; results in {args.out / 'results.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
