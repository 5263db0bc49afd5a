"""Issue 27's evidence: the seamless super-scan mesh on random simulator conditions.

For each virtual capture (rendered here from ``draw_conditions(seed)`` at full resolution, or
given with ``--captures``, each with its ``truth/``): scan with the capture's true calibration,
merge with ``write_merge(seamless_mesh=True)`` (figures and files off), and measure the mesh:
non-manifold edges and vertices, inconsistent windings, boundary edges, the outline and the
holes inside it (``nail2nail.merge.boundary_figures``: hole edges farther than 2 grid spacings
from the outline), the largest distance of a vertex from the true surface (along the true
normal of its pixel), the merge figures, and whether trimesh reads the exported PLY back as
one winding-consistent mesh.

Usage::

    .venv/bin/python bench/seamless_mesh.py [--conditions 6 --seed0 950] [--scale 1]
        [--captures DIR ...] [--out DIR] [--json]

About 1.5 min per capture at full resolution on two cores (render 45 s, scan, fusion, 15 s of
meshing).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _measure import log

from nail2nail.calibration.files import RigCalibration, load_calibration
from nail2nail.io.capture import read_capture, read_truth
from nail2nail.io.meshes import write_mesh
from nail2nail.io.ply import read_ply
from nail2nail.merge.fusion import fuse_scans
from nail2nail.merge.report import write_merge
from nail2nail.scan.capture import scan_capture
from nail2nail.simulation.capture import simulate_capture
from nail2nail.simulation.conditions import draw_conditions
from nail2nail.simulation.rig import Rig, ideal_calibration
from nail2nail.simulation.scenes import make_scene
from nail2nail.simulation.truth import surface_distance


def render(out: Path, seed: int, scale: float) -> Path:
    path = out / "captures" / f"cond{seed}"
    if not (path / "capture.json").is_file():
        log(f"condition {seed}: render")
        cond = draw_conditions(seed)
        rig = cond.rig(scale)
        scene = make_scene("finger", rig=rig, seed=seed, **cond.finger_options())
        simulate_capture(path, scene, rig=rig, seed=seed)
    return path


def measure(capture_dir: Path, out: Path) -> dict:
    import trimesh

    capture = read_capture(capture_dir, load=False)
    truth_calib = capture_dir / "truth" / "calibration.json"
    calib = (load_calibration(truth_calib) if truth_calib.is_file()
             else RigCalibration.from_dict(ideal_calibration(Rig.from_capture(capture))))
    t0 = time.perf_counter()
    scans = scan_capture(capture, calib)
    t_scan = time.perf_counter() - t0
    label = capture_dir.name if capture_dir.name != "capture" else capture_dir.parent.name
    merge_dir = out / "merge" / label
    summary = write_merge(scans, merge_dir, figures=False, mat5=False, seamless_mesh=True)
    mesh = summary["super_scan"]["mesh"]
    # the written mesh, read back; its vertices are the super scan's (the same fusion, the same
    # order), each against the truth of the pixel it comes from
    ply = read_ply(merge_dir / "super.ply")
    sup = fuse_scans(scans)
    if not np.array_equal(np.asarray(ply.points), sup.vertices):
        raise RuntimeError(f"{merge_dir}: super.ply's vertices are not the super scan's")
    truths = [read_truth(capture_dir, scan.name) for scan in scans]
    d = np.abs(surface_distance(sup.vertices, sup.camera, sup.pixel, truths))
    glb = out / "merge" / f"{label}.glb"
    write_mesh(glb, ply.points, ply.faces, colors=ply.colors, normals=ply.normals)
    loaded = trimesh.load(glb, force="mesh", process=False)
    return {
        "capture": str(capture_dir),
        "label": label,
        "scan_s": round(t_scan, 1),
        "mesh": mesh,
        "merge_um": {k: [round(1000 * m["distance_mm"]["median"], 2),
                         round(1000 * m["distance_mm"]["p95"], 2)]
                     for k, m in summary["merge"].items()},
        "vertex_far_um": round(1000 * float(np.nanmax(d)), 1),
        "vertex_p999_um": round(1000 * float(np.nanpercentile(d, 99.9)), 1),
        "vertices_over_50um": int(np.count_nonzero(d > 0.050)),
        "vertices": int(d.size),
        "trimesh": {"faces": len(loaded.faces),
                    "winding_consistent": bool(loaded.is_winding_consistent),
                    "watertight": bool(loaded.is_watertight)},
    }


def main(argv=None) -> list:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--conditions", type=int, default=6)
    ap.add_argument("--seed0", type=int, default=950)
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--captures", type=Path, nargs="*", default=None)
    ap.add_argument("--out", type=Path, default=Path("bench-output/seamless_mesh"))
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    captures = args.captures or [render(args.out, args.seed0 + k, args.scale)
                                 for k in range(args.conditions)]
    results = []
    for cap in captures:
        r = measure(Path(cap), args.out)
        m = r["mesh"]
        log(f"{cap}: boundary {m['boundary_edges']} (outline {m['boundary']['outline_edges']}, "
            f"holes {m['boundary']['holes']}, far {m['boundary']['hole_edges_far']}), "
            f"non-manifold edges {m['non_manifold_edges']}, vertices far {r['vertex_far_um']} um")
        results.append(r)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps(results, indent=1))
    if args.json:
        print(json.dumps(results, indent=1))
    else:
        print("| capture | boundary edges (outline) | holes (edges; far > 2 spacings) | "
              "non-manifold edges / vertices | inconsistent | vertex farthest from truth µm | "
              "merge µm | trimesh winding consistent | s |")
        print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
        for r in results:
            m, b = r["mesh"], r["mesh"]["boundary"]
            merge = "; ".join(f"{k} {v[0]} / {v[1]}" for k, v in r["merge_um"].items())
            print(f"| {r['label']} | {m['boundary_edges']} ({b['outline_edges']}) "
                  f"| {b['holes']} ({b['hole_edges']}; {b['hole_edges_far']}) | "
                  f"{m['non_manifold_edges']} / {m['non_manifold_vertices']} | "
                  f"{m['inconsistent_edges']} | {r['vertex_far_um']} ({r['vertices_over_50um']} of "
                  f"{r['vertices']} over 50) | {merge} | "
                  f"{r['trimesh']['winding_consistent']} | {m['seconds']} |")
    return results


if __name__ == "__main__":
    main()
