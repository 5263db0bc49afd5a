"""End to end on the virtual scanner (issue 4): simulate → decode → calibrate → scan, against
the simulator's ground truth. Reduced scale (0.5: the target's marks need ~20 px)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nail2nail.calibration.camera_models import dlt_from_pinhole
from nail2nail.calibration.files import CameraCalibration, RigCalibration, load_calibration
from nail2nail.calibration.markers import TargetGeometry
from nail2nail.calibration.observe import target_observations
from nail2nail.calibration.target import calibrate_from_observations
from nail2nail.cli import main
from nail2nail.io.capture import read_capture, read_truth
from nail2nail.io.mat5 import read_mat5
from nail2nail.scan.capture import scan_capture
from nail2nail.scan.decoding import decode
from nail2nail.simulation.capture import simulate_capture
from nail2nail.simulation.rig import Rig, default_rig, ideal_calibration

SCALE = 0.5


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """Target and finger captures, projector distortion off (issue 4), default noise."""
    root = tmp_path_factory.mktemp("e2e")
    rig = default_rig(SCALE, projector_distortion="none")
    for scene in ("target", "finger"):
        simulate_capture(root / scene, scene, rig=rig, seed=3)
    return root


def surface_distance_um(scan, truth) -> np.ndarray:
    """Distance of each scanned point to the true surface (first order: along its normal), µm."""
    ok = scan.mask & truth["mask"]
    d = np.sum((scan.xyz[ok] - truth["xyz"][ok]) * truth["normal"][ok], axis=-1)
    return 1000 * d


def test_decoded_projector_coordinates_match_truth(captures):
    capture = read_capture(captures / "finger", load=False)
    for name in capture.camera_names:
        d = decode(capture.load_frames(name), capture.pattern_set)
        truth = read_truth(captures / "finger", name)
        ok = d.mask & truth["mask"]
        assert ok.sum() > 0.6 * truth["mask"].sum()
        err = np.hypot(d.xp[ok] - truth["xp"][ok], d.yp[ok] - truth["yp"][ok])
        rms_x = np.sqrt(np.mean((d.xp[ok] - truth["xp"][ok]) ** 2))
        rms_y = np.sqrt(np.mean((d.yp[ok] - truth["yp"][ok]) ** 2))
        assert rms_x <= 0.05 and rms_y <= 0.05, (name, rms_x, rms_y)
        assert err.max() < 1.0, (name, err.max())  # no unwrapping error


@pytest.fixture(scope="module")
def joint_calibration(captures):
    observations = target_observations(read_capture(captures / "target", load=False))
    surface = TargetGeometry().signed_distance
    return calibrate_from_observations(observations, model="joint", surface=surface)


def test_calibration_from_target_capture_finds_marks(captures, joint_calibration):
    calib, summary = joint_calibration
    assert all(s["points"] >= 25 for s in summary.values())
    assert all(s["camera_rms_px"] < 0.3 for s in summary.values())
    # The fitted cameras project the target's volume where the true ones do (focal length and
    # distance trade off along the narrow field of view, so compare projections, not centres).
    rig = Rig.from_capture(read_capture(captures / "target", load=False))
    _, xyz = TargetGeometry().all_marks()
    for cam_true, cam in zip(rig.cameras, calib.cameras, strict=True):
        err = cam.camera.project(xyz) - cam_true.project(xyz)
        assert np.sqrt(np.mean(err**2)) < 0.3, np.sqrt(np.mean(err**2))


def test_scan_after_target_calibration_is_within_15_um(captures, joint_calibration):
    """Issue 4: RMS distance to the true surface ≤ 15 µm for every camera."""
    calib, _ = joint_calibration
    scans = scan_capture(read_capture(captures / "finger", load=False), calib)
    for scan in scans:
        d = surface_distance_um(scan, read_truth(captures / "finger", scan.name))
        assert d.size > 50_000
        assert np.sqrt(np.mean(d**2)) <= 15.0, (scan.name, np.sqrt(np.mean(d**2)))


def test_opencv_form_gives_the_dlt_scan(captures):
    """The rig's pinhole (OpenCV) calibration and its DLT form give the same scan."""
    capture = read_capture(captures / "finger", load=False)
    pinhole = RigCalibration.from_dict(ideal_calibration(Rig.from_capture(capture)))
    dlt = RigCalibration(cameras=[
        CameraCalibration(c.name, dlt_from_pinhole(c.camera), dlt_from_pinhole(c.projector))
        for c in pinhole.cameras])
    scans_p = scan_capture(capture, pinhole)
    scans_d = scan_capture(capture, dlt)
    for sp, sd in zip(scans_p, scans_d, strict=True):
        assert np.array_equal(sp.mask, sd.mask)
        assert np.nanmax(np.abs(sp.xyz - sd.xyz)) < 1e-3  # mm; float32 storage
        d = surface_distance_um(sp, read_truth(captures / "finger", sp.name))
        assert np.sqrt(np.mean(d**2)) < 5.0  # the truth calibration: decoding noise only


def test_camera_lens_distortion_in_the_opencv_model(tmp_path):
    """A camera with radial distortion: its OpenCV model reconstructs the true surface."""
    rig = default_rig(0.25, projector_distortion="none", camera_distortion=(-0.3, 0, 0, 0, 0))
    simulate_capture(tmp_path / "finger", "finger", rig=rig, seed=1)
    capture = read_capture(tmp_path / "finger", load=False)
    calib = RigCalibration.from_dict(ideal_calibration(Rig.from_capture(capture)))
    assert np.any(calib.cameras[0].camera.dist)
    for scan in scan_capture(capture, calib):
        d = surface_distance_um(scan, read_truth(tmp_path / "finger", scan.name))
        assert np.sqrt(np.mean(d**2)) < 8.0


def test_cli_calibrate_and_scan(captures, tmp_path, capsys):
    rig_json = tmp_path / "rig.json"
    assert main(["calibrate", str(captures / "target"), "-o", str(rig_json), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out["cameras"]) == {"cam0", "cam1", "cam2"}
    for path in out["points_tables"].values():
        with open(path) as fh:
            header = fh.readline().split("\t")
        assert header[:8] == ["point", "Xw", "Yw", "Zw", "xc", "yc", "xp", "yp"]
    assert np.asarray(load_calibration(rig_json).cameras[0].camera).shape == (3, 4)
    scan_dir = tmp_path / "scan"
    assert main(["scan", str(captures / "finger"), "--calib", str(rig_json), "--out",
                 str(scan_dir), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    for name, cam in out["cameras"].items():
        assert cam["valid_pixels"] > 50_000
        back = read_mat5(cam["mat5"])
        assert back.mask.sum() == cam["valid_pixels"]
        assert (scan_dir / f"{name}.ply").exists()


def test_cli_scan_bad_calibration_exits_2(captures, tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    out = tmp_path / "scan"
    assert main(["scan", str(captures / "finger"), "--calib", str(bad), "--out", str(out)]) == 2
    assert "bad.json" in capsys.readouterr().err
    assert not out.exists()
