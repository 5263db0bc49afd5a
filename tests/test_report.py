"""The HTML report (issue 13): its inputs, the viewer's decimation, the command and its errors.

The browser checks (WebGL draws, rotation, console) are in tests/test_report_browser.py; the
capture, calibration and distortion sections in tests/test_report_sections.py.
"""

from __future__ import annotations

import base64
import hashlib
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nail2nail.cli import main
from nail2nail.report import build_report, find_inputs
from nail2nail.report.viewer import cluster_vertices, viewer_data

SECTIONS = ("overview", "capture", "calibration", "distortion", "merge", "view3d", "print")


# -- vertex clustering -------------------------------------------------------------------------

@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 400), k=st.integers(1, 120), seed=st.integers(0, 2**16))
def test_cluster_vertices_invariants(n, k, seed):
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(n, 3)) * [10, 20, 3]
    faces = rng.integers(0, n, size=(2 * n, 3))
    value = rng.normal(size=n)
    out, out_faces, (mean,), labels = cluster_vertices(points, faces, max_vertices=k,
                                                       attributes=(value,))
    assert len(out) <= max(k, 1) and labels.shape == (n,)
    assert set(np.unique(labels)) == set(range(len(out)))  # every output vertex is used
    # each output vertex is the mean of its cluster, and so is its attribute
    for c in np.unique(labels)[:5]:
        np.testing.assert_allclose(out[c], points[labels == c].mean(axis=0), atol=1e-9)
        np.testing.assert_allclose(mean[c], value[labels == c].mean(), atol=1e-9)
    if len(out_faces):
        assert out_faces.min() >= 0 and out_faces.max() < len(out)
        assert np.all(out_faces[:, 0] != out_faces[:, 1])
        assert np.all(out_faces[:, 1] != out_faces[:, 2])
        assert np.all(out_faces[:, 0] != out_faces[:, 2])
        assert len(np.unique(np.sort(out_faces, axis=1), axis=0)) == len(out_faces)
    if n <= k:  # nothing to merge: the mesh as it was, less its degenerate triangles
        np.testing.assert_array_equal(out, points)
        np.testing.assert_array_equal(labels, np.arange(n))


def test_cluster_vertices_keeps_a_surface_connected():
    # a 200 x 200 grid of a plane, two triangles per cell: decimated ~16x, still one sheet
    i, j = np.meshgrid(np.arange(200), np.arange(200), indexing="ij")
    points = np.stack([i.ravel() * 0.1, j.ravel() * 0.1, np.zeros(i.size)], axis=1)
    v = (i[:-1, :-1] * 200 + j[:-1, :-1]).ravel()
    faces = np.concatenate([np.stack([v, v + 1, v + 201], 1), np.stack([v, v + 201, v + 200], 1)])
    out, out_faces, _, _ = cluster_vertices(points, faces, max_vertices=2_500)
    assert 1_500 < len(out) <= 2_500
    area = 0.5 * np.linalg.norm(np.cross(out[out_faces[:, 1]] - out[out_faces[:, 0]],
                                         out[out_faces[:, 2]] - out[out_faces[:, 0]]), axis=1)
    # no holes: the triangles cover the square the vertices span (cluster means sit up to half
    # a cube inside the border, so that square is a little smaller than the plane)
    span = np.ptp(out[:, :2], axis=0)
    assert area.sum() == pytest.approx(span.prod(), rel=0.01)
    assert span.min() > 19


def test_cluster_vertices_bad_input():
    with pytest.raises(ValueError, match="max_vertices"):
        cluster_vertices(np.zeros((3, 3)), max_vertices=0)


# -- inputs ------------------------------------------------------------------------------------

def test_find_inputs_of_each_kind(processed_finger):
    out = processed_finger
    inputs = find_inputs(out)
    assert inputs.kind == "process" and inputs.notes == []
    assert inputs.scans == out / "scans" and inputs.merge == out / "merge"
    assert inputs.print == out / "print"
    assert (inputs.capture / "capture.json").is_file() and inputs.calibration.is_file()
    assert find_inputs(out / "scans").kind == "scans"
    assert find_inputs(out / "merge").kind == "merge"


def test_find_inputs_bad_directory(tmp_path):
    with pytest.raises(ValueError, match="not a directory"):
        find_inputs(tmp_path / "absent")
    with pytest.raises(ValueError, match="not a nail2nail output directory"):
        find_inputs(tmp_path)


# -- the viewer's data -------------------------------------------------------------------------

def test_viewer_data_colourings(processed_finger):
    import base64

    inputs = find_inputs(processed_finger)
    whole = viewer_data(inputs, max_points=5_000)
    merged = json.loads((processed_finger / "merge" / "merge.json").read_text())
    assert whole["source_vertices"] == merged["super_scan"]["vertices"]
    assert whole["cameras"] == ["cam0", "cam1", "cam2"]
    data, detail = whole["levels"]["base"], whole["levels"]["detail"]
    assert data["n_vertices"] <= 5_000 and data["n_faces"] > data["n_vertices"]
    assert 5_000 < detail["n_vertices"] <= 20_000 and detail["n_faces"] == 0
    assert detail["spacing_mm"] < data["spacing_mm"]

    def arr(key, dtype):
        return np.frombuffer(base64.b64decode(data[key]), dtype=dtype)

    xyz = arr("xyz", np.float32).reshape(-1, 3)
    camera = arr("camera", np.float32)
    error = arr("error", np.float32)
    assert len(xyz) == len(camera) == len(error) == data["n_vertices"]
    # every camera owns a share of the vertices, cam1 (front) the middle of the finger
    assert set(np.unique(camera)) <= {-1, 0, 1, 2} and np.all(np.bincount(
        camera[camera >= 0].astype(int), minlength=3) > 0.1 * len(camera))
    assert np.median(xyz[camera == 0, 0]) < np.median(xyz[camera == 1, 0]) < np.median(
        xyz[camera == 2, 0])
    # merge errors where two cameras overlap, of the size merge.json reports
    found = error[np.isfinite(error)]
    assert 0.2 < data["error_coverage"] < 1 and len(found) == round(
        data["error_coverage"] * len(error))
    medians = [1e3 * m["distance_mm"]["median"] for m in merged["merge"].values()]
    assert 0.5 * min(medians) < np.median(found) < 2 * max(medians)


def test_viewer_mesh_is_one_seamless_surface(processed_finger):
    """Issue 27: the viewer's mesh joins the cameras (the super scan's grids stop a pixel apart
    at every seam): no edge of three triangles, one winding, the boundary only on the outline
    (every boundary edge within 3 vertex spacings of the decimated cloud's outline in the
    rolled print plane), and fewer boundary edges than the clustered grids had."""
    import base64

    from nail2nail.merge.mesh import mesh_topology
    from nail2nail.report.viewer import seamless_faces

    inputs = find_inputs(processed_finger)
    data = viewer_data(inputs, max_points=5_000, detail_points=0)["levels"]["base"]
    assert data["mesh"]["seamless"] and data["mesh"]["non_manifold_edges"] == 0
    xyz = np.frombuffer(base64.b64decode(data["xyz"]), np.float32).reshape(-1, 3)
    faces = np.frombuffer(base64.b64decode(data["faces"]), np.int32).reshape(-1, 3)
    topology = mesh_topology(faces, len(xyz))
    assert topology["non_manifold_edges"] == 0 and topology["inconsistent_edges"] == 0
    assert topology["isolated_vertices"] <= 0.01 * len(xyz)
    # against the super scan's own triangles, clustered the same way
    from nail2nail.io.ply import read_ply

    ply = read_ply(processed_finger / "merge" / "super.ply")
    small, clustered, _, _ = cluster_vertices(ply.points, ply.faces, max_vertices=5_000)
    before = mesh_topology(clustered, len(small))
    after = mesh_topology(seamless_faces(small, clustered)[0], len(small))
    print("\nclustered grids:", before, "\nseamless:", after)
    assert after["boundary_edges"] < 0.5 * before["boundary_edges"]
    assert after["non_manifold_edges"] == 0 and after["non_manifold_vertices"] <= 0.002 * len(
        small)


def test_seamless_faces_fall_back_on_a_flat_cloud():
    """A surface the rolled map cannot unroll (a plane: no axis to roll around) keeps the given
    triangles, or is meshed no worse."""
    from nail2nail.merge.mesh import mesh_topology
    from nail2nail.report.viewer import seamless_faces

    x, y = np.meshgrid(np.linspace(0, 10, 30), np.linspace(0, 8, 25))
    points = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], -1)
    from nail2nail.merge.fusion import grid_mesh

    _, grid = grid_mesh(points.reshape(25, 30, 3), np.ones((25, 30), bool), max_edge_mm=1.0,
                        normals=np.broadcast_to([0.0, 0.0, 1.0], (25, 30, 3)))
    faces, info = seamless_faces(points, grid)
    assert mesh_topology(faces, len(points))["boundary_edges"] <= mesh_topology(
        grid, len(points))["boundary_edges"]
    assert info["non_manifold_edges"] == 0


# -- the command -------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def report_html(processed_finger, tmp_path_factory) -> tuple[Path, str]:
    path = tmp_path_factory.mktemp("report") / "r.html"
    assert main(["-q", "report", str(processed_finger), "--out", str(path),
                 "--report-points", "8000"]) == 0
    return path, path.read_text()


def test_report_has_every_section_and_is_self_contained(report_html, processed_finger):
    path, html = report_html
    for sid in SECTIONS:
        assert f'<section id="{sid}">' in html, sid
    assert html.count('id="viewer"') == 1
    # nothing loaded from elsewhere: every src/href is a data: URI or an anchor
    refs = re.findall(r'<(?:img|script|link|iframe)[^>]*\b(?:src|href)="([^"]*)"', html)
    assert refs and all(r.startswith(("data:", "#")) for r in refs)
    assert "window.nail2nailReport" in html and "Plotly.newPlot" in html
    merged = json.loads((processed_finger / "merge" / "merge.json").read_text())
    for key, m in merged["merge"].items():  # the table shows merge.json's figures
        assert f"<td>{key}</td>" in html
        assert f"<td>{1e3 * m['distance_mm']['median']:.2f}</td>" in html
        assert m["pair_by"] == "xpyp"  # a still capture triangulated from both coordinates
    assert "<td>xp, yp</td>" in html
    meta = json.loads((processed_finger / "print" / "print.json").read_text())
    assert f"{meta['shape'][1]} × {meta['shape'][0]} px" in html
    assert html.count("data:image/png;base64,") >= 6
    assert path.stat().st_size < 30e6


def test_detail_level_is_inert_json(report_html):
    # the detail level rides as JSON the page parses only when shown (not in the opening time)
    _, html = report_html
    found = re.search(r'<script type="application/json" id="viewer-detail">(.*?)</script>', html,
                      re.S)
    assert found
    detail = json.loads(found.group(1))
    assert detail["n_faces"] == 0 and 8_000 < detail["n_vertices"] <= 32_000
    xyz = np.frombuffer(base64.b64decode(detail["xyz"]), np.float32)
    assert xyz.size == 3 * detail["n_vertices"] and np.isfinite(xyz).all()


def test_vendored_plotly_is_the_recorded_release():
    # report/vendor/README.md records package, version and checksum: the file is never edited
    from nail2nail.report.viewer import PLOTLY_JS

    text = PLOTLY_JS.read_bytes()
    record = (PLOTLY_JS.parent / "README.md").read_text()
    assert b"plotly.js (gl3d - minified) v3.3.1" in text[:200]
    assert "| 3.3.1 |" in record
    assert hashlib.sha256(text).hexdigest() in record
    assert (PLOTLY_JS.parent / "plotly-gl3d.LICENSE").read_text().startswith("MIT License")


def test_process_report_and_default_path(processed_finger, tmp_path, capsys):
    out = tmp_path / "copy"
    shutil.copytree(processed_finger, out)
    assert main(["report", str(out)]) == 0
    assert (out / "report.html").is_file()
    assert f"wrote {out / 'report.html'}" in capsys.readouterr().out


def test_partial_directories(processed_finger, tmp_path):
    merge_only = tmp_path / "merge"
    shutil.copytree(processed_finger / "merge", merge_only)
    html = build_report(merge_only, max_points=2_000)
    assert html.count('class="missing"') >= 3  # capture, calibration, print …
    assert "window.nail2nailReport" in html
    no_super = tmp_path / "scans"
    shutil.copytree(processed_finger / "scans", no_super)
    html = build_report(no_super)
    # no super scan: the page still keeps its contract (ready resolves, methods exist)
    assert "No super scan" in html and "window.nail2nailReport = {ready: Promise.resolve()" in html
    from nail2nail.io.ply import write_ply

    write_ply(merge_only / "super.ply", np.zeros((0, 3)))  # a fusion that kept nothing
    assert "No super scan" in build_report(merge_only)


def test_bad_input_writes_nothing(processed_finger, tmp_path, capsys):
    assert main(["report", str(tmp_path / "absent")]) == 2
    assert "not a directory" in capsys.readouterr().err
    assert main(["report", str(tmp_path)]) == 2
    assert "not a nail2nail output directory" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
    # a corrupt merge.json (issue 29): its sections say so, the rest is drawn, one warning
    # naming it, exit 0 (tests/test_robustness_messages.py); an unwritable --out: exit 2, an
    # earlier report kept, no temporary file
    out = tmp_path / "job"
    shutil.copytree(processed_finger, out, ignore=shutil.ignore_patterns("report.html"))
    (out / "merge" / "merge.json").write_text("{not json")
    assert main(["report", str(out), "--report-points", "2000"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "merge.json: not valid JSON" in err[0]
    (out / "report.html").write_text("earlier")
    (out / "blocker").write_text("a file")
    assert main(["report", str(out), "--out", str(out / "blocker" / "report.html")]) == 2
    assert "blocker" in capsys.readouterr().err
    assert (out / "report.html").read_text() == "earlier"
    assert not [p for p in out.iterdir() if p.name.startswith(".report.html")]
    assert main(["report", str(processed_finger), "--out", str(tmp_path)]) == 2
    assert "is a directory" in capsys.readouterr().err
    assert main(["report", str(processed_finger), "--report-points", "5"]) == 2


HOSTILE = "<!--<script><img src=x onerror=alert(1)>$^"


def _renamed_copy(processed_finger: Path, dst: Path, names: dict[str, str]) -> Path:
    """A copy of the processed finger and its capture with cameras renamed in every JSON."""
    src_root = processed_finger.parent
    shutil.copytree(src_root / "capture", dst / "capture")
    shutil.copytree(processed_finger, dst / "out", ignore=shutil.ignore_patterns("report.html"))

    def sub(o):
        if isinstance(o, dict):
            return {names.get(k, k): sub(v) for k, v in o.items()}
        if isinstance(o, list):
            return [sub(v) for v in o]
        if isinstance(o, str):
            return names.get(o, o.replace(str(src_root), str(dst)))
        return o

    for path in [*dst.rglob("*.json")]:
        path.write_text(json.dumps(sub(json.loads(path.read_text()))))
    return dst / "out"


def test_names_from_input_files_are_text_not_markup(processed_finger, tmp_path):
    out = _renamed_copy(processed_finger, tmp_path, {"cam0": HOSTILE})
    html = build_report(out, max_points=2_000)
    assert "<img src=x" not in html and "<!--<script>" not in html
    assert "&lt;img src=x onerror=alert(1)&gt;$^" in html  # shown as text in the page
    assert html.count("<script") == html.count("</script>")


@given(st.recursive(st.none() | st.booleans() | st.integers() | st.text(),
                    lambda children: st.lists(children, max_size=4)
                    | st.dictionaries(st.text(), children, max_size=4), max_leaves=12))
@settings(max_examples=200, deadline=None)
def test_json_for_script_is_inert_and_exact(data):
    from nail2nail.report._html import json_for_script

    text = json_for_script(data)
    assert not set("<>&") & set(text)  # nothing an HTML parser acts on inside <script>
    assert json.loads(text) == data


def test_script_safe_neutralises_closing_tags_and_comments():
    from nail2nail.report._html import _script_safe

    js = _script_safe('let a = "</SCRIPT>", b = "</script >", c = "<!--";')
    assert not re.search("</script", js, re.IGNORECASE) and "<!--" not in js


def test_missing_statistics_are_shown_as_dashes(processed_finger, tmp_path):
    out = tmp_path / "job"
    shutil.copytree(processed_finger, out, ignore=shutil.ignore_patterns("report.html"))
    merge_json = out / "merge" / "merge.json"
    summary = json.loads(merge_json.read_text())
    pair = next(iter(summary["merge"]))
    d = summary["merge"][pair]["distance_mm"]
    summary["merge"][pair]["distance_mm"] = dict.fromkeys(d)  # a pair without matches
    merge_json.write_text(json.dumps(summary))
    print_json = out / "print" / "print.json"
    meta = json.loads(print_json.read_text())
    meta["quality"] = {**meta["quality"], "clarity_median": None, "clarity_p10": None,
                       "ridge_period_mm_median": None}
    print_json.write_text(json.dumps(meta))
    html = build_report(out, max_points=2_000)
    assert f"merge {pair}: no matched pixels" in html
    assert "—, — over" in html  # the print's clarity


def test_merge_table_names_the_pairing_and_refuses_an_unknown_one(processed_finger, tmp_path):
    out = tmp_path / "job"
    shutil.copytree(processed_finger, out, ignore=shutil.ignore_patterns("report.html"))
    merge_json = out / "merge" / "merge.json"
    summary = json.loads(merge_json.read_text())
    first, second = list(summary["merge"])[:2]
    summary["merge"][first]["pair_by"] = "yp"
    del summary["merge"][second]["pair_by"]  # a merge written before the field: the thesis's
    merge_json.write_text(json.dumps(summary))
    html = build_report(out, max_points=2_000)
    assert "<td>yp + surface</td>" in html and "<td>xp, yp</td>" in html
    summary["merge"][first]["pair_by"] = "<b>zp</b>"
    merge_json.write_text(json.dumps(summary))
    with pytest.warns(UserWarning, match=f"merge.{first}.pair_by: expected one of"):
        html = build_report(out, max_points=2_000)
    assert f"merge.{first}.pair_by: expected one of" in html and "<b>zp</b>" not in html


def test_projector_panel_from_the_capture(processed_finger, tmp_path):
    from nail2nail.report.inputs import find_inputs, projector_panel
    from nail2nail.scan.patterns import PANEL_SIZE as DEFAULT_PANEL

    assert projector_panel(find_inputs(processed_finger)) == DEFAULT_PANEL  # as simulated
    out = _renamed_copy(processed_finger, tmp_path, {})
    manifest = tmp_path / "capture" / "capture.json"
    data = json.loads(manifest.read_text())
    data["projector"]["size"] = [800, 600]
    manifest.write_text(json.dumps(data))
    inputs = find_inputs(out)
    assert projector_panel(inputs) == (800, 600)  # the distortion grid's, a DLT's size
    data["projector"] = {}
    manifest.write_text(json.dumps(data))
    assert projector_panel(inputs) == DEFAULT_PANEL
