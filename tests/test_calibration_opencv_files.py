"""Issue 12: calibrations in OpenCV FileStorage files (SLStudio, stereo_calib, nail2nail layout),
imported with one command and scanned without edits, output in the camera frame."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from nail2nail.calibration.camera_models import Pinhole, dlt_from_pinhole
from nail2nail.calibration.files import (
    CameraCalibration,
    RigCalibration,
    load_calibration,
    save_calibration,
)
from nail2nail.calibration.opencv_files import read_opencv_calibration, write_opencv_calibration
from nail2nail.cli import main
from nail2nail.io.capture import read_capture, read_truth
from nail2nail.io.scans import load_scans, read_scan_frame
from nail2nail.scan.capture import scan_capture
from nail2nail.simulation.capture import simulate_capture
from nail2nail.simulation.rig import Rig, default_rig, ideal_calibration


def write_storage(path, entries: dict) -> None:
    """Write `entries` with cv2.FileStorage as another program would (its own dtypes)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in entries.items():
        fs.write(key, value)
    fs.release()


def slstudio_entries(camera: Pinhole, projector: Pinhole, dtype=np.float32) -> dict:
    """SLStudio's calibration keys of a camera and projector (world frame arbitrary), the
    projector's pose relative to the camera as cv::stereoCalibrate gives it; float32 as
    SLStudio's cv::Matx33f / cv::Vec3f."""
    Rp = projector.R @ camera.R.T
    Tp = projector.t - Rp @ camera.t
    return {"Kc": camera.K.astype(dtype), "kc": camera.dist.reshape(1, 5).astype(dtype),
            "Kp": projector.K.astype(dtype), "kp": projector.dist.reshape(1, 5).astype(dtype),
            "Rp": Rp.astype(dtype), "Tp": Tp.reshape(3, 1).astype(dtype),
            "cam_error": 0.1, "proj_error": 0.2, "stereo_error": 0.3,
            "frameWidth": camera.size[0], "frameHeight": camera.size[1],
            "screenResX": projector.size[0], "screenResY": projector.size[1]}


def assert_same_rig(a: RigCalibration, b: RigCalibration) -> None:
    assert [c.name for c in a.cameras] == [c.name for c in b.cameras]
    for ca, cb in zip(a.cameras, b.cameras, strict=True):
        assert tuple(ca.size) == tuple(cb.size)
        for ma, mb in ((ca.camera, cb.camera), (ca.projector, cb.projector)):
            for key in ("K", "dist", "R", "t"):
                assert np.array_equal(getattr(ma, key), getattr(mb, key)), key
            assert tuple(ma.size) == tuple(mb.size)


# -- import -----------------------------------------------------------------------------------

def test_slstudio_float32_file_imports_with_a_warning(tmp_path):
    rig = default_rig(0.25, projector_distortion="none")
    camera, projector = rig.cameras[1], rig.projector
    write_storage(tmp_path / "calibration.xml", slstudio_entries(camera, projector))
    with pytest.warns(UserWarning, match=r"calibration\.xml: Kp, kp, Rp, Tp: R: not "
                                         r"orthonormal.*nearest rotation"):
        calib = read_opencv_calibration(tmp_path / "calibration.xml")
    assert [c.name for c in calib.cameras] == ["cam0"]
    cam = calib.cameras[0]
    assert np.array_equal(cam.camera.R, np.eye(3)) and not np.any(cam.camera.t)
    assert cam.size == camera.size and cam.projector.size == projector.size
    assert np.array_equal(cam.camera.K, camera.K.astype(np.float32))
    Rp = projector.R @ camera.R.T
    assert np.max(np.abs(cam.projector.R - Rp)) < 1e-7  # float32 rounding of the file
    assert np.max(np.abs(cam.projector.t - (projector.t - Rp @ camera.t))) < 2e-5  # mm
    assert calib.extra["source_layout"] == "slstudio" and calib.extra["world_frame"] == "cam0"


def test_stereo_calib_two_files_and_sizes_as_options(tmp_path):
    rig = default_rig(0.25, projector_distortion="none")
    camera, projector = rig.cameras[0], rig.projector
    e = slstudio_entries(camera, projector, dtype=np.float64)
    write_storage(tmp_path / "intrinsics.yml", {"M1": e["Kc"], "D1": e["kc"][:, :4],
                                                "M2": e["Kp"], "D2": e["kp"]})
    write_storage(tmp_path / "extrinsics.yml", {"R": e["Rp"], "T": e["Tp"],
                                                "R1": np.eye(3), "P1": np.zeros((3, 4))})
    files = [tmp_path / "intrinsics.yml", tmp_path / "extrinsics.yml"]
    with pytest.raises(ValueError, match=r"no image size \(key 'size1'\); give --camera-size"):
        read_opencv_calibration(files)
    calib = read_opencv_calibration(files, camera_size=camera.size,
                                    projector_size=projector.size)
    assert calib.extra["source_layout"] == "stereo"
    assert np.array_equal(calib.cameras[0].projector.R, e["Rp"])
    assert np.array_equal(calib.cameras[0].projector.t, e["Tp"].ravel())
    assert calib.cameras[0].camera.dist.shape == (5,)


@pytest.mark.parametrize(("entries", "match"), [
    ({"kc": None}, r"calibration\.xml: missing key 'kc'"),
    ({"Kc": np.eye(2)}, r"calibration\.xml: Kc: expected a 3x3 matrix, got shape \(2, 2\)"),
    ({"kc": np.zeros((1, 6))}, r"kc: expected 4, 5, 8, 12 or 14 distortion"),
    ({"kc": np.array([[0, 0, 0, 0, 0, 0.1, 0, 0]])},
     r"kc: coefficients beyond k3 must be zero .* got k4=0\.1"),
    ({"Rp": np.array([[1.0, 1e-3, 0], [0, 1, 0], [0, 0, 1]])},
     r"Rp, Tp: R: not a rotation matrix \(max \|R R\^T - I\| = 0\.001"),
    ({"Tp": "far"}, r"Tp: expected 3 numbers"),
    ({"frameWidth": -4}, r"frameWidth: expected a positive integer, got -4"),
    ({"frameWidth": None}, r"missing key 'frameWidth'"),
])
def test_bad_slstudio_file_names_the_file_and_the_key(tmp_path, entries, match):
    rig = default_rig(0.25, projector_distortion="none")
    base = slstudio_entries(rig.cameras[1], rig.projector, dtype=np.float64)
    for key, value in entries.items():
        if value is None:
            del base[key]
        else:
            base[key] = value
    write_storage(tmp_path / "calibration.xml", base)
    with pytest.raises(ValueError, match=match):
        read_opencv_calibration(tmp_path / "calibration.xml")


@pytest.mark.parametrize("content", [b"", b"<?xml version='1.0'?><opencv_storage><K>oops",
                                     b"\xff\xfe\x00binary", b"just: [text"])
def test_unreadable_file_is_one_line_exit_2(tmp_path, capsys, content):
    path = tmp_path / "calibration.xml"
    path.write_bytes(content)
    code = main(["import-calibration", str(path), "-o", str(tmp_path / "rig.json")])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and str(path) in err, err
    assert not (tmp_path / "rig.json").exists()


def test_missing_file_and_unknown_layout(tmp_path, capsys):
    assert main(["import-calibration", str(tmp_path / "nope.xml"), "-o",
                 str(tmp_path / "rig.json")]) == 2
    assert "nope.xml: cannot read" in capsys.readouterr().err
    write_storage(tmp_path / "other.yml", {"camera_matrix": np.eye(3)})
    with pytest.raises(ValueError, match=r"other\.yml: unknown layout \(top-level keys "
                                         r"\['camera_matrix'\]\)"):
        read_opencv_calibration(tmp_path / "other.yml")


# -- export -----------------------------------------------------------------------------------

def test_export_refuses_the_thesis_projector_distortion(tmp_path):
    calib = RigCalibration.from_dict(ideal_calibration(default_rig(0.25)))
    with pytest.raises(ValueError, match=r"projector radial distortion .* has no OpenCV form"):
        write_opencv_calibration(tmp_path / "rig.yml", calib)
    assert not (tmp_path / "rig.yml").exists()


def test_export_of_dlt_matrices_decomposes_them_with_a_warning(tmp_path):
    calib = RigCalibration.from_dict(ideal_calibration(default_rig(0.25,
                                                                   projector_distortion="none")))
    dlt = RigCalibration(cameras=[
        CameraCalibration(c.name, dlt_from_pinhole(c.camera), dlt_from_pinhole(c.projector),
                          c.camera.size) for c in calib.cameras])
    with pytest.warns(UserWarning, match="DLT matrix decomposed into K, R, t"):
        write_opencv_calibration(tmp_path / "rig.xml", dlt, projector_size=(1280, 1040))
    back = read_opencv_calibration(tmp_path / "rig.xml")
    for a, b in zip(calib.cameras, back.cameras, strict=True):
        assert np.allclose(a.camera.K, b.camera.K, rtol=1e-9)
        assert np.allclose(a.camera.R, b.camera.R, atol=1e-9)
        assert np.allclose(a.camera.t, b.camera.t, atol=1e-7)
    with pytest.warns(UserWarning) as caught:
        notes = write_opencv_calibration(tmp_path / "guess.yml", dlt)
    assert any("projector size not known for a DLT projector: 1280 x 1040 written"
               in str(w.message) for w in caught)
    assert sum("projector size" in note for note in notes) == 1  # said once, not per camera
    assert read_opencv_calibration(tmp_path / "guess.yml").cameras[0].projector.size == (1280,
                                                                                          1040)
    with pytest.raises(ValueError, match="holds one camera: give the camera"):
        write_opencv_calibration(tmp_path / "one.xml", calib, layout="slstudio")


def test_export_of_a_world_frame_rig_to_slstudio_re_expresses_the_projector(tmp_path):
    calib = RigCalibration.from_dict(ideal_calibration(default_rig(0.25,
                                                                   projector_distortion="none")))
    with pytest.warns(UserWarning, match="re-expressed in camera 'cam2'"):
        write_opencv_calibration(tmp_path / "c.xml", calib, layout="slstudio", camera="cam2")
    back = read_opencv_calibration(tmp_path / "c.xml").cameras[0]
    cam, proj = calib.cameras[2].camera, calib.cameras[2].projector
    X = np.array([[1.0, 2.0, 3.0], [-4.0, 5.0, -2.0]])  # world points, seen in both frames
    assert np.allclose(back.projector.project(cam.to_camera(X)), proj.project(X), atol=1e-9)


# -- round trip (property) --------------------------------------------------------------------

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@st.composite
def pinholes(draw, *, at_origin=False):
    fx, fy = (draw(st.floats(50.0, 1e4)) for _ in range(2))
    K = np.array([[fx, draw(st.floats(-1.0, 1.0)), draw(st.floats(0.0, 4000.0))],
                  [0.0, fy, draw(st.floats(0.0, 4000.0))], [0.0, 0.0, 1.0]])
    dist = np.array([draw(st.floats(-0.5, 0.5)) for _ in range(5)])
    size = (draw(st.integers(1, 8192)), draw(st.integers(1, 8192)))
    if at_origin:
        return Pinhole(K=K, R=np.eye(3), t=np.zeros(3), dist=dist, size=size)
    quaternion = np.array([draw(st.floats(-1.0, 1.0)) for _ in range(4)])
    if np.linalg.norm(quaternion) < 0.1:
        quaternion = np.array([0.0, 0.0, 0.0, 1.0])
    R = Rotation.from_quat(quaternion).as_matrix()
    t = np.array([draw(st.floats(-1e3, 1e3)) for _ in range(3)])
    return Pinhole(K=K, R=R, t=t, dist=dist, size=size)


@st.composite
def rigs(draw, layout):
    one = layout != "nail2nail"
    n = 1 if one else draw(st.integers(1, 3))
    shared = draw(pinholes())
    cameras = []
    for i in range(n):
        camera = draw(pinholes(at_origin=one))
        projector = shared if one or draw(st.booleans()) else draw(pinholes())
        cameras.append(CameraCalibration(f"cam{i}" if one else draw(
            st.sampled_from(["cam", "left", "c"])) + str(i), camera, projector, camera.size))
    return RigCalibration(cameras=cameras)


@pytest.mark.parametrize("suffix", [".xml", ".yml", ".yaml"])
@pytest.mark.parametrize("layout", ["nail2nail", "slstudio", "stereo"])
@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_export_import_round_trip_is_exact(tmp_path, layout, suffix, data):
    calib = data.draw(rigs(layout))
    path = tmp_path / f"rig{suffix}"
    write_opencv_calibration(path, calib, layout=layout)
    back = read_opencv_calibration(path, layout=layout, allow_mirrored=True)
    assert_same_rig(calib, back)


def test_cli_export_then_import_round_trip(tmp_path, capsys):
    calib = RigCalibration.from_dict(ideal_calibration(default_rig(0.25,
                                                                   projector_distortion="none")))
    save_calibration(tmp_path / "rig.json", calib)
    assert main(["export-calibration", str(tmp_path / "rig.json"), "-o",
                 str(tmp_path / "rig.yaml"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["layout"] == "nail2nail"
    assert main(["import-calibration", str(tmp_path / "rig.yaml"), "-o",
                 str(tmp_path / "back.json"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["layout"] == "nail2nail" and set(out["cameras"]) == {"cam0", "cam1", "cam2"}
    assert_same_rig(calib, load_calibration(tmp_path / "back.json"))
    assert main(["export-calibration", str(tmp_path / "rig.json"), "-o",
                 str(tmp_path / "rig.txt")]) == 2
    assert "expected a .xml, .yml or .yaml" in capsys.readouterr().err


# -- the requirement, end to end ------------------------------------------------------

def test_camera_centred_opencv_calibration_scans_in_the_camera_frame(tmp_path, capsys):
    """A camera-centred OpenCV calibration imported with one command scans a capture without
    edits, with output in the camera frame."""
    full = default_rig(0.25, projector_distortion="none")
    camera, projector = full.cameras[1], full.projector  # the frontal camera
    rig = Rig(cameras=[camera], projector=projector, photometry=full.photometry,
              scale=full.scale)
    simulate_capture(tmp_path / "finger", "finger", rig=rig, seed=5)
    # SLStudio's calibration.xml: the camera's frame, float32 matrices
    write_storage(tmp_path / "calibration.xml", slstudio_entries(camera, projector))
    assert main(["import-calibration", str(tmp_path / "calibration.xml"), "-o",
                 str(tmp_path / "rig.json")]) == 0
    assert "float32" in capsys.readouterr().err  # the rotation's warning, one line
    assert main(["scan", str(tmp_path / "finger"), "--calib", str(tmp_path / "rig.json"),
                 "--out", str(tmp_path / "scan"), "--frame", "cam0", "--json"]) == 0
    capsys.readouterr()
    frame, T = read_scan_frame(tmp_path / "scan")
    assert frame == "cam0" and np.array_equal(T, np.eye(4))  # the world frame is cam0's
    (scan,) = load_scans(tmp_path / "scan")
    truth = read_truth(tmp_path / "finger", "cam0")
    xyz_cam = camera.to_camera(truth["xyz"])  # the true surface in the camera's frame
    normal_cam = truth["normal"] @ camera.R.T
    ok = scan.mask & truth["mask"]
    assert ok.sum() > 0.8 * truth["mask"].sum()
    d = np.sum((scan.xyz[ok] - xyz_cam[ok]) * normal_cam[ok], axis=-1)
    # measured: rms 1.90 µm, median -0.003 µm, max 9.4 µm along the true normal over 30596
    # pixels: the decoding noise at scale 0.25 (the simulator's ideal calibration in the world
    # frame gives the same 1.90 µm); 3 µm leaves room for the noise of another platform's
    # float rounding, not for a wrong frame (a 1e-3 rad error moves points by 0.15 mm here)
    assert np.sqrt(np.mean(d**2)) < 3e-3
    assert abs(np.median(d)) < 0.5e-3
    # the same points as the simulator's ideal world calibration, moved into the camera frame:
    # measured max 1.0e-5 mm (the float32 entries of the file and float32 points, 1.5e-5 mm
    # per unit in the last place at 128..256 mm)
    ideal = RigCalibration.from_dict(ideal_calibration(rig))
    (world_scan,) = scan_capture(read_capture(tmp_path / "finger", load=False), ideal)
    assert np.array_equal(world_scan.mask, scan.mask)
    moved = camera.to_camera(world_scan.xyz[scan.mask])
    assert np.max(np.abs(moved - scan.xyz[scan.mask])) < 1e-4
