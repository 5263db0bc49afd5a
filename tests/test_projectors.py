"""Issue 26: rigs with more than one projector (layouts, coverage, same-pixel pairs, fusion)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from nail2nail.calibration.files import RigCalibration
from nail2nail.io.capture import read_capture, read_truth
from nail2nail.merge import correspond, same_pixel_pairs
from nail2nail.merge.fusion import fuse_scans
from nail2nail.scan.capture import scan_capture
from nail2nail.scan.results import Scan
from nail2nail.simulation.projectors import (
    LAYOUTS,
    projector_rigs,
    rolled_coverage,
    turned_projector,
)
from nail2nail.simulation.render import camera_geometry
from nail2nail.simulation.rig import Rig, default_rig, ideal_calibration
from nail2nail.simulation.scenes import make_scene
from nail2nail.simulation.truth import surface_distance


# -- layouts ---------------------------------------------------------------------------------
@pytest.mark.parametrize("azimuth", [-75.0, -45.0, 30.0, 90.0])
def test_turned_projector_keeps_its_distance_and_aim(azimuth):
    rig = default_rig(0.25)
    turned = turned_projector(rig, azimuth).projector
    p = rig.projector
    # the centre turns about the Y axis: height and distance from the axis kept
    c0, c1 = p.center, turned.center
    assert c1[1] == pytest.approx(c0[1])
    assert np.hypot(c1[0], c1[2]) == pytest.approx(np.hypot(c0[0], c0[2]))
    assert np.degrees(np.arctan2(c1[0], c1[2])) == pytest.approx(
        np.degrees(np.arctan2(c0[0], c0[2])) + azimuth)
    # a point on the axis projects to the same panel pixel: the aim is kept
    on_axis = np.array([[0.0, 3.0, 0.0], [0.0, 5.0, 0.0]])
    np.testing.assert_allclose(turned.project(on_axis), p.project(on_axis), atol=1e-6)
    np.testing.assert_allclose(turned.K, p.K)
    assert turned.size == p.size
    assert np.linalg.det(turned.R) == pytest.approx(1.0)


def test_projector_rigs_share_the_cameras():
    rig = default_rig(0.25)
    assert projector_rigs("thesis", rig) == [rig]
    rigs = projector_rigs("sides-60", rig)
    assert len(rigs) == len(LAYOUTS["sides-60"]) == 3
    assert rigs[0] is rig
    for r in rigs[1:]:
        assert r.cameras is rig.cameras or all(
            np.array_equal(a.R, b.R) and np.array_equal(a.K, b.K)
            for a, b in zip(r.cameras, rig.cameras, strict=True))
        assert r.projector_distortion == rig.projector_distortion
    assert len(projector_rigs((-45, 45), rig)) == 2


@pytest.mark.parametrize(("layout", "message"), [
    ("nope", "expected one of"), ((), "one or more"), ((10.0, 10.0), "repeat"),
    ((0.0, float("nan")), "finite"),
])
def test_projector_rigs_refuse_bad_layouts(layout, message):
    with pytest.raises(ValueError, match=message):
        projector_rigs(layout, default_rig(0.25))


# -- same-pixel pairs ------------------------------------------------------------------------
def _plane(name, *, dz=0.0, xp_scale=1.0, shape=(24, 30)):
    rr, cc = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float32)
    xyz = np.stack([cc * 0.1, rr * 0.1, 0 * rr + dz], -1).astype(np.float32)
    one = np.ones(shape, np.float32)
    return Scan(name, xyz, xp_scale * cc, rr + 3, one, one, one, one > 0)


def test_same_pixel_pairs_pair_the_pixel_with_itself():
    a = _plane("cam0-p0")
    b = _plane("cam0-p1", dz=0.004, xp_scale=-2.0)  # another projector: other coordinates
    hole = b.mask.copy()
    hole[10:14, 10:16] = False
    b = replace(b, mask=hole)
    m = same_pixel_pairs(a, b, outlier_mm=None)
    np.testing.assert_array_equal(m.parent_rc, m.child_nearest)
    np.testing.assert_allclose(m.distance_mm, 0.004, atol=1e-6)
    # the child's hole and its 2-px border are dropped as child_border
    inner_a = (20 * 26)  # the parent's inner region: 2 px off every edge
    assert m.n_sampled == 24 * 30
    assert m.dropped["parent_border"] == 24 * 30 - inner_a
    assert m.dropped["child_border"] == (4 + 4) * (6 + 4)
    assert m.n_pairs + sum(m.dropped.values()) == m.n_sampled
    # projector-space matching would pair nothing sensible here: other projectors' codes
    assert correspond(a, b, outlier_mm=None).n_pairs < m.n_pairs


def test_same_pixel_pairs_refuse_two_cameras():
    with pytest.raises(ValueError, match="one camera"):
        same_pixel_pairs(_plane("a"), _plane("b", shape=(24, 31)))


def test_fuse_scans_refuses_inconsistent_groups():
    scans = [_plane("a"), _plane("b", dz=0.001)]
    with pytest.raises(ValueError, match="one index per scan"):
        fuse_scans(scans, projectors=[0], cameras=[0, 0])
    with pytest.raises(ValueError, match="share both"):
        fuse_scans(scans, projectors=[0, 0], cameras=[1, 1])
    with pytest.raises(ValueError, match="differ in size"):
        fuse_scans([_plane("a"), _plane("b", shape=(24, 31))], projectors=[0, 1],
                   cameras=[0, 0])


# -- end to end: two projectors at ±45° on the virtual scanner -------------------------------
SCALE = 0.25
PITCH = 0.3  # coverage cells no finer than a pixel's footprint on grazing skin at this scale


@pytest.fixture(scope="module")
def layout_capture(tmp_path_factory):
    """``nail2nail simulate --projectors pair-45``: a finger under two projectors at ±45°."""
    from nail2nail.cli import main

    cap = tmp_path_factory.mktemp("layout") / "cap"
    assert main(["simulate", "--scene", "finger", "--projectors", "pair-45", "--scale",
                 str(SCALE), "--seed", "2", "--out", str(cap), "--json"]) == 0
    return cap


@pytest.fixture(scope="module")
def two_projectors(layout_capture):
    rig = default_rig(SCALE)
    scene = make_scene("finger", rig=rig, seed=2)
    scans, projectors, cameras, truths = [], [], [], []
    for k in range(2):
        out = layout_capture / f"p{k}"
        capture = read_capture(out, load=False)
        calib = RigCalibration.from_dict(ideal_calibration(Rig.from_capture(capture)))
        for i, s in enumerate(scan_capture(capture, calib, max_gradient=2.0)):
            scans.append(replace(s, name=f"{s.name}-p{k}"))
            projectors.append(k)
            cameras.append(i)
            truths.append(read_truth(out, s.name))
    return scene, scans, projectors, cameras, truths


def test_side_projectors_light_the_skin_to_the_nail_edges(layout_capture):
    """The thesis rig lights about 80 % of the nail-to-nail width; two projectors at ±45° all
    of it (the captures' true masks: the pixels each projector lights)."""
    rig = default_rig(SCALE)
    scene = make_scene("finger", rig=rig, seed=2)
    thesis = rolled_coverage(scene, [
        (g.mask, g.params["u"], g.params["v"])
        for g in (camera_geometry(rig, scene, i) for i in range(len(rig.cameras)))],
        pitch_mm=PITCH)
    truths = [read_truth(layout_capture / f"p{k}", f"cam{i}") for k in range(2)
              for i in range(3)]
    sides = rolled_coverage(scene, [(t["mask"], t["param_u"], t["param_v"]) for t in truths],
                            pitch_mm=PITCH)
    assert 0.7 < thesis["width_median"] < 0.88
    assert thesis["extent_mm"] == pytest.approx(sides["extent_mm"])
    assert sides["width_median"] >= 0.99 and sides["width_min"] >= 0.97
    assert sides["area"] > thesis["area"] + 0.1
    assert sides["span_mm"] > thesis["span_mm"] + 4


def test_two_projectors_fuse_nail_to_nail(two_projectors):
    scene, scans, projectors, cameras, truths = two_projectors
    sup = fuse_scans(scans, projectors=projectors, cameras=cameras)
    # every ordered pair of one projector or of one camera is matched, no other
    expected = {(i, j) for i in range(6) for j in range(6) if i != j
                and (projectors[i] == projectors[j] or cameras[i] == cameras[j])}
    assert set(sup.correspondences) == expected
    for (i, j), m in sup.correspondences.items():
        assert m.n_pairs > 0, (i, j)
        if cameras[i] == cameras[j]:
            np.testing.assert_array_equal(m.parent_rc, m.child_nearest)
    # no fused vertex farther than 50 µm from the true surface (along its true normal)
    for k, tr in enumerate(truths):
        r, c = sup.pixel[sup.camera == k].T
        assert tr["mask"][r, c].all()
    d = np.abs(surface_distance(sup.vertices, sup.camera, sup.pixel, truths))
    assert np.isfinite(d).all() and d.max() < 0.050, d.max()
    # both projectors' scans contribute, and the lit skin reaches the nail edges
    assert all(np.any(sup.camera == k) for k in range(6))
    cover = rolled_coverage(scene, [(s.mask, t["param_u"], t["param_v"])
                                    for s, t in zip(scans, truths, strict=True)], pitch_mm=PITCH)
    assert cover["width_median"] >= 0.95
    one = rolled_coverage(scene, [(s.mask, t["param_u"], t["param_v"])
                                  for s, t, p in zip(scans, truths, projectors, strict=True)
                                  if p == 0], pitch_mm=PITCH)
    assert one["width_median"] < cover["width_median"] - 0.05


# -- the commands: simulate --projectors, scan each, merge and unroll them together ----------
def test_cli_several_projectors_end_to_end(layout_capture, tmp_path, capsys):
    import json

    from nail2nail.cli import main

    cap = layout_capture
    layout = json.loads((cap / "projectors.json").read_text())
    assert [c["capture"] for c in layout["captures"]] == ["p0", "p1"]
    assert [c["azimuth_deg"] for c in layout["captures"]] == [-45.0, 45.0]
    assert layout["n_frames"] == 48 and layout["capture_s_at_120_fps"] == pytest.approx(0.4)
    scans = []
    for k in range(2):
        out = tmp_path / f"scans{k}"
        assert main(["scan", str(cap / f"p{k}"), "--calib",
                     str(cap / f"p{k}" / "truth" / "calibration.json"), "--out", str(out)]) == 0
        scans.append(str(out))
    capsys.readouterr()
    assert main(["merge", *scans, "--no-figures", "--out", str(tmp_path / "merge"),
                 "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["scan_dir"] == scans
    kinds = {key: m["kind"] for key, m in summary["merge"].items()}
    # per projector its neighbouring cameras, per camera its two projectors
    assert kinds == {"0-1": "projector", "1-2": "projector", "3-4": "projector",
                     "4-5": "projector", "0-3": "camera", "1-4": "camera", "2-5": "camera"}
    for key, m in summary["merge"].items():
        assert m["pairs"] > 0 and m["distance_mm"]["median"] < 0.01, key
    assert set(summary["super_scan"]["cameras"]) == {f"cam{i}-p{k}" for i in range(3)
                                                    for k in range(2)}
    assert main(["merge", *scans, "--pairs", "0-4", "--out", str(tmp_path / "bad")]) == 2
    assert "share neither a projector nor a camera" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()
    assert main(["unroll", *scans, "--out", str(tmp_path / "print"), "--no-wsq",
                 "--json"]) == 0
    meta = json.loads(capsys.readouterr().out)
    assert meta["scan_dir"] == scans and (tmp_path / "print" / "print.json").is_file()
    # a directory twice, and another rig's cameras, are refused
    assert main(["merge", scans[0], scans[0], "--out", str(tmp_path / "twice")]) == 2
    assert "given twice" in capsys.readouterr().err


def test_cli_process_of_several_projectors(layout_capture, tmp_path, capsys):
    """``nail2nail process`` on a capture of two projectors: rig.json stands for rig_p0.json and
    rig_p1.json; one scan directory holds all six scans with their projector and camera, which
    ``merge`` reads back to the same pairs; the print comes from all of them. Without the
    per-projector files the job is refused and nothing written."""
    import json
    import shutil

    from nail2nail.cli import main
    from nail2nail.io.scans import load_scan_dirs

    cap = layout_capture
    for k in range(2):
        shutil.copy(cap / f"p{k}" / "truth" / "calibration.json", tmp_path / f"rig_p{k}.json")
    job = tmp_path / "job"
    assert main(["process", str(cap), "--calib", str(tmp_path / "rig.json"), "--out", str(job),
                 "--no-wsq", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["projectors"] == ["p0", "p1"]
    assert summary["calibration"] == [str(tmp_path / f"rig_p{k}.json") for k in range(2)]
    assert set(summary["merge"]) == {"0-1", "1-2", "3-4", "4-5", "0-3", "1-4", "2-5"}
    for key, m in summary["merge"].items():
        assert m["pairs"] > 0 and m["distance_mm"]["median"] < 0.01, key
    scans, projectors, cameras = load_scan_dirs([job / "scans"])
    assert [s.name for s in scans] == [f"cam{i}-p{k}" for k in range(2) for i in range(3)]
    assert projectors == [0, 0, 0, 1, 1, 1] and cameras == [0, 1, 2, 0, 1, 2]
    assert all(s.projector_center is not None for s in scans)
    assert (job / "print" / "print.json").is_file()
    assert main(["merge", str(job / "scans"), "--no-figures", "--out", str(tmp_path / "m"),
                 "--json"]) == 0
    again = json.loads(capsys.readouterr().out)["merge"]
    assert {k: v["pairs"] for k, v in again.items()} == {
        k: v["pairs"] for k, v in summary["merge"].items()}
    assert main(["report", str(job)]) == 0
    capsys.readouterr()
    (tmp_path / "rig_p1.json").unlink()
    assert main(["process", str(cap), "--calib", str(tmp_path / "rig.json"), "--out",
                 str(tmp_path / "job2")]) == 2
    assert "rig_p1.json not found" in capsys.readouterr().err
    assert not (tmp_path / "job2").exists()


def test_cli_calibrates_several_projectors_with_shared_cameras(tmp_path, capsys):
    """``calibrate --model joint`` on a target capture of two projectors at ±45°: one bundle,
    one file per projector with the same cameras, each near the rig's truth (the side
    projectors leave a camera's far side of the target dark: it finds its marks lit by both)."""
    import json

    from nail2nail.calibration.files import load_calibration
    from nail2nail.cli import main

    cap = tmp_path / "target"
    # scale 0.5: the target's marks need about 20 px
    assert main(["simulate", "--scene", "target", "--projectors", "pair-45", "--scale", "0.5",
                 "--seed", "3", "--out", str(cap), "--json"]) == 0
    capsys.readouterr()
    assert main(["calibrate", str(cap), "--model", "joint", "-o", str(tmp_path / "rig.json"),
                 "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out["outputs"]) == {"p0", "p1"}
    calibs = [load_calibration(out["outputs"][f"p{k}"]) for k in range(2)]
    for a, b in zip(calibs[0].cameras, calibs[1].cameras, strict=True):
        np.testing.assert_array_equal(a.camera.K, b.camera.K)
        np.testing.assert_array_equal(a.camera.t, b.camera.t)
    from nail2nail.scan.triangulation import reconstruct_image

    for k, calib in enumerate(calibs):
        truth = load_calibration(cap / f"p{k}" / "truth" / "calibration.json")
        for fit in calib.cameras:
            # every pixel this projector lights, from its true projector coordinates: the
            # calibration's points against the true surface
            t = read_truth(cap / f"p{k}", fit.name)
            xyz = reconstruct_image(fit.camera, fit.projector, t["xp"], t["yp"],
                                    projector_distortion=calib.projector_distortion)
            err = np.linalg.norm(xyz - t["xyz"], axis=-1)[t["mask"]]
            assert t["mask"].sum() > 1000 and np.sqrt(np.mean(err**2)) < 0.01, (k, fit.name)
        d_fit, d_true = calib.projector_distortion, truth.projector_distortion
        r = 600.0  # the distortion's displacement at 600 px, to a tenth of a pixel
        assert d_fit.rho**3 * r**3 == pytest.approx(d_true.rho**3 * r**3, abs=0.1)
        summary = out["projectors"][f"p{k}"]["cameras"]
        assert all(s["camera_rms_px"] < 0.1 for s in summary.values())


def test_scan_directory_of_several_projectors_records_both_indices(two_projectors, tmp_path):
    import json

    from nail2nail.io.scans import load_scan_dirs, save_scans

    _, scans, projectors, cameras, _ = two_projectors
    with pytest.raises(ValueError, match="give both or neither"):
        save_scans(tmp_path / "a", scans, mat5=False, ply=False, projectors=projectors)
    with pytest.raises(ValueError, match="one each per scan"):
        save_scans(tmp_path / "a", scans, mat5=False, ply=False, projectors=projectors[:2],
                   cameras=cameras[:2])
    save_scans(tmp_path / "s", scans, mat5=False, ply=False, projectors=projectors,
               cameras=cameras)
    assert load_scan_dirs([tmp_path / "s"])[1:] == (projectors, cameras)
    manifest = json.loads((tmp_path / "s" / "scan.json").read_text())
    del manifest["cameras"][2]["camera_index"]
    (tmp_path / "s" / "scan.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="for every camera or for none"):
        load_scan_dirs([tmp_path / "s"])
    manifest["cameras"][2]["camera_index"] = -1
    (tmp_path / "s" / "scan.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="non-negative integer"):
        load_scan_dirs([tmp_path / "s"])


def test_cli_batch_of_captures_of_several_projectors(layout_capture, tmp_path, capsys):
    """``nail2nail batch`` takes captures of several projectors as ``process`` does: each job
    as one, its per-projector calibrations in its inputs' hash (a changed ``rig_p1.json``
    redoes it), the memory estimate over all its captures."""
    import json
    import shutil

    from nail2nail.batch import capture_memory_mb, inputs_hash
    from nail2nail.cli import main

    caps = tmp_path / "caps"
    shutil.copytree(layout_capture, caps / "a")
    for k in range(2):
        shutil.copy(layout_capture / f"p{k}" / "truth" / "calibration.json",
                    tmp_path / f"rig_p{k}.json")
    rig = tmp_path / "rig.json"
    one = capture_memory_mb(layout_capture / "p0")
    assert capture_memory_mb(caps / "a") == pytest.approx(2 * one - 600.0)
    before = inputs_hash(caps / "a", rig)
    args = ["batch", str(caps / "*"), "--calib", str(rig), "--out", str(tmp_path / "out"),
            "--workers", "1", "--no-wsq", "--json"]
    assert main(args) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["status"] for r in rows] == ["done"]
    job = json.loads((tmp_path / "out" / "a" / "process.json").read_text())
    assert job["projectors"] == ["p0", "p1"] and len(job["calibration"]) == 2
    calib = json.loads((tmp_path / "rig_p1.json").read_text())
    calib["note"] = "edited"
    (tmp_path / "rig_p1.json").write_text(json.dumps(calib))
    assert inputs_hash(caps / "a", rig) != before
    (tmp_path / "rig_p0.json").unlink()
    assert main(args) == 2  # no capture has its calibrations: refused before any task
    assert "rig_p0.json not found" in capsys.readouterr().err
