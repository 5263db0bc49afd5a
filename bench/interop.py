"""Issue 22's evidence: the print on data the project did not tune on, scored by a real matcher.

Every finger is a *random condition* of the virtual scanner
(:func:`nail2nail.simulation.conditions.draw_conditions`: projector focus and pixel fill, gamma
against the patterns' pre-compensation, camera blur, ambient light, specular highlights,
subsurface spread, noise, skin albedo and ridge contrast, ridge height, finger section, cap,
taper, tilt, roll, yaw and position), drawn from seeds that no tuning used: the print's
parameters were tuned on condition seeds 0–19; this bench draws from 100 up (synthetic prints
of every class) and 200 up (the real impression ``probe.png`` of ``../shared/data/prints``
wrapped around the finger). The calibration is the demo's "best" (joint, on the cylindrical
target) under the default optics, made once and cached: the rig's geometry is the same for
every condition, its optics are not.

Per finger, at full resolution: simulate (with ``truth/``), scan, unroll with the default
options and with the fixed relief + albedo blend of earlier versions (``before``), and measure

- the geometry against the true skin coordinates (``unroll.accuracy.geometric_accuracy``):
  local scale error and displacement p95 over the finger's body (true ``v`` below the cap's
  base) and, apart, over the tip's cap;
- SourceAFIS scores (``bench/sourceafis.py``, threshold 40 = FMR 0.01 %): the unrolled print
  against its true print (genuine) and against every other finger's (impostor), and the
  *ceiling*: the ideal print of the skin this rig saw (the true print cut to the scanned area)
  against the true print. A real-print finger is scored against ``matching.png`` (another
  impression of the same finger; ``probe.png`` against it scores 235.6) and
  ``nonmatching.png``;
- where the score is lost: the true print brought through the default print's own geometry
  and mask (``unroll_matcher.truth_through_print``: perfect ridges, our map and data region)
  against the true print, as a fraction of the ceiling (what geometry and coverage cost; the
  rest, to the unrolled print's ratio, is the ridge signal's), and the print's area against
  the ideal crop's;
- the synthetic true prints against each other: the impostor scores the print generator gives
  before any scanning, the floor under the unrolled prints' impostors.

From these: genuine and impostor distributions, FNMR at threshold 40 and at the threshold of
FMR 10⁻³ (the impostors' 99.9th percentile), a DET plot (``--det docs/img/interop_det.png``),
and per finger the ratio unrolled / ceiling. Writes ``results.json`` and prints a Markdown
summary.

Usage::

    .venv/bin/python bench/interop.py [--fingers 40] [--real 10] [--workers 2] [--scale 1]
        [--out bench-output/interop] [--det docs/img/interop_det.png] [--no-matcher]

Cost (full resolution, two cores, two workers): calibration 70 s once, then about 70 s of one
core per finger (simulation 30–55 s, scan 8 s, two unrolls and the geometry 15 s) and a minute
of SourceAFIS for all comparisons: 40 + 10 fingers in about 35 minutes. Captures are kept under
``--out`` and reused by a rerun.
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
import unroll_matcher as um
from _measure import log
from sourceafis import PRINTS

SYNTHETIC_SEED0 = 100
REAL_SEED0 = 200
THRESHOLD = 40.0
PROBE_VS_MATCHING = 235.6  # SourceAFIS 3.18.1, measured by the issue
#: what the default options are compared with (``--before``): the fixed relief + albedo blend
#: of earlier versions (no clarity mix, no mask, no phase-locked fit), or the default options
#: without the phase-locked fit alone, or the print's length counted from the scan's top row
#: instead of the estimated fingertip, or the grey print without its unsharp mask, or the
#: albedo deshaded before mixing (``unroll.mixing.deshade_albedo``, off by default)
BEFORE = {
    "fixed-blend": {"mix": False, "min_clarity": None, "ridge_options": {"fringe_harmonics": 0},
                    "sharpen": 0.0},
    "no-fringe-fit": {"ridge_options": {"fringe_harmonics": 0}},
    "scan-top": {"estimate_tip": False},
    "no-sharpen": {"sharpen": 0.0},
    "local-polarity": {"polarity": "local"},
    "deshade": {"deshade": True},
}


def body_and_cap(rolled, scans, uv, y0: float, acc: dict) -> dict:
    """Scale error and displacement p95 over the body (true ``v ≤ y0``) and the cap."""
    v_sum, n = um.splat_on_print(rolled, scans, uv, lambda tu, tv: tv)
    with np.errstate(invalid="ignore"):
        v_map = v_sum / n
    out = {}
    for part, sel in (("body", v_map <= y0), ("cap", v_map > y0)):
        scale = acc["scale_error_map"][sel & np.isfinite(acc["scale_error_map"])]
        disp = acc["displacement_map"][sel & np.isfinite(acc["displacement_map"])]
        out[part] = {
            "scale_error_p95": round(float(np.percentile(scale, 95)), 5) if scale.size else None,
            "scale_error_median": round(float(np.median(scale)), 5) if scale.size else None,
            "displacement_p95_mm": round(float(np.percentile(disp, 95)), 5) if disp.size
            else None,
        }
    return out


def run_finger(job: dict) -> dict:
    """Simulate, scan, unroll and measure one finger (in a worker process)."""
    from nail2nail.calibration.files import load_calibration
    from nail2nail.io.capture import read_capture
    from nail2nail.io.prints import read_print_image
    from nail2nail.scan.capture import scan_capture
    from nail2nail.simulation.capture import simulate_capture
    from nail2nail.simulation.conditions import draw_conditions
    from nail2nail.simulation.scenes import make_scene
    from nail2nail.unroll import unroll_scans
    from nail2nail.unroll.accuracy import geometric_accuracy

    out = Path(job["dir"])
    seed = job["seed"]
    cond = draw_conditions(seed)
    cap = out / "capture"
    t0 = time.perf_counter()
    if not (cap / "capture.json").is_file():
        rig = cond.rig(job["scale"])
        image = None
        if job["print"]:
            image, _ = read_print_image(job["print"])
        scene = make_scene("finger", rig=rig, seed=seed, **cond.finger_options(print_image=image))
        simulate_capture(cap, scene, rig=rig, seed=seed)
    t_sim = time.perf_counter() - t0
    calib = load_calibration(job["calibration"])
    scans = scan_capture(read_capture(cap, load=False), calib)
    truth, geometry = um.truth_print(cap)
    sourceafis.save_png(out / "truth.png", truth)
    uv = um.truth_uv(cap, scans)
    crop, crop_info = um.truth_crop(truth, geometry, scans, uv)
    sourceafis.save_png(out / "ideal.png", crop)
    sampler = um.make_truth_sampler(truth, geometry)
    y0 = json.loads((cap / "capture.json").read_text())["scene"]["y0"]
    result = {"name": out.name, "seed": seed, "print": job["print"] or cond.finger["pattern"],
              "conditions": cond.to_dict(), "simulate_s": round(t_sim, 1), "ideal": crop_info}
    for tag, options in (("default", {}), ("before", BEFORE[job["before"]])):
        t1 = time.perf_counter()
        rolled = unroll_scans(scans, **options)
        t_unroll = time.perf_counter() - t1
        sourceafis.save_png(out / f"print_{tag}.png", rolled.image)
        if tag == "default":
            # perfect ridges through this print's geometry and mask: what those cost
            sourceafis.save_png(out / "truth_through_print.png",
                                um.truth_through_print(rolled, scans, uv, sampler))
        acc = geometric_accuracy(rolled, scans, uv, truth_sampler=sampler, maps=True)
        meta = rolled.metadata()
        result[tag] = {
            "unroll_s": round(t_unroll, 2),
            # the one similarity the local figures are taken after (its scale: the print's
            # global scale error, which the local scale error does not show)
            "similarity": acc["similarity"],
            "scale_error_p95": acc["scale_error"]["p95"],
            "displacement_p95_mm": acc["displacement_mm"]["p95"],
            **body_and_cap(rolled, scans, uv, y0, acc),
            "clarity_median": meta["quality"]["clarity_median"],
            "gate": meta["quality"].get("gate"),
            "print_size_mm": meta["print_size_mm"],
            "print_area_mm2": meta["print_area_mm2"],
        }
    return result


def det_points(genuine, impostor):
    """``(fmr, fnmr)`` over every threshold between the scores."""
    t = np.unique(np.concatenate([genuine, impostor, [np.inf]]))
    fmr = np.array([(impostor >= x).mean() for x in t])
    fnmr = np.array([(genuine < x).mean() for x in t])
    return fmr, fnmr


def plot_det(path: Path, curves: dict, thresholds: dict) -> None:
    """Score distributions (genuine and impostor, per variant) and the DET curves."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (hist, det) = plt.subplots(1, 2, figsize=(10, 4.2), dpi=110)
    bins = np.logspace(0, 3.2, 50)
    for (label, (genuine, impostor)), color in zip(curves.items(), ("C0", "C1"), strict=False):
        hist.hist(np.maximum(impostor, 1), bins=bins, color=color, alpha=0.35,
                  label=f"impostor, {label}")
        hist.hist(np.maximum(genuine, 1), bins=bins, color=color, histtype="step", lw=2,
                  label=f"genuine, {label}")
    hist.axvline(40, color="k", ls="--", lw=1, label="threshold 40 (FMR 0.01 %)")
    hist.set_xscale("log")
    hist.set_yscale("log")
    hist.set_xlabel("SourceAFIS score (under 1 drawn at 1)")
    hist.set_ylabel("comparisons")
    hist.set_title("scores: unrolled print vs true prints")
    hist.legend(fontsize=7)
    floor = 1e-4
    for label, (genuine, impostor) in curves.items():
        fmr, fnmr = det_points(np.asarray(genuine), np.asarray(impostor))
        det.step(np.maximum(fmr, floor), np.maximum(fnmr, floor), where="post", label=label)
    for label, (fmr, fnmr) in thresholds.items():
        det.plot(max(fmr, floor), max(fnmr, floor), "o", label=label)
    det.set_xscale("log")
    det.set_yscale("log")
    det.set_xlim(floor, 1)
    det.set_ylim(floor, 1)
    det.set_xlabel("false match rate (0 drawn at 1e-4)")
    det.set_ylabel("false non-match rate (0 drawn at 1e-4)")
    det.set_title("DET, held-out conditions")
    det.grid(True, which="both", alpha=0.3)
    det.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def replot(results_json: Path, path: Path) -> None:
    """:func:`plot_det` from a ``results.json`` of an earlier run."""
    summary = json.loads(results_json.read_text())["summary"]
    d, b = summary["default"], summary["before"]
    plot_det(path, {"default": (d["_genuine"], d["_impostor"]),
                    "before (fixed blend)": (b["_genuine"], b["_impostor"])},
             {"threshold 40, default": (d["fmr_at_40"], d["fnmr_at_40"])})


def score(results: list[dict], out: Path, *, imageio_grey: bool = False) -> dict:
    """Every SourceAFIS comparison, in one JVM run; the figures of the issue."""
    synthetic = [r for r in results if not r["print"].endswith(".png")]
    real = [r for r in results if r["print"].endswith(".png")]
    pairs, keys = [], []

    def add(a, b, key):
        pairs.append((a, b))
        keys.append(key)

    for i, r in enumerate(synthetic):
        d = out / r["name"]
        add(d / "ideal.png", d / "truth.png", ("ceiling", i))
        add(d / "truth_through_print.png", d / "truth.png", ("through", i))
        for tag in ("default", "before"):
            for j, s in enumerate(synthetic):
                add(d / f"print_{tag}.png", out / s["name"] / "truth.png", (tag, i, j))
        for j, s in enumerate(synthetic):  # the generator's own impostors: truth against truth
            if j != i:
                add(d / "truth.png", out / s["name"] / "truth.png", ("truths", i, j))
    for k, r in enumerate(real):
        d = out / r["name"]
        # the real finger's ceiling: probe.png cut to the skin this rig saw, and through the
        # default print's geometry and mask, against the other impression
        add(d / "ideal.png", PRINTS / "matching.png", ("real", "ideal", k, "matching"))
        add(d / "truth_through_print.png", PRINTS / "matching.png",
            ("real", "through", k, "matching"))
        for tag in ("default", "before"):
            add(d / f"print_{tag}.png", PRINTS / "matching.png", ("real", tag, k, "matching"))
            add(d / f"print_{tag}.png", PRINTS / "nonmatching.png",
                ("real", tag, k, "nonmatching"))
    add(PRINTS / "probe.png", PRINTS / "matching.png", ("probe",))
    t0 = time.perf_counter()
    values = sourceafis.score_pairs(pairs, imageio_grey=imageio_grey)
    scores = dict(zip(keys, (float(v) for v in values), strict=True))
    summary: dict = {"matcher_s": round(time.perf_counter() - t0, 1),
                     "probe_vs_matching": scores[("probe",)]}
    n = len(synthetic)
    truths = [scores[("truths", i, j)] for i in range(n) for j in range(n) if i != j]
    if truths:
        # how far the synthetic prints resemble one another before any scanning: the floor
        # under the unrolled prints' impostor scores
        summary["truth_impostor_max"] = max(truths)
        summary["truth_impostors_over_20"] = int(sum(t >= 20 for t in truths))
        summary["truth_impostors"] = len(truths)
    for i, r in enumerate(synthetic):
        ceiling = scores[("ceiling", i)]
        r["ceiling"] = ceiling
        # perfect ridges through our geometry and mask, as a fraction of the ceiling
        r["through_print_ratio"] = round(scores[("through", i)] / ceiling, 4) \
            if ceiling > 0 else None
        for tag in ("default", "before"):
            g = scores[(tag, i, i)]
            imp = [scores[(tag, i, j)] for j in range(n) if j != i]
            r[tag]["genuine"] = g
            r[tag]["ratio_to_ceiling"] = round(g / ceiling, 4) if ceiling > 0 else None
            r[tag]["impostor_max"] = max(imp) if imp else None
    for k, r in enumerate(real):
        probe = scores[("probe",)]
        r["ceiling_to_probe"] = round(scores[("real", "ideal", k, "matching")] / probe, 4)
        r["through_print_to_probe"] = round(scores[("real", "through", k, "matching")] / probe, 4)
        for tag in ("default", "before"):
            m = scores[("real", tag, k, "matching")]
            r[tag]["vs_matching"] = m
            r[tag]["ratio_to_probe"] = round(m / scores[("probe",)], 4)
            r[tag]["vs_nonmatching"] = scores[("real", tag, k, "nonmatching")]
    for tag in ("default", "before"):
        if synthetic:
            genuine = np.array([r[tag]["genuine"] for r in synthetic])
            impostor = np.array([scores[(tag, i, j)] for i in range(n) for j in range(n)
                                 if i != j])
            ratios = np.array([r[tag]["ratio_to_ceiling"] for r in synthetic], float)
            t_fmr3 = float(np.percentile(impostor, 99.9)) if impostor.size else None
            summary[tag] = {
                "fingers": n,
                "genuine_min": float(genuine.min()), "genuine_median": float(np.median(genuine)),
                "impostor_max": float(impostor.max()) if impostor.size else None,
                "impostor_p99_9": t_fmr3,
                "fnmr_at_40": float((genuine < THRESHOLD).mean()),
                "fmr_at_40": float((impostor >= THRESHOLD).mean()) if impostor.size else None,
                "threshold_fmr_1e-3": t_fmr3,
                "fnmr_at_fmr_1e-3": float((genuine < t_fmr3).mean()) if t_fmr3 else None,
                "ratio_to_ceiling_median": float(np.median(ratios)),
                "ratio_to_ceiling_min": float(ratios.min()),
                # the loss split: perfect ridges through the print's geometry and mask (the
                # same for both variants: the default's), and the print's area against the
                # ideal crop's
                "through_print_ratio_median": float(np.median(
                    [r["through_print_ratio"] for r in synthetic])),
                "area_to_ideal_median": float(np.median(
                    [r[tag]["print_area_mm2"] / r["ideal"]["area_mm2"] for r in synthetic])),
                "_genuine": genuine.tolist(), "_impostor": impostor.tolist(),
            }
        if real:
            ratios = np.array([r[tag]["ratio_to_probe"] for r in real])
            summary[f"real_{tag}"] = {
                "fingers": len(real), "ratio_to_probe_min": float(ratios.min()),
                "ceiling_to_probe_min": float(min(r["ceiling_to_probe"] for r in real)),
                "through_print_to_probe_min": float(min(r["through_print_to_probe"]
                                                        for r in real)),
                "ratio_to_probe_median": float(np.median(ratios)),
                "nonmatching_max": max(r[tag]["vs_nonmatching"] for r in real)}
    return summary


def geometry_summary(results: list[dict], tag: str) -> dict:
    def worst(part, key):
        values = [r[tag][part][key] for r in results if r[tag].get(part, {}).get(key) is not None]
        return (round(float(np.max(values)), 5), round(float(np.median(values)), 5)) \
            if values else (None, None)

    return {f"{part}_{key}_max_median": worst(part, key)
            for part in ("body", "cap") for key in ("scale_error_p95", "displacement_p95_mm")}


def markdown(summary: dict, results: list[dict], before: str = "fixed-blend") -> str:
    lines = [f"| | default | before ({before}) |", "| --- | --- | --- |"]
    d, b = summary.get("default", {}), summary.get("before", {})

    def row(label, key, fmt="{:.3f}"):
        def f(x):
            return "—" if x is None else fmt.format(x)
        lines.append(f"| {label} | {f(d.get(key))} | {f(b.get(key))} |")

    row("unrolled / ceiling, median", "ratio_to_ceiling_median")
    row("unrolled / ceiling, worst finger", "ratio_to_ceiling_min")
    row("true print through the default's geometry and mask / ceiling, median",
        "through_print_ratio_median")
    row("print area / ideal crop's area, median", "area_to_ideal_median")
    row("genuine score, lowest", "genuine_min", "{:.1f}")
    row("impostor score, highest", "impostor_max", "{:.1f}")
    row("FNMR at 40 (FMR 0.01 %)", "fnmr_at_40")
    row("FNMR at FMR 1e-3", "fnmr_at_fmr_1e-3")
    if "truth_impostor_max" in summary:
        lines.append(f"\ntrue prints against each other (the generator's own impostors): highest "
                     f"{summary['truth_impostor_max']:.1f}, {summary['truth_impostors_over_20']} "
                     f"of {summary['truth_impostors']} at 20 or more")
    for tag in ("real_default", "real_before"):
        if tag in summary:
            s = summary[tag]
            lines.append(f"\n{tag}: unrolled probe vs matching / {summary['probe_vs_matching']:.1f}"
                         f": min {s['ratio_to_probe_min']:.3f}, median "
                         f"{s['ratio_to_probe_median']:.3f}; vs nonmatching max "
                         f"{s['nonmatching_max']:.1f}")
    real = [r for r in results if "ceiling_to_probe" in r]
    if real:
        lines += ["", "| real finger | ideal crop / probe | true print through the print / "
                  "probe | default / probe | before / probe |", "| --- | --- | --- | --- | --- |"]
        lines += [f"| {r['name']} | {r['ceiling_to_probe']:.3f} | "
                  f"{r['through_print_to_probe']:.3f} | {r['default']['ratio_to_probe']:.3f} | "
                  f"{r['before']['ratio_to_probe']:.3f} |" for r in real]
    for tag in ("default", "before"):
        lines.append(f"\ngeometry ({tag}, max and median over fingers): "
                     f"{json.dumps(geometry_summary(results, tag))}")
    return "\n".join(lines)


def rescore(out: Path, *, imageio_grey: bool, before: str) -> int:
    """Score the prints an earlier run left under `out` again; print the summary (the run's
    ``results.json`` is left as it is)."""
    path = out / "results.json"
    if not path.is_file():
        print(f"--rescore: no {path} (run the bench first)", file=sys.stderr)
        return 2
    results = json.loads(path.read_text())["fingers"]
    summary = {"fingers": len(results), **score(results, out, imageio_grey=imageio_grey)}
    print(markdown(summary, results, before))
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--fingers", type=int, default=40, help="synthetic fingers (default 40)")
    p.add_argument("--real", type=int, default=10,
                   help="fingers wearing the real probe.png (default 10)")
    p.add_argument("--seed0", type=int, default=SYNTHETIC_SEED0)
    p.add_argument("--real-seed0", type=int, default=REAL_SEED0)
    p.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1))
    p.add_argument("--scale", type=float, default=1.0)
    p.add_argument("--out", type=Path, default=Path("bench-output/interop"))
    p.add_argument("--det", type=Path, help="write the DET plot here (PNG)")
    p.add_argument("--no-matcher", action="store_true")
    p.add_argument("--before", choices=sorted(BEFORE), default="fixed-blend",
                   help="what the default is compared with (default: fixed-blend)")
    p.add_argument("--rescore", action="store_true",
                   help="score the prints of an earlier run under --out again (no scanning)")
    p.add_argument("--imageio-grey", action="store_true",
                   help="let SourceAFIS read grey PNGs through ImageIO, brightened, as this "
                        "bench did before 2026-12-08 (bench/sourceafis.py)")
    args = p.parse_args(argv)
    if args.rescore:
        return rescore(args.out, imageio_grey=args.imageio_grey, before=args.before)
    from nail2nail.simulation.rig import default_rig

    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    _, calib_path = um.best_calibration(args.out, default_rig(args.scale), args.scale)
    jobs = [{"dir": str(args.out / f"syn{args.seed0 + i:04d}"), "seed": args.seed0 + i,
             "print": None, "scale": args.scale, "calibration": calib_path,
             "before": args.before} for i in range(args.fingers)]
    jobs += [{"dir": str(args.out / f"real{args.real_seed0 + i:04d}"),
              "seed": args.real_seed0 + i, "print": str(PRINTS / "probe.png"),
              "scale": args.scale, "calibration": calib_path, "before": args.before}
             for i in range(args.real)]
    results = []
    # spawn: the calibration above ran OpenMP threads, which a forked worker cannot use
    with ProcessPoolExecutor(max_workers=max(1, args.workers),
                             mp_context=multiprocessing.get_context("spawn")) as pool:
        for r in pool.map(run_finger, jobs):
            log(f"{r['name']}: {r['print']}, before/default clarity "
                f"{r['before']['clarity_median']}/{r['default']['clarity_median']}, body scale "
                f"p95 {r['default']['body']['scale_error_p95']}")
            results.append(r)
    summary = {"fingers": len(results), "wall_s": None}
    if not args.no_matcher and sourceafis.available():
        summary.update(score(results, args.out, imageio_grey=args.imageio_grey))
        if args.det and "default" in summary:
            d, b = summary["default"], summary["before"]
            plot_det(args.det, {"default": (d["_genuine"], d["_impostor"]),
                                f"before ({args.before})": (b["_genuine"], b["_impostor"])},
                     {"threshold 40, default": (d["fmr_at_40"], d["fnmr_at_40"])})
    elif not args.no_matcher:
        log("SourceAFIS not available (Java and Maven): geometry only")
    summary["wall_s"] = round(time.perf_counter() - t0, 1)
    summary["geometry"] = {tag: geometry_summary(results, tag) for tag in ("default", "before")}
    (args.out / "results.json").write_text(json.dumps({"summary": summary, "fingers": results},
                                                      indent=1))
    print(markdown(summary, results, args.before))
    return 0


if __name__ == "__main__":
    sys.exit(main())
