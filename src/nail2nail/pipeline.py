"""The whole pipeline on the virtual scanner, as ``nail2nail demo`` (and ``make demo``) runs it.

Steps, each written under ``out``:

1. ``captures/``: the virtual scanner renders the cylindrical target, a flat plane and the
   finger (thesis projector distortion, default multi-frequency patterns).
2. ``distortion/``: the projector's optical centre and ρ, estimated from the plane (thesis
   method and non-linear fit, :mod:`nail2nail.calibration.distortion`).
3. The target and the finger are rendered again under patterns pre-distorted with the
   estimate's look-up table (the thesis's correction, appendix ``distortion2dlut``).
4. ``calib/``: calibrations from the target captures: the thesis's per-camera DLT on plain
   patterns ("before"), the same on LUT-corrected patterns ("thesis_lut"), the same on plain
   patterns with the estimated distortion compensated in the model ("model_dlt"), and the
   joint calibration with one shared projector whose distortion is modelled, the marks'
   projected discs modelled on the cylinder, refined on the target's surface ("best"):
   ``rig_CONFIG.json``, and beside each the observations it was fitted to as points tables
   ``rig_CONFIG_points_CAMERA.tsv`` (as ``nail2nail calibrate`` writes them; the report's
   calibration residuals).
5. ``merge/``: per configuration and object, the merge error of camera pairs in projector
   space (thesis chapter four: ``merge.json`` and figures); ``scans/best/finger`` holds the
   best configuration's finger scans (.npz, PLY) and its merge directory the data files
   (mapping files, super scan PLY and super mat5). The other configurations are compared by
   their numbers and figures, not written point by point (the output stays a few hundred MB).
6. Super scans (renders) of the target in every configuration and of the finger in the best
   one.
7. ``print/``: the finger of the best configuration unrolled into a rolled-equivalent print
   (:mod:`nail2nail.unroll`, default method; PNG, WSQ, binarised, mask, metadata), and every
   unrolling method compared with the virtual finger's true skin coordinates (geometric
   accuracy, distortion, ridge period).
8. ``projectors/``: the same finger on a rig of two projectors at ±45° (:data:`PROJECTOR_LAYOUT`,
   ``docs/projectors.md``), at half resolution whatever `scale` (:data:`PROJECTOR_SCALE`):
   the target and the finger captured under each projector (``captures/target``,
   ``captures/finger``), both projectors calibrated with the cameras in one bundle
   (``calib/rig_p0.json``, ``rig_p1.json``), and the whole job of ``nail2nail process`` on
   the finger (``job/``: scans, merge of every kind of pair, super scan, print; its
   ``report.html``). The summary gives the nail-to-nail width its scans cover against one
   projector's.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from nail2nail._progress import Stages
from nail2nail.calibration.distortion import (
    ProjectorDistortion,
    apply_lut,
    distortion_lut,
    estimate_from_decoded,
)
from nail2nail.calibration.files import save_calibration
from nail2nail.calibration.markers import TargetGeometry
from nail2nail.calibration.observe import target_observations
from nail2nail.calibration.target import calibrate_from_observations
from nail2nail.io._atomic import atomic_directory
from nail2nail.io._json import write_json
from nail2nail.io.capture import read_capture
from nail2nail.io.points import PointsTable, write_points
from nail2nail.io.rolled import write_rolled_print
from nail2nail.io.scans import save_scans
from nail2nail.merge.report import write_merge
from nail2nail.scan.capture import decode_cameras, scan_capture
from nail2nail.scan.patterns import default_pattern_set, make_patterns
from nail2nail.simulation.capture import simulate as simulate_frames
from nail2nail.simulation.capture import write_capture
from nail2nail.simulation.rig import default_rig
from nail2nail.simulation.truth import truth_print_sampler, truth_skin_coordinates
from nail2nail.unroll import DEFAULT_METHOD, METHODS, unroll_scans
from nail2nail.unroll.accuracy import geometric_accuracy

__all__ = ["CONFIGURATIONS", "PROJECTOR_LAYOUT", "PROJECTOR_SCALE", "best_calibration",
           "plane_distortion", "run_demo"]

#: Merge configurations compared by the demo (issue 5's table).
CONFIGURATIONS = ("before", "thesis_lut", "model_dlt", "best")
#: The demo's rig of several projectors (:data:`nail2nail.simulation.projectors.LAYOUTS`) and
#: its camera scale: half resolution keeps the step to about a minute and a half and the
#: target's marks above the 20 px they need.
PROJECTOR_LAYOUT = "pair-45"
PROJECTOR_SCALE = 0.5


def _merge_summary(stats: dict) -> dict:
    keep = ("median", "p95", "max", "frac_below_0_05", "mean")
    return {
        pair: {"pairs": s["pairs"], "distance_mm": {k: s["distance_mm"][k] for k in keep}}
        for pair, s in stats.items()
    }


def plane_distortion(plane_capture):
    """The projector's radial distortion estimated from a capture of a flat plane.

    Every camera's decoded projector coordinates go into the joint non-linear fit of
    :func:`nail2nail.calibration.distortion.estimate_from_decoded` (centre, ρ and a homography per
    camera;
    the thesis's model, eq. 3.15–3.16).

    Parameters
    ----------
    plane_capture : Capture
        A capture of a flat plane under the default (or any full) pattern set.

    Returns
    -------
    report
        The estimate; ``report.fit.center`` (2,) panel px and ``report.fit.rho``.
    """

    return estimate_from_decoded(
        {name: (d.xp, d.yp, d.mask) for name, d in decode_cameras(plane_capture)})


def best_calibration(target_capture, *, center, rho, panel_size, observations=None):
    """The demo's "best" calibration of a rig from a capture of the cylindrical target.

    All cameras and one shared projector are fitted jointly, the projector's radial
    distortion in the model (started at `center`, `rho`, e.g. from :func:`plane_distortion`),
    each mark's projected disc on the cylinder modelled from marks re-measured against their
    local background, and the whole refined on the target's known surface.

    Parameters
    ----------
    target_capture : Capture
        A capture of the target (:class:`nail2nail.calibration.markers.TargetGeometry`).
    center : (2,) float
        Initial distortion centre, panel px.
    rho : float
        Initial distortion parameter (thesis eq. 3.15).
    panel_size : (int, int)
        Projector panel ``(width, height)``, px.
    observations : list of TargetObservations, optional
        The capture's observations with re-measured marks
        (``target_observations(target_capture, refine_marks=True)``, computed when not given;
        the demo computes them once, to write them as points tables too).

    Returns
    -------
    RigCalibration
    """

    target = TargetGeometry()
    if observations is None:
        observations = target_observations(target_capture, refine_marks=True)
    return calibrate_from_observations(
        observations, model="joint", surface=target.signed_distance,
        projector_size=panel_size, initial_distortion={"center": list(center), "rho": rho},
        target=target)[0]


def run_demo(
    out: str | os.PathLike = "demo-output",
    *,
    scale: float = 1.0,
    seed: int = 0,
    progress: bool = True,
    super_scan: bool = True,
    figures: bool = True,
) -> dict:
    """Run the pipeline end to end on the virtual scanner; return (and write) a summary.

    Parameters
    ----------
    out : path-like
        Output directory (created). Its ``summary.json`` is removed first and written last
        (a directory without it is incomplete); every sub-directory (``captures/NAME``,
        ``distortion``, ``calib``, ``scans/C/O``, ``merge/C/O``, ``print``) is replaced as a
        whole (:func:`nail2nail.io._atomic.atomic_directory`).
    scale : float
        Camera resolution scale (1 = 1024 × 1280; 0.25 for a quick run).
    seed : int
        Fingerprint and noise seed.
    progress : bool
        Step lines on stderr (also when it is not a terminal; none inside
        :func:`nail2nail._progress.quiet`).
    super_scan, figures : bool
        Build the super scan / write the figures.

    Returns
    -------
    dict
        ``{"merge": {"0-1": …, "1-2": …}`` (the best configuration, finger), ``"comparison"``
        (merge medians per configuration and object), ``"distortion"``, ``"calibration"``,
        ``"outputs"`` (every file written) …}; also written to ``out/summary.json``.
    """

    rig = default_rig(scale, projector_distortion="thesis")  # checks `scale` before any write
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out}: exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    # summary.json goes first and comes back last: without it the directory is visibly
    # incomplete; every sub-directory is replaced as a whole (atomic_directory)
    (out / "summary.json").unlink(missing_ok=True)
    # one line per step on stderr with the elapsed time, also into a log file; not with --quiet
    step = Stages(18, enabled=progress, terminal_only=False)
    pattern_set = default_pattern_set()
    patterns = make_patterns(pattern_set)
    captures = {}

    def simulate(name, scene, pats, *, like=None, truth=False):
        """Render and write a capture; `like`: an earlier simulation of the same object,
        whose geometry (the costly ray casting) is reused under other patterns."""
        step(f"simulate {name} ({len(rig.cameras)} cameras x {len(pats)} frames)")
        path = out / "captures" / name
        sim = simulate_frames(scene if like is None else like.scene, rig=rig, patterns=pats,
                              pattern_set=pattern_set, seed=seed,
                              geometry=None if like is None else like.geometry)
        write_capture(path, sim, seed=seed, write_truth=truth)
        captures[name] = str(path)
        return sim

    simulate("plane", "plane", patterns)
    step("estimate the projector distortion from the plane")
    report = plane_distortion(read_capture(captures["plane"], load=False))
    distortion = report.to_dict(truth=None)
    with atomic_directory(out / "distortion", marker="projector_distortion.json") as tmp:
        write_json(tmp / "projector_distortion.json", distortion)
    center, rho = report.fit.center, report.fit.rho
    lut_patterns = apply_lut(patterns, distortion_lut(pattern_set.panel_size, center, rho))

    # ground truth only for the finger (its rolled print is what unrolling is tested on)
    simulate("target_lut", "target", lut_patterns, like=simulate("target", "target", patterns))
    simulate("finger_lut", "finger", lut_patterns,
             like=simulate("finger", "finger", patterns, truth=True))

    step("calibrate: per-camera DLT (before, thesis_lut, model_dlt) and joint (best)")
    obs_plain = target_observations(read_capture(captures["target"], load=False))
    obs_lut = target_observations(read_capture(captures["target_lut"], load=False))
    target_capture = read_capture(captures["target"], load=False)
    obs_best = target_observations(target_capture, refine_marks=True)
    calibs = {
        "before": calibrate_from_observations(obs_plain, model="dlt")[0],
        "thesis_lut": calibrate_from_observations(obs_lut, model="dlt")[0],
        "model_dlt": calibrate_from_observations(
            obs_plain, model="dlt", projector_distortion=ProjectorDistortion(
                (float(center[0]), float(center[1])), float(rho))
        )[0],
        "best": best_calibration(target_capture, center=center, rho=rho,
                                 panel_size=pattern_set.panel_size, observations=obs_best),
    }
    # the observations each calibration was fitted to, as `nail2nail calibrate` writes them
    observed = {"before": obs_plain, "thesis_lut": obs_lut, "model_dlt": obs_plain,
                "best": obs_best}
    calib_paths = {}
    names = [f"rig_{name}.json" for name in calibs]
    with atomic_directory(out / "calib", marker=tuple(names)) as tmp:
        for name, calib in calibs.items():
            save_calibration(tmp / f"rig_{name}.json", calib)
            calib_paths[name] = str(out / "calib" / f"rig_{name}.json")
            for obs in observed[name]:
                extra = None if obs.grid is None else {"grid_row": obs.grid[:, 0],
                                                         "grid_col": obs.grid[:, 1]}
                write_points(tmp / f"rig_{name}_points_{obs.name}.tsv", PointsTable.from_arrays(
                    obs.xyz_world, obs.xy_camera, obs.xy_projector, extra=extra))

    comparison: dict = {}
    merges: dict = {}
    finger_scans = None  # the best configuration's finger: what the unroll step takes
    outputs: list[str] = [str(out / "distortion" / "projector_distortion.json"),
                          *calib_paths.values()]
    for config in CONFIGURATIONS:
        for obj in ("target", "finger"):
            src = f"{obj}_lut" if config == "thesis_lut" else obj
            step(f"scan and merge {obj} ({config})")
            scans = scan_capture(read_capture(captures[src], load=False), calibs[config])
            # the data files (scans as .npz and PLY; mapping files, super scan PLY and mat5)
            # of the result, the best configuration's finger; of the comparisons their
            # numbers and figures (merge.json, PNG): a few hundred MB in all, not gigabytes
            keep = (config, obj) == ("best", "finger")
            if keep:
                scan_dir = out / "scans" / config / obj
                manifest = save_scans(
                    scan_dir, scans, mat5=False, ply=True,
                    extra={"capture": captures[src], "calibration": calib_paths[config]})
                outputs.append(str(scan_dir / "scan.json"))
                for cam in manifest["cameras"]:
                    outputs += [str(scan_dir / cam[k]) for k in ("npz", "ply") if k in cam]
            # super scans of the target in every configuration (the thesis's Figures 26 and
            # 27), of the finger in the best one
            build_super = super_scan and (obj == "target" or config == "best")
            summary = write_merge(
                scans,
                out / "merge" / config / obj,
                pairs=[(0, 1), (1, 2)],
                figures=figures,
                super_scan=build_super,
                data=keep,
            )
            merges[(config, obj)] = summary
            if (config, obj) == ("best", "finger"):
                finger_scans = scans
            comparison.setdefault(config, {})[obj] = _merge_summary(summary["merge"])
            outputs += summary.get("outputs", [])
    step("unroll the finger into a rolled-equivalent print (every method against the truth)")
    unrolled = _unroll_demo(finger_scans, captures["finger"], out / "print", figures=figures)
    outputs += unrolled.pop("outputs")
    projectors = _projectors_demo(out / "projectors", seed=seed, step=step)
    outputs += projectors.pop("outputs")
    best = merges[("best", "finger")]
    result = {
        "out": str(out),
        "scale": scale,
        "merge": _merge_summary(best["merge"]),
        "comparison": comparison,
        "distortion": {
            "center_px": list(map(float, center)),
            "rho": float(rho),
            "thesis": distortion.get("thesis"),
        },
        "calibration": calib_paths,
        "captures": captures,
        "super_scan": best.get("super_scan"),
        "print": unrolled,
        "projectors": projectors,
        "outputs": [*outputs, str(out / "summary.json")],
    }
    write_json(out / "summary.json", result, default=float)
    return result


def _projectors_demo(out: Path, *, seed: int, step) -> dict:
    """Step 8 of the module docstring: a rig of two projectors from captures to print."""
    from nail2nail.calibration.observe import projector_target_observations
    from nail2nail.calibration.target import calibrate_projectors_from_observations
    from nail2nail.io.capture import projector_captures, read_truth
    from nail2nail.io.scans import load_scan_dirs
    from nail2nail.process import process_capture
    from nail2nail.report import write_report
    from nail2nail.simulation.projectors import rolled_coverage, simulate_projector_captures
    from nail2nail.simulation.scenes import make_scene

    rig = default_rig(PROJECTOR_SCALE, projector_distortion="thesis")
    step(f"simulate the target and the finger under two projectors ({PROJECTOR_LAYOUT}, "
         f"scale {PROJECTOR_SCALE:g})")
    dirs = {name: out / "captures" / name for name in ("target", "finger")}
    finger = make_scene("finger", rig=rig, seed=seed)
    for name, scene in (("target", "target"), ("finger", finger)):
        simulate_projector_captures(dirs[name], scene, PROJECTOR_LAYOUT, rig=rig, seed=seed,
                                    scene_name=name)
    step("calibrate both projectors with the cameras; process the finger (scan, merge, print)")
    layout = projector_captures(dirs["target"])
    assert layout is not None  # written just above
    opened = [read_capture(path, load=False) for _, path in layout]
    sets = projector_target_observations(opened, refine_marks=True)
    calibs, _ = calibrate_projectors_from_observations(
        sets, projector_sizes=[tuple(c.manifest["projector"]["size"]) for c in opened],
        surface=TargetGeometry().signed_distance, target=TargetGeometry())
    names = [f"rig_{name}.json" for name, _ in layout]
    with atomic_directory(out / "calib", marker=tuple(names)) as tmp:
        for file, calib in zip(names, calibs, strict=True):
            save_calibration(tmp / file, calib)
    job = out / "job"
    summary = process_capture(dirs["finger"], out / "calib" / "rig.json", job, wsq=False)
    report = write_report(job, progress=False)
    # the nail-to-nail width the scans see, both projectors against the first alone
    scans, projectors, _ = load_scan_dirs([job / "scans"])
    captures = projector_captures(dirs["finger"])
    assert captures is not None and projectors is not None
    truths = [read_truth(captures[k][1], str(s.name).rsplit("-p", 1)[0])
              for s, k in zip(scans, projectors, strict=True)]
    seen = [(s.mask, t["param_u"], t["param_v"]) for s, t in zip(scans, truths, strict=True)]
    both = rolled_coverage(finger, seen, pitch_mm=0.2)
    one = rolled_coverage(finger, [x for x, k in zip(seen, projectors, strict=True) if k == 0],
                          pitch_mm=0.2)
    return {
        "layout": PROJECTOR_LAYOUT, "scale": PROJECTOR_SCALE,
        "captures": {k: str(v) for k, v in dirs.items()},
        "calibration": [str(out / "calib" / n) for n in names],
        "job": str(job), "report": str(report),
        "coverage": {"width_median": both["width_median"],
                     "first_projector_width_median": one["width_median"]},
        "merge": {key: {"kind": m.get("kind"), "pairs": m["pairs"],
                        "distance_mm": m["distance_mm"]}
                  for key, m in summary["merge"].items()},
        "print": summary.get("print"),
        "outputs": [str(out / "calib" / n) for n in names]
        + [str(job / "process.json"), str(report)],
    }


def _unroll_demo(scans, capture_dir, out: Path, *, figures: bool) -> dict:
    """Unroll with every method, compare each with the truth, write the default's print."""

    truth_uv = truth_skin_coordinates(capture_dir, [s.name for s in scans])
    _, sampler = truth_print_sampler(capture_dir)
    methods, prints, maps = {}, {}, {}
    for method in (DEFAULT_METHOD, *[m for m in METHODS if m != DEFAULT_METHOD]):
        start = time.perf_counter()
        rolled = unroll_scans(scans, method=method)
        seconds = time.perf_counter() - start
        acc = geometric_accuracy(rolled, scans, truth_uv, truth_sampler=sampler, maps=figures)
        truth_on_grid = acc.pop("truth_on_grid")
        maps[method] = (acc.pop("scale_error_map", None), acc.pop("displacement_map", None))
        prints[method] = (rolled, truth_on_grid)
        methods[method] = {"seconds": round(seconds, 3), "distortion": rolled.distortion,
                           **acc}
    rolled, truth_on_grid = prints[DEFAULT_METHOD]
    with atomic_directory(out, marker="print.json") as tmp:  # print, methods, figures: whole
        meta = write_rolled_print(tmp, rolled, extra={"accuracy": methods[DEFAULT_METHOD]})
        names = [*meta["files"].values(), "print.json"]
        write_json(tmp / "methods.json", methods)
        names.append("methods.json")
        if figures:
            # Deferred: unroll.figures imports matplotlib, needed only when figures are drawn.
            from nail2nail.unroll.figures import save_print_figures

            names += [str(Path(p).relative_to(tmp))
                      for p in save_print_figures(tmp, prints, maps)]
    outputs = [str(out / name) for name in names]
    return {"method": DEFAULT_METHOD, "dir": str(out), "methods": methods,
            "shape": meta["shape"], "print_size_mm": meta["print_size_mm"],
            "outputs": outputs}


def format_summary(result: dict) -> str:
    """Human-readable tables of :func:`run_demo`'s result."""
    lines = [
        f"Projector distortion estimate: centre ({result['distortion']['center_px'][0]:.1f},"
        f" {result['distortion']['center_px'][1]:.1f}) px, rho "
        f"{result['distortion']['rho']:.6f} (thesis: (640, 1000), -0.004)",
        "",
        "Merge error, median / p95 (µm), camera pairs 0-1 and 1-2:",
        f"{'configuration':<14}{'object':<8}{'0-1':>16}{'1-2':>16}",
    ]
    for config, objs in result["comparison"].items():
        for obj, pairs in objs.items():
            cells = []
            for pair in ("0-1", "1-2"):
                d = pairs[pair]["distance_mm"]
                cells.append(f"{1000 * d['median']:7.1f} / {1000 * d['p95']:6.1f}")
            lines.append(f"{config:<14}{obj:<8}{cells[0]:>16}{cells[1]:>16}")
    if result.get("print"):
        p = result["print"]
        lines += ["", f"Rolled-equivalent print ({p['method']}, {p['print_size_mm'][0]} x "
                  f"{p['print_size_mm'][1]} mm at 500 ppi) against the true skin coordinates:",
                  f"{'method':<11}{'scale err p95':>14}{'displ. p95':>12}{'period dev':>12}"
                  f"{'length dist p95':>17}{'time s':>8}"]
        for name, m in p["methods"].items():
            lines.append(
                f"{name:<11}{100 * m['scale_error']['p95']:13.2f}%"
                f"{1000 * m['displacement_mm']['p95']:9.0f} µm"
                f"{100 * m['period_ratio']['median_abs_deviation']:11.2f}%"
                f"{100 * m['distortion']['length']['p95']:16.1f}%{m['seconds']:8.2f}")
    if result.get("projectors"):
        pj = result["projectors"]
        cover = pj["coverage"]
        lines += ["", f"Two projectors ({pj['layout']}, scale {pj['scale']:g}): the scans cover "
                  f"{100 * cover['width_median']:.1f} % of the nail-to-nail width (one of them "
                  f"{100 * cover['first_projector_width_median']:.1f} %); merge median / p95 "
                  "(µm):"]
        for key, m in pj["merge"].items():
            d = m["distance_mm"]
            kind = f"({m['kind'] or 'projector'})"
            lines.append(f"  {key:<5} {kind:<12}{1000 * d['median']:6.1f} / "
                         f"{1000 * d['p95']:5.1f}")
        lines.append(f"  the job (scans, merge, print, report) in {pj['job']}")
    lines.append("")
    lines.append(f"outputs under {result['out']} (summary.json lists every file)")
    return "\n".join(lines)
