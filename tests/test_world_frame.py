"""Issue 12: any world frame (a camera-centred calibration), float32 rotations, scans written in
a chosen frame (``--frame``) and read back by ``merge``."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial import cKDTree

from nail2nail.calibration.camera_models import (
    Pinhole,
    dlt_from_pinhole,
    look_at,
    nearest_rotation,
    pinhole_from_dlt,
    project_dlt,
    projection_matrix,
)
from nail2nail.calibration.files import (
    CameraCalibration,
    RigCalibration,
    load_calibration,
    save_calibration,
)
from nail2nail.cli import main
from nail2nail.frames import (
    frame_transform,
    invert_transform,
    points_in_frame,
    scan_in_frame,
)
from nail2nail.io.capture import read_capture
from nail2nail.io.ply import read_ply
from nail2nail.io.scans import load_scans, read_scan_frame, save_scans
from nail2nail.scan.capture import scan_capture
from nail2nail.scan.decoding import decode
from nail2nail.scan.triangulation import reconstruct_image
from nail2nail.simulation.capture import simulate_capture
from nail2nail.simulation.rig import Rig, default_rig, ideal_calibration

#: float32 storage of scan points: one unit in the last place is 1.5e-5 mm at 128..256 mm
#: (the rig's points are 100..200 mm from either origin); a point rounded once in either frame
#: and rotated differs by a few of them.
FLOAT32_MM = 1e-4


def camera_centred(calibration: dict, camera: int = 0) -> dict:
    """`calibration` (a calibration-file dict of pinhole models) re-expressed in the frame of
    its camera `camera`: ``R_i' = R_i R_0ᵀ``, ``t_i' = t_i − R_i R_0ᵀ t_0`` for every model."""
    ref = calibration["cameras"][camera]["camera"]
    R0, t0 = np.array(ref["R"]), np.array(ref["t"])
    out = json.loads(json.dumps(calibration))
    for entry in out["cameras"]:
        for role in ("camera", "projector"):
            model = entry[role]
            R, t = np.array(model["R"]), np.array(model["t"])
            model["R"] = (R @ R0.T).tolist()
            model["t"] = (t - R @ R0.T @ t0).tolist()
    return out


@pytest.fixture(scope="module")
def finger(tmp_path_factory):
    """A finger capture of the default rig (thesis projector distortion) at scale 0.25."""
    root = tmp_path_factory.mktemp("frame")
    simulate_capture(root / "finger", "finger", rig=default_rig(0.25), seed=2)
    capture = read_capture(root / "finger", load=False)
    world = ideal_calibration(Rig.from_capture(capture))
    save_calibration(root / "world.json", RigCalibration.from_dict(world))
    save_calibration(root / "cam0.json", RigCalibration.from_dict(camera_centred(world)))
    return root


# -- projection matrices and rotations -------------------------------------------------------

def test_projection_matrix_w_is_depth_in_any_frame():
    R, t = look_at([30.0, 10.0, 140.0], [0, 0, 0], [0, 1, 0])
    cam = Pinhole(K=[[2000, 0, 511.5], [0, 2010, 639.5], [0, 0, 1]], R=R, t=t)
    P = projection_matrix(cam)
    X = np.array([[1.0, 2.0, 3.0], [-5.0, 4.0, 10.0]])
    depth = cam.to_camera(X)[:, 2]
    assert np.allclose(X @ P[2, :3] + P[2, 3], depth, rtol=0, atol=1e-12)
    assert np.allclose(project_dlt(P, X), cam.project(X), rtol=0, atol=1e-9)
    # any scale and sign of a DLT matrix gives the same normalised matrix
    assert np.allclose(projection_matrix(-3.5 * dlt_from_pinhole(cam)), P, rtol=0, atol=1e-12)
    # the camera's own frame: m34 = 0, the thesis's DLT form does not exist, P does
    own = Pinhole(K=cam.K, R=np.eye(3), t=np.zeros(3))
    with pytest.raises(ValueError, match="m34 is zero"):
        dlt_from_pinhole(own)
    assert projection_matrix(own)[2].tolist() == [0.0, 0.0, 1.0, 0.0]
    back = pinhole_from_dlt(projection_matrix(cam))
    assert np.allclose(back.R, R, atol=1e-12) and np.allclose(back.t, t, atol=1e-9)


def test_float32_rotation_is_reorthonormalised_with_a_warning():
    R, t = look_at([30.0, 10.0, 140.0], [0, 0, 0], [0, 1, 0])
    R32 = R.astype(np.float32)
    deviation = np.max(np.abs(R32.astype(float) @ R32.astype(float).T - np.eye(3)))
    assert 1e-9 < deviation < 1e-5  # what the user had: ~4e-8
    with pytest.warns(UserWarning, match=r"R: not orthonormal.*nearest rotation"):
        cam = Pinhole(K=np.diag([1000.0, 1000, 1]), R=R32, t=t)
    assert np.max(np.abs(cam.R @ cam.R.T - np.eye(3))) < 1e-14  # float64 rounding: 1.4e-15
    assert np.max(np.abs(cam.R - R)) < 1e-7  # float32 rounding of the entries
    assert np.linalg.det(cam.R) > 0


def test_rotation_beyond_tolerance_is_refused_with_the_deviation():
    R = np.eye(3)
    R[0, 1] = 1e-4
    with pytest.raises(ValueError, match=r"R: not a rotation matrix \(max \|R R\^T - I\| = 0"
                                         r"\.0001"):
        nearest_rotation(R)
    exact = look_at([1.0, 2.0, 3.0], [0, 0, 0], [0, 1, 0])[0]
    assert nearest_rotation(exact) is not None and np.array_equal(nearest_rotation(exact), exact)


def test_float32_calibration_file_loads_with_a_warning(tmp_path):
    data = ideal_calibration(default_rig(0.25))
    for entry in data["cameras"]:
        for role in ("camera", "projector"):
            entry[role]["R"] = np.asarray(entry[role]["R"], np.float32).astype(float).tolist()
    (tmp_path / "rig.json").write_text(json.dumps(data))
    with pytest.warns(UserWarning, match="nearest rotation"):
        calib = load_calibration(tmp_path / "rig.json")
    assert len(calib.cameras) == 3


# -- a camera-centred calibration scans the same surface -------------------------------------

def test_camera_centred_calibration_triangulates_the_same_points(finger):
    """float64 triangulation of the same decoded coordinates: equal within 1e-6 mm."""
    capture = read_capture(finger / "finger", load=False)
    world = load_calibration(finger / "world.json")
    centred = load_calibration(finger / "cam0.json")
    T = frame_transform(world, "cam0")
    for name in capture.camera_names:
        d = decode(capture.load_frames(name), capture.pattern_set)
        a, b = world.camera(name), centred.camera(name)
        pw = reconstruct_image(a.camera, a.projector, d.xp, d.yp,
                               projector_distortion=world.projector_distortion)
        pc = reconstruct_image(b.camera, b.projector, d.xp, d.yp,
                               projector_distortion=centred.projector_distortion)
        ok = np.all(np.isfinite(pw), axis=-1)
        assert ok.sum() > 1000
        assert np.array_equal(ok, np.all(np.isfinite(pc), axis=-1))
        # measured: 5e-9, 2.3e-7, 1e-8 mm (float64 rounding: points 150 mm from either
        # origin, normal equations of the camera-weighted least squares)
        assert np.max(np.abs(points_in_frame(pw[ok], T) - pc[ok])) < 1e-6


def test_camera_centred_calibration_scans_the_same_surface(finger):
    capture = read_capture(finger / "finger", load=False)
    world = load_calibration(finger / "world.json")
    centred = load_calibration(finger / "cam0.json")
    T = frame_transform(world, "cam0")
    assert np.allclose(frame_transform(centred, "cam0"), np.eye(4), atol=1e-12)
    for method in ("numba", "numpy"):
        scans_w = scan_capture(capture, world, method=method)
        scans_c = scan_capture(capture, centred, method=method)
        for sw, sc in zip(scans_w, scans_c, strict=True):
            assert np.array_equal(sw.mask, sc.mask)
            moved = scan_in_frame(sw, T)
            assert np.max(np.abs(moved.xyz[sw.mask] - sc.xyz[sc.mask])) < FLOAT32_MM
            assert np.allclose(moved.camera_center, sc.camera_center, rtol=0, atol=1e-9)


# -- scans written in a chosen frame ---------------------------------------------------------

def test_scan_frame_option_writes_camera_frame_and_merge_reads_it_back(finger, tmp_path, capsys):
    capture, calib = str(finger / "finger"), str(finger / "world.json")
    assert main(["scan", capture, "--calib", calib, "--out", str(tmp_path / "w"), "--json"]) == 0
    assert main(["scan", capture, "--calib", calib, "--out", str(tmp_path / "c1"), "--json",
                 "--frame", "cam1"]) == 0
    capsys.readouterr()
    T = frame_transform(load_calibration(calib), "cam1")
    frame, recorded = read_scan_frame(tmp_path / "c1")
    assert frame == "cam1" and np.array_equal(recorded, T)
    assert read_scan_frame(tmp_path / "w")[0] == "world"
    stored_w = load_scans(tmp_path / "w", frame="stored")
    stored_c = load_scans(tmp_path / "c1", frame="stored")
    for sw, sc in zip(stored_w, stored_c, strict=True):
        assert np.array_equal(sw.mask, sc.mask)
        assert np.max(np.abs(points_in_frame(sw.xyz[sw.mask], T) - sc.xyz[sc.mask])) < FLOAT32_MM
        ply = read_ply(tmp_path / "c1" / f"{sc.name}.ply")
        assert np.array_equal(np.sort(ply.points[:, 2]), np.sort(sc.xyz[sc.mask][:, 2]))
    # cam1's optical centre is the origin of its frame
    assert np.allclose(stored_c[1].camera_center, 0, atol=1e-9)
    # read back in the world frame: the world scans within float32 rounding
    for sw, sc in zip(stored_w, load_scans(tmp_path / "c1"), strict=True):
        assert np.max(np.abs(sw.xyz[sw.mask] - sc.xyz[sc.mask])) < FLOAT32_MM

    # merge computes in the world frame whatever the scans' frame, writes the super scan in it
    for name in ("w", "c1"):
        assert main(["merge", str(tmp_path / name), "--out", str(tmp_path / f"m_{name}"),
                     "--no-figures", "--json"]) == 0
    capsys.readouterr()
    mw = json.loads((tmp_path / "m_w" / "merge.json").read_text())
    mc = json.loads((tmp_path / "m_c1" / "merge.json").read_text())
    assert mc["super_scan"]["frame"] == "cam1"
    assert np.array_equal(mc["super_scan"]["T_frame_world"], T)
    for key in mw["merge"]:
        assert mw["merge"][key]["pairs"] == pytest.approx(mc["merge"][key]["pairs"], rel=0.01)
        assert mw["merge"][key]["distance_mm"]["median"] == pytest.approx(
            mc["merge"][key]["distance_mm"]["median"], abs=1e-4)
    vw = read_ply(tmp_path / "m_w" / "super.ply").points
    vc = read_ply(tmp_path / "m_c1" / "super.ply").points
    # the camera-frame super scan mapped back is the world one: fusion's discrete choices
    # (which camera owns a point) may flip at a threshold under float32 rounding (measured: one
    # of 40637 points), so compared as point sets
    assert abs(len(vw) - len(vc)) <= 1e-3 * len(vw)
    nearest, _ = cKDTree(vw).query(points_in_frame(vc, invert_transform(T)))
    assert np.percentile(nearest, 99.9) < FLOAT32_MM  # measured 7.6e-6 mm


def test_scan_frame_unknown_camera_is_refused_before_reading(finger, tmp_path, capsys):
    code = main(["scan", str(tmp_path / "missing"), "--calib", str(finger / "world.json"),
                 "--out", str(tmp_path / "o"), "--frame", "cam9"])
    assert code == 2
    err = capsys.readouterr().err
    assert "frame" in err and "cam9" in err and "cam0, cam1, cam2" in err
    assert not (tmp_path / "o").exists()


def test_load_scans_refuses_a_camera_frame_without_its_transform(finger, tmp_path):
    capture = read_capture(finger / "finger", load=False)
    calib = load_calibration(finger / "world.json")
    scans = scan_capture(capture, calib)[:2]
    save_scans(tmp_path / "s", scans, mat5=False, ply=False, frame="cam0",
               transform=frame_transform(calib, "cam0"))
    manifest = json.loads((tmp_path / "s" / "scan.json").read_text())
    del manifest["T_frame_world"]
    (tmp_path / "s" / "scan.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match=r"scan\.json: the points are in frame 'cam0' but "
                                         r"'T_frame_world' is missing"):
        load_scans(tmp_path / "s")
    manifest["T_frame_world"] = np.diag([1.0, 1.0, -1.0, 1.0]).tolist()  # a mirror
    (tmp_path / "s" / "scan.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="T_frame_world' must be a rigid 4x4 transform"):
        load_scans(tmp_path / "s")
    assert main(["merge", str(tmp_path / "s"), "--out", str(tmp_path / "m")]) == 2
    with pytest.raises(ValueError, match="transform T_frame_world is needed"):
        save_scans(tmp_path / "t", scans, frame="cam0")


def test_process_frame_option_records_the_transform(finger, tmp_path, capsys):
    out = tmp_path / "job"
    assert main(["process", str(finger / "finger"), "--calib", str(finger / "world.json"),
                 "--out", str(out), "--frame", "cam0", "--no-unroll", "--json"]) == 0
    capsys.readouterr()
    summary = json.loads((out / "process.json").read_text())
    T = frame_transform(load_calibration(finger / "world.json"), "cam0")
    assert summary["frame"] == "cam0" and np.array_equal(summary["T_frame_world"], T)
    assert summary["super_scan"]["frame"] == "cam0"
    assert read_scan_frame(out / "scans")[0] == "cam0"
    # the scans, read back, are the world scans
    scans = load_scans(out / "scans")
    assert np.allclose(scans[0].camera_center,
                       load_calibration(finger / "world.json").cameras[0].camera.center,
                       atol=1e-9)


def test_unroll_of_camera_frame_scans_is_the_world_print(finger, tmp_path, capsys):
    """``unroll`` reads scans written in a camera's frame back into the world frame (its tip
    direction, world +Y, holds): the same print but for float32 rounding of the points."""
    from PIL import Image

    capture, calib = str(finger / "finger"), str(finger / "world.json")
    for name, extra in (("w", []), ("c", ["--frame", "cam2"])):
        assert main(["scan", capture, "--calib", calib, "--out", str(tmp_path / name),
                     "--no-mat5", "--no-ply", "--json", *extra]) == 0
        assert main(["unroll", str(tmp_path / name), "--out", str(tmp_path / f"u{name}"),
                     "--json"]) == 0
    capsys.readouterr()

    def image(name, file):
        return np.asarray(Image.open(tmp_path / name / file)).astype(int)

    a, b = image("uw", "print.png"), image("uc", "print.png")
    mask_a, mask_b = image("uw", "print_mask.png") > 0, image("uc", "print_mask.png") > 0
    assert a.shape == b.shape
    # the 1.5e-5 mm rounding of a float32 point moves a sample across a rounding boundary.
    # Measured: 5 of 311780 mask pixels differ; inside both masks, 438 of 176388 pixels
    # (0.25 %) differ by more than 1 grey level, at most 19 (p99.9 5): they lie in a clarity
    # block whose two spectral peaks are nearly equal, whose ring (centred on the stronger)
    # the rounding switches (mixing.clarity_map; before the phase-locked fit no block of this
    # finger sat on such a tie, and every pixel was within 1 level)
    assert np.count_nonzero(mask_a != mask_b) <= 1e-4 * mask_a.size
    diff = np.abs(a - b)[mask_a & mask_b]
    assert np.mean(diff <= 1) >= 0.995 and np.percentile(diff, 99.9) <= 8


def test_frame_of_a_dlt_camera_is_its_decomposed_pose():
    calib = RigCalibration.from_dict(ideal_calibration(default_rig(0.25)))
    dlt = RigCalibration(cameras=[
        CameraCalibration(c.name, dlt_from_pinhole(c.camera), dlt_from_pinhole(c.projector))
        for c in calib.cameras])
    for name in ("cam0", "cam1", "cam2"):
        # RQ decomposition of the DLT matrix: the pose within float64 rounding
        assert np.allclose(frame_transform(dlt, name), frame_transform(calib, name),
                           rtol=0, atol=1e-9)
    assert np.array_equal(frame_transform(dlt, "world"), np.eye(4))


def test_camera_centred_calibration_unrolls_upright_by_default(finger, tmp_path, capsys):
    """With a camera-centred calibration the world's +Y is the camera's image *down*; the
    default tip direction (up in the images, measured on the scans) still finds the tip, so
    the print is the world calibration's without --tip-direction."""
    from PIL import Image

    from nail2nail.unroll.rolled import image_up_direction

    capture = str(finger / "finger")
    for name in ("world", "cam0"):
        assert main(["scan", capture, "--calib", str(finger / f"{name}.json"), "--out",
                     str(tmp_path / name), "--no-mat5", "--no-ply", "--json"]) == 0
        assert main(["unroll", str(tmp_path / name), "--out", str(tmp_path / f"u{name}"),
                     "--json"]) == 0
    capsys.readouterr()
    # the virtual cameras' image up is world +Y (look_at with up = +Y)
    up = image_up_direction(load_scans(tmp_path / "world"))
    assert up[1] > 0.99
    a, b = (np.asarray(Image.open(tmp_path / f"u{n}" / "print.png")).astype(int)
            for n in ("world", "cam0"))
    mask_a, mask_b = (np.asarray(Image.open(tmp_path / f"u{n}" / "print_mask.png")) > 0
                      for n in ("world", "cam0"))
    assert a.shape == b.shape
    # the same print but for rounding: the points are triangulated in another frame, then
    # stored as float32. Measured: the masks agree; of 180631 pixels 18437 differ by 1 grey
    # level, 50 by 2 and 3 by 3 (the clarity-weighted blend and the RMS floors use levels of
    # the whole print, which move a little with every pixel's rounding; the fixed blend of
    # earlier versions differed by 1 at 1.2 % of its pixels). Upside down, nothing would match.
    diff = np.abs(a - b)[mask_a & mask_b]
    assert np.count_nonzero(mask_a != mask_b) <= 1e-4 * mask_a.size
    assert diff.max() <= 3 and np.count_nonzero(diff >= 2) <= 1e-3 * diff.size
    assert np.count_nonzero(diff) <= 0.15 * diff.size
