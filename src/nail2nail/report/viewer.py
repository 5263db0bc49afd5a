"""The report's interactive 3D viewer of the super scan (plotly.js, WebGL).

The super scan (``merge/super.ply``) is decimated for the browser by vertex clustering
(:func:`cluster_vertices`: one vertex per occupied cube of a regular grid; Rossignac & Borrel
1993), to at most ``max_points`` vertices, and meshed again as one surface
(:func:`seamless_faces`, :func:`nail2nail.merge.mesh.seamless_mesh`: a Delaunay triangulation
in the plane of a cylinder fitted about the points, unrolled), so the seams between the
cameras' grids, which the super scan's own mesh keeps (a line of light dots down the finger),
are closed; where that mesh is not better (a surface no cylinder unrolls, such as a flat
board), the super scan's triangles re-indexed by the clustering are shown. Each vertex carries
three colourings:

- ``albedo``: the PLY's vertex colour (the decoded albedo, grey);
- ``camera``: which camera's scan the vertex comes from (nearest scan point of every camera,
  in the world frame);
- ``error``: the merge error (µm) of the camera pair whose corresponding points lie at the
  vertex (nearest point of the pairs' mapping files within two vertex spacings), grey where
  no two cameras overlap.

The page shows them as points or as a shaded mesh (buttons), orbit/zoom/pan with the mouse.
Full detail stays in the PLY: the browser gets the decimated copy, so that the page opens in a
few seconds on a machine without a GPU.

JavaScript contract (tests and scripts): ``<div id="viewer">`` holds the WebGL canvas;
``window.nail2nailReport = {ready, rotate(degrees), colorBy(name), show(kind)}``, every
method returning a promise resolved after the redraw.
"""

from __future__ import annotations

import base64
from pathlib import Path

import numpy as np

from nail2nail.frames import invert_transform
from nail2nail.io._json import read_json
from nail2nail.io.ply import read_ply
from nail2nail.io.scans import load_scans
from nail2nail.report._html import Section, escape, json_for_script, note_html
from nail2nail.report._parts import CorruptPart, reading
from nail2nail.report.inputs import ReportInputs

__all__ = ["MIN_VERTICES", "cluster_vertices", "libraries", "seamless_faces", "section",
           "viewer_data"]

#: Fewest super-scan vertices the viewer shows (fewer: the section says the scan is missing).
MIN_VERTICES = 3

#: Camera colours (index order of the scans), also in the legend.
CAMERA_COLOURS = ("#d62728", "#2ca02c", "#1f77b4", "#ff7f0e", "#9467bd", "#8c564b")


#: The page's JavaScript contract without a viewer (no super scan, or a corrupt one): `ready`
#: resolves, the methods exist.
STUB_JS = ("window.nail2nailReport = {ready: Promise.resolve(), rotate: () => "
           "Promise.resolve(), colorBy: () => Promise.resolve(), show: () => "
           "Promise.resolve()};")

#: plotly.js's 3D-only bundle (``vendor/README.md``: package, version, licence, checksum).
PLOTLY_JS = Path(__file__).parent / "vendor" / "plotly-gl3d.min.js"


def libraries() -> list[str]:
    """Inline JavaScript the viewer needs in the page head: plotly.js's 3D bundle (offline)."""
    return [PLOTLY_JS.read_text(encoding="utf-8")]


def cluster_vertices(points, faces=None, *, max_vertices: int, attributes=()):
    """Decimate a mesh (or a point cloud) by vertex clustering on a regular grid.

    Parameters
    ----------
    points : (N, 3) float
        Vertex positions, mm.
    faces : (M, 3) int, optional
        Triangles (vertex indices).
    max_vertices : int
        Most vertices kept: the cube size grows (×1.25 per step, from the cloud's mean
        spacing) until at most this many cubes are occupied. ``N <= max_vertices``: nothing is
        merged.
    attributes : sequence of (N,) or (N, k) float arrays
        Per-vertex values averaged per cube (NaN ignored: a cube of NaN stays NaN).

    Returns
    -------
    points : (K, 3) float64
        Mean position of each occupied cube.
    faces : (L, 3) int64 or None
        Triangles whose three vertices fell into three different cubes, re-indexed; each
        distinct triangle once.
    attributes : list of arrays
        Per-cube means of `attributes`.
    labels : (N,) int64
        The cube (output vertex) of every input vertex.
    """
    points = np.asarray(points, dtype=float)
    n = len(points)
    if max_vertices < 1:
        raise ValueError(f"max_vertices: expected a positive count, got {max_vertices}")
    if n <= max_vertices:
        labels = np.arange(n)
    else:
        lo, hi = points.min(axis=0), points.max(axis=0)
        extent = np.maximum(hi - lo, 1e-9)
        # a surface of N points over this box: spacing ~ sqrt(area / N), area ~ the box's
        # two largest faces; start below the answer and grow
        size = float(np.sqrt(np.sort(extent)[1:].prod() / max_vertices)) * 0.5
        while True:
            cells = np.floor((points - lo) / size).astype(np.int64)
            dims = cells.max(axis=0) + 1
            key = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
            _, labels = np.unique(key, return_inverse=True)
            if labels.max() + 1 <= max_vertices:
                break
            size *= 1.25
    k = int(labels.max()) + 1 if n else 0
    counts = np.bincount(labels, minlength=k).astype(float)
    out_points = np.stack([np.bincount(labels, points[:, i], k) / counts for i in range(3)], 1)
    out_attributes = [_cluster_mean(labels, np.asarray(a, dtype=float), k) for a in attributes]
    out_faces = None
    if faces is not None:
        f = labels[np.asarray(faces, dtype=np.int64)]
        keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
        f = f[keep]
        # the same triangle from several fine ones: once (orientation kept of the first)
        rolled = np.sort(f, axis=1)
        _, first = np.unique(rolled, axis=0, return_index=True)
        out_faces = f[np.sort(first)]
    return out_points, out_faces, out_attributes, labels


def seamless_faces(points, faces=None) -> tuple[np.ndarray | None, dict]:
    """One seamless mesh over `points`, or `faces` where it is not better.

    :func:`nail2nail.merge.mesh.seamless_mesh`: the points triangulated in the plane of a
    cylinder fitted about them, unrolled; wound to face away from the cloud's middle.

    Parameters
    ----------
    points : (N, 3) float
        Vertices, mm.
    faces : (M, 3) int, optional
        The mesh to fall back on (the clustered super scan's).

    Returns
    -------
    faces : (F, 3) int64 or None
        The seamless triangles when they leave no more boundary edges than `faces` (or
        `faces` is None) and no edge shared by three triangles; else `faces`.
    topology : dict
        ``{"seamless": bool, "boundary_edges": int, "non_manifold_edges": int}`` of the
        faces returned, for the page's note.
    """
    from nail2nail.merge.mesh import mesh_topology, seamless_mesh

    points = np.asarray(points, dtype=float)
    old = None if faces is None else mesh_topology(faces, len(points))
    try:
        # wound to face away from the cloud's middle (the finger's inside)
        new_faces = seamless_mesh(points, normals=points - points.mean(axis=0))
    except ValueError:  # too few points, or a surface no cylinder fits
        new_faces = None
    new = None if new_faces is None else mesh_topology(new_faces, len(points))
    if new is not None and new["non_manifold_edges"] == 0 and (
            old is None or new["boundary_edges"] <= old["boundary_edges"]):
        return new_faces, {"seamless": True, "boundary_edges": new["boundary_edges"],
                           "non_manifold_edges": 0}
    return faces, {"seamless": False,
                   "boundary_edges": None if old is None else old["boundary_edges"],
                   "non_manifold_edges": None if old is None else old["non_manifold_edges"]}


def _cluster_mean(labels: np.ndarray, values: np.ndarray, k: int) -> np.ndarray:
    flat = values.reshape(len(values), -1)
    out = np.empty((k, flat.shape[1]))
    for j in range(flat.shape[1]):  # a few columns, not pixels
        finite = np.isfinite(flat[:, j])
        total = np.bincount(labels[finite], flat[finite, j], k)
        count = np.bincount(labels[finite], minlength=k)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[:, j] = np.where(count > 0, total / np.maximum(count, 1), np.nan)
    return out.reshape((k, *values.shape[1:]))


def _world_points(inputs: ReportInputs, points: np.ndarray) -> np.ndarray:
    """Super-scan vertices (written in ``super_scan.frame``) in the world frame."""

    info = _merge_summary(inputs).get("super_scan", {})
    transform = np.asarray(info.get("T_frame_world", np.eye(4)), dtype=float)
    if transform.shape != (4, 4) or not np.all(np.isfinite(transform)):
        raise ValueError(f"super_scan.T_frame_world: expected a 4 × 4 matrix of finite "
                         f"numbers, got shape {transform.shape}")
    if np.allclose(transform, np.eye(4)):
        return points
    back = invert_transform(transform)
    return points @ back[:3, :3].T + back[:3, 3]


def _merge_summary(inputs: ReportInputs) -> dict:

    return read_json(inputs.merge / "merge.json") if inputs.merge is not None else {}


def _vertex_cameras(points: np.ndarray, inputs: ReportInputs) -> tuple[np.ndarray, list[str]]:
    """Index of the camera whose scan point is nearest to each vertex; the camera names."""
    from scipy.spatial import cKDTree

    if inputs.scans is None:
        return np.full(len(points), -1), []
    scans = load_scans(inputs.scans)
    best = np.full(len(points), np.inf)
    camera = np.full(len(points), -1)
    for i, scan in enumerate(scans):
        xyz = scan.xyz[scan.mask]
        if len(xyz) == 0:
            continue
        d, _ = cKDTree(xyz).query(points, workers=-1)
        closer = d < best
        best[closer], camera[closer] = d[closer], i
    return camera, [s.name for s in scans]


def _vertex_errors(points: np.ndarray, inputs: ReportInputs, spacing: float) -> np.ndarray:
    """Merge error (µm) of the pair points within 2 spacings of each vertex; NaN elsewhere."""
    from scipy.spatial import cKDTree

    xyz, error = [], []
    for pair in sorted(inputs.merge.glob("merge_*_mapping.npz")) if inputs.merge else []:
        try:
            with reading(pair), np.load(pair, allow_pickle=False) as data:
                d = data["distance_mm"].astype(float) * 1e3
                parent, child = (np.asarray(data[k], float).reshape(-1, 3)
                                 for k in ("xyz_parent", "xyz_child"))
                if not len(parent) == len(child) == len(d):
                    raise ValueError("xyz_parent, xyz_child and distance_mm differ in length")
        except CorruptPart as exc:  # the error colouring without this pair
            inputs.problems.append((exc.path, exc.reason))
            continue
        keep = np.all(np.isfinite(parent), axis=1) & np.all(np.isfinite(child), axis=1)
        xyz += [parent[keep], child[keep]]
        error += [d[keep], d[keep]]
    if not xyz:
        return np.full(len(points), np.nan)
    d, index = cKDTree(np.concatenate(xyz)).query(points, workers=-1,
                                                  distance_upper_bound=2 * spacing)
    values = np.concatenate(error)
    found = np.isfinite(d)
    out = np.full(len(points), np.nan)
    out[found] = values[index[found]]
    return out


def viewer_data(inputs: ReportInputs, *, max_points: int = 60_000,
                detail_points: int | None = None) -> dict | None:
    """The decimated super scan and its colourings, as the page's JavaScript reads them.

    Parameters
    ----------
    inputs : ReportInputs
    max_points : int
        Vertices of the mesh the page opens with.
    detail_points : int, optional
        Vertices of the "full detail" point cloud the page switches to on a click or when the
        user zooms in (default ``4 * max_points``; the whole scan when it has fewer; 0: none).
        Decoded only when shown, so it costs the page's size, not its opening time.

    Returns
    -------
    dict or None
        ``{"source_vertices", "source_faces", "cameras", "levels": {"base": level,
        ["detail": level]}}``, each level ``{"n_vertices", "n_faces", "mesh" (the base
        level: :func:`seamless_faces`'s topology, else None), "spacing_mm", "xyz"
        (base64 float32 (K, 3), mm, world frame), "faces" (base64 int32 (L, 3)), "albedo"
        (base64 float32, 0..1), "camera" (base64 float32 index, -1 none), "error" (base64
        float32 µm, NaN where no pair), "albedo_range", "error_range", "error_coverage"}``;
        ``None`` without a super scan, or one of fewer than :data:`MIN_VERTICES` vertices.
    """

    if inputs.merge is None or not (inputs.merge / "super.ply").is_file():
        return None
    with reading(inputs.merge / "super.ply"):
        ply = read_ply(inputs.merge / "super.ply")
        if not np.all(np.isfinite(ply.points)):
            raise ValueError("vertices with NaN or infinite coordinates")
    if len(ply.points) < MIN_VERTICES:  # nothing to look at (a failed fusion): no viewer
        return None
    with reading(inputs.merge / "merge.json"):
        points = _world_points(inputs, ply.points.astype(float))
    albedo = (ply.colors.astype(float).mean(axis=1) / 255 if ply.colors is not None
              else np.full(len(points), 0.7))
    try:  # corrupt scans: the viewer without the camera colouring
        with reading(inputs.scans / "scan.json" if inputs.scans else inputs.root):
            camera, names = _vertex_cameras(points, inputs)
    except CorruptPart as exc:
        inputs.problems.append((exc.path, exc.reason))
        camera, names = np.full(len(points), -1), []
    one_hot = np.eye(max(len(names), 1))[np.maximum(camera, 0)] * (camera >= 0)[:, None]
    levels = {"base": _level(points, ply.faces, albedo, one_hot, inputs, max_points)}
    detail = 4 * max_points if detail_points is None else detail_points
    if detail > max_points and len(points) > max_points:
        levels["detail"] = _level(points, None, albedo, one_hot, inputs, detail)
    return {
        "source_vertices": len(points),
        "source_faces": 0 if ply.faces is None else len(ply.faces),
        "cameras": names,
        "levels": levels,
    }


def _level(points, faces, albedo, one_hot, inputs: ReportInputs, max_vertices: int) -> dict:
    """One level of detail of the viewer: vertices, triangles and the three colourings."""
    from scipy.spatial import cKDTree

    small, small_faces, (albedo_k, camera_hist), _ = cluster_vertices(
        points, faces, max_vertices=max_vertices, attributes=(albedo, one_hot))
    mesh = None
    if faces is not None:
        small_faces, mesh = seamless_faces(small, small_faces)
    camera_k = np.where(camera_hist.max(axis=1) > 0, camera_hist.argmax(axis=1), -1)
    # vertex spacing of the decimated cloud: the pairing radius of the merge errors
    spacing = float(np.median(cKDTree(small).query(small[:20_000], k=2)[0][:, 1]))
    error = _vertex_errors(small, inputs, max(spacing, 1e-6))
    finite = error[np.isfinite(error)]
    return {
        "n_vertices": len(small),
        "n_faces": 0 if small_faces is None else len(small_faces),
        "mesh": mesh,
        "spacing_mm": spacing,
        "xyz": _b64(small, np.float32),
        "faces": _b64(np.zeros((0, 3)) if small_faces is None else small_faces, np.int32),
        "albedo": _b64(albedo_k, np.float32),
        "camera": _b64(camera_k, np.float32),
        "error": _b64(error, np.float32),
        # the albedo's grey scale stretched over its 1st..99th percentile, for contrast
        "albedo_range": np.nanpercentile(albedo_k, [1, 99]).tolist(),
        "error_range": [0.0, float(np.percentile(finite, 95)) if finite.size else 1.0],
        "error_coverage": float(finite.size / max(len(error), 1)),
    }


def _b64(array, dtype) -> str:
    return base64.b64encode(np.ascontiguousarray(array, dtype=dtype).tobytes()).decode("ascii")


def section(inputs: ReportInputs, *, max_points: int = 60_000) -> Section:
    """The 3D viewer section (``<div id="viewer">`` and its script)."""
    data = viewer_data(inputs, max_points=max_points)
    if data is None:
        where = inputs.merge / "super.ply" if inputs.merge else inputs.root / "merge/super.ply"
        body = note_html(f"No super scan: {where} not found or with fewer than {MIN_VERTICES} "
                         "vertices (merge writes it).", "missing")
        return Section("view3d", "3D viewer", body, status="missing", scripts=[STUB_JS])
    base, detail = data["levels"]["base"], data["levels"].get("detail")
    legend = " ".join(
        f'<span style="color:{CAMERA_COLOURS[i % len(CAMERA_COLOURS)]}">■ {escape(n)}</span>'
        for i, n in enumerate(data["cameras"]))
    mesh = base.get("mesh") or {}
    if mesh.get("seamless"):
        decimated = (f"The mesh shows {base['n_vertices']:,} of the scan's "
                     f"{data['source_vertices']:,} vertices (vertex clustering, "
                     f"{1e3 * base['spacing_mm']:.0f} µm apart) as one seamless surface of "
                     f"{base['n_faces']:,} triangles ({mesh['boundary_edges']:,} boundary "
                     "edges)")
    else:
        decimated = (f"The mesh shows {base['n_vertices']:,} of the scan's "
                     f"{data['source_vertices']:,} vertices and {base['n_faces']:,} of its "
                     f"{data['source_faces']:,} triangles (vertex clustering, "
                     f"{1e3 * base['spacing_mm']:.0f} µm apart)")
    if detail is not None:
        decimated += (f"; 'detail' (or zooming in) shows {detail['n_vertices']:,} points, "
                      f"{1e3 * detail['spacing_mm']:.0f} µm apart")
    detail_button = ('<button data-show="detail">detail</button>' if detail is not None
                     else "")
    body = (
        '<div class="controls">Colour by: '
        '<button data-color="albedo" class="active">albedo</button>'
        '<button data-color="camera">camera</button>'
        '<button data-color="error">merge error</button>'
        ' &nbsp; Show: <button data-show="mesh" class="active">mesh</button>'
        '<button data-show="points">points</button>' + detail_button +
        ' &nbsp; <button data-reset="1">reset view</button></div>'
        '<div id="viewer"></div>'
        f'<p class="note">Drag to orbit, scroll to zoom, right-drag to pan. {decimated}; the '
        "full scan is merge/super.ply (--report-points sets the mesh's size). Cameras: "
        + legend + ". Merge error: distance between the corresponding points of two cameras "
        f"(µm, colour scale to its 95th percentile) on {100 * base['error_coverage']:.0f}% of "
        "the vertices; grey where one camera alone sees the finger.</p>"
    )
    # the detail level is inert JSON (not script): the browser only tokenises it at load and
    # JavaScript parses it when first shown, which keeps it out of the opening time
    levels = {"base": base}
    if detail is not None:
        body += ('<script type="application/json" id="viewer-detail">'
                 + json_for_script(detail) + "</script>")
    payload = json_for_script({**data, "levels": levels, "colours": list(CAMERA_COLOURS)})
    script = _VIEWER_JS.replace("__DATA__", payload)
    return Section("view3d", "3D viewer", body, scripts=[script])


_VIEWER_JS = r"""
(() => {
"use strict";
const data = __DATA__;
const decode = (b64, Type) => {
  const s = atob(b64), bytes = new Uint8Array(s.length);
  for (let i = 0; i < s.length; i++) bytes[i] = s.charCodeAt(i);
  return new Type(bytes.buffer);
};
// a level of detail, decoded when first shown (the detail level may never be)
const detailNode = document.getElementById("viewer-detail");
const cache = {};
const level = (name) => {
  if (cache[name]) return cache[name];
  const L = name === "detail" ? JSON.parse(detailNode.textContent) : data.levels[name];
  const n = L.n_vertices, m = L.n_faces;
  const xyz = decode(L.xyz, Float32Array), faces = decode(L.faces, Int32Array);
  const out = {L, n, m, x: new Float32Array(n), y: new Float32Array(n), z: new Float32Array(n),
    i: new Int32Array(m), j: new Int32Array(m), k: new Int32Array(m),
    albedo: decode(L.albedo, Float32Array), camera: decode(L.camera, Float32Array),
    error: decode(L.error, Float32Array)};
  for (let v = 0; v < n; v++) {
    out.x[v] = xyz[3 * v]; out.y[v] = xyz[3 * v + 1]; out.z[v] = xyz[3 * v + 2];
  }
  for (let t = 0; t < m; t++) {
    out.i[t] = faces[3 * t]; out.j[t] = faces[3 * t + 1]; out.k[t] = faces[3 * t + 2];
  }
  // "no pair" sits in a grey band below the colour scale (plotly draws NaN inconsistently)
  const top = L.error_range[1] || 1;
  out.errorLow = -top / 40;
  for (let v = 0; v < n; v++) if (!Number.isFinite(out.error[v])) out.error[v] = out.errorLow;
  return (cache[name] = out);
};
const NONE = "#b8bcc4";
const nc = Math.max(data.cameras.length, 1);
const schemes = {
  albedo: (D) => ({values: D.albedo, cmin: D.L.albedo_range[0],
    cmax: Math.max(D.L.albedo_range[1], D.L.albedo_range[0] + 1e-3),
    colorscale: [[0, "#000000"], [1, "#ffffff"]], title: "albedo"}),
  camera: (D) => {
    const scale = [[0, NONE], [1 / (nc + 1), NONE]];
    for (let c = 0; c < nc; c++) {
      const col = data.colours[c % data.colours.length];
      scale.push([(c + 1) / (nc + 1), col], [(c + 2) / (nc + 1), col]);
    }
    return {values: D.camera, cmin: -1, cmax: nc - 1 + 1e-6, colorscale: scale,
      title: "camera", showscale: false};
  },
  error: (D) => {
    const f = (1 / 41) * 0.999, viridis = ["#440154", "#3b528b", "#21918c", "#5ec962", "#fde725"];
    const scale = [[0, NONE], [f, NONE]];
    viridis.forEach((c, i) => scale.push([f + 1e-4 + (1 - f - 1e-4) * i / 4, c]));
    return {values: D.error, cmin: D.errorLow, cmax: D.L.error_range[1] || 1, colorscale: scale,
      title: "merge error (µm)"};
  },
};
const div = document.getElementById("viewer");
const base = level("base");
let current = "albedo", shown = base.m > 0 ? "mesh" : "points", angle = 0;
const eye0 = {x: 0, y: 0.3, z: 2.5};
const eye = () => {
  const a = angle * Math.PI / 180;
  return {x: eye0.x * Math.cos(a) + eye0.z * Math.sin(a), y: eye0.y,
          z: -eye0.x * Math.sin(a) + eye0.z * Math.cos(a)};
};
const colourbar = (s) => ({title: {text: s.title}, len: 0.6, thickness: 14});
const traces = () => {
  const D = shown === "detail" ? level("detail") : base, s = schemes[current](D);
  const common = {cmin: s.cmin, cmax: s.cmax, colorscale: s.colorscale,
                  showscale: s.showscale !== false, colorbar: colourbar(s)};
  // only the trace shown: plotly converts hidden traces too
  if (shown === "mesh") {
    return [{type: "mesh3d", x: D.x, y: D.y, z: D.z, i: D.i, j: D.j, k: D.k,
      intensity: s.values, ...common, flatshading: false, hoverinfo: "skip",
      lighting: {ambient: 0.45, diffuse: 0.75, specular: 0.15, roughness: 0.6},
      lightposition: {x: 0, y: 200, z: 1000}}];
  }
  return [{type: "scatter3d", mode: "markers", x: D.x, y: D.y, z: D.z, hoverinfo: "skip",
    marker: {size: shown === "detail" ? 1.2 : 1.6, color: s.values, ...common}}];
};
const layout = {
  margin: {l: 0, r: 0, t: 0, b: 0}, paper_bgcolor: "#ffffff", showlegend: false,
  scene: {aspectmode: "data", dragmode: "orbit",
          xaxis: {visible: false}, yaxis: {visible: false}, zaxis: {visible: false},
          camera: {up: {x: 0, y: 1, z: 0}, eye: eye(), center: {x: 0, y: 0, z: 0},
                   projection: {type: "perspective"}}},
};
const frame = () => new Promise((resolve) => requestAnimationFrame(() =>
  requestAnimationFrame(resolve)));
const keepCamera = () => { layout.scene.camera = div._fullLayout.scene.camera; };
const redraw = () => Plotly.react(div, traces(), layout).then(frame);
const mark = () => document.querySelectorAll(".controls button").forEach((b) => {
  b.classList.toggle("active", b.dataset.color === current || b.dataset.show === shown);
});
const report = {
  ready: Plotly.newPlot(div, traces(), layout,
                        {responsive: true, displaylogo: false}).then(frame),
  rotate: (degrees) => {
    angle += Number(degrees);
    layout.scene.camera = {...div._fullLayout.scene.camera, eye: eye()};
    return redraw();
  },
  colorBy: (name) => {
    if (!(name in schemes)) return Promise.reject(new Error("colorBy: unknown " + name));
    current = name; mark(); keepCamera();
    return redraw();
  },
  show: (kind) => {
    if (!["mesh", "points", "detail"].includes(kind)) {
      return Promise.reject(new Error("show: unknown " + kind));
    }
    if (kind === "detail" && !detailNode) kind = "points";
    if (kind === "mesh" && base.m === 0) kind = "points";
    shown = kind; mark(); keepCamera();
    return redraw();
  },
};
// zooming in past twice the opening view shows the detail level (once; buttons go back)
let zoomed = false;
div.on("plotly_relayout", (change) => {
  const cam = change["scene.camera"];
  if (zoomed || !detailNode || !cam || !cam.eye || shown === "detail") return;
  const r = Math.hypot(cam.eye.x, cam.eye.y, cam.eye.z);
  if (r < 0.5 * Math.hypot(eye0.x, eye0.y, eye0.z)) { zoomed = true; report.show("detail"); }
});
document.querySelectorAll(".controls button").forEach((b) => b.addEventListener("click", () => {
  if (b.dataset.color) report.colorBy(b.dataset.color);
  if (b.dataset.show) report.show(b.dataset.show);
  if (b.dataset.reset) {
    angle = 0;
    layout.scene.camera = {...layout.scene.camera, eye: eye(), center: {x: 0, y: 0, z: 0}};
    redraw();
  }
}));
window.nail2nailReport = report;
})();
"""
