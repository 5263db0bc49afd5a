"""Scanning glue: calibration from target observations, bilinear sampling, scan_frames."""

from __future__ import annotations

import numpy as np
import pytest
from test_calibration_target import make_rig, observe

from nail2nail.calibration.observe import sample_bilinear
from nail2nail.calibration.target import calibrate_from_observations
from nail2nail.io.points import PointsTable
from nail2nail.scan.capture import camera_center


@pytest.mark.parametrize("model", ["dlt", "joint"])
def test_calibrate_from_observations(model):
    cams, proj = make_rig()
    obs = observe(cams, proj, rho=-0.004, noise=0.05)
    calib, summary = calibrate_from_observations(obs, model=model)
    assert [c.name for c in calib.cameras] == ["cam0", "cam1", "cam2"]
    for cam_true, cam in zip(cams, calib.cameras, strict=True):
        assert np.linalg.norm(camera_center(cam.camera) - cam_true.center) < 2.0
    if model == "joint":
        assert calib.projector_distortion.rho == pytest.approx(-0.004, rel=0.05)
        assert max(s["projector_rms_px"] for s in summary.values()) < 0.1
    else:
        assert calib.projector_distortion is None
        assert all(s["points"] >= 15 for s in summary.values())


def test_points_table_has_thesis_columns():
    cams, proj = make_rig()
    obs = observe(cams, proj, rho=0.0, noise=0.0)[1]
    table = PointsTable.from_arrays(obs.xyz_world, obs.xy_camera, obs.xy_projector)
    assert len(table) == len(obs.xyz_world)
    np.testing.assert_array_equal(table.xy_projector, obs.xy_projector)


def test_sample_bilinear():
    image = np.arange(20.0).reshape(4, 5)  # value = 5 row + col
    xy = np.array([[1.5, 2.25], [0, 0], [4, 3], [4.5, 1], [-0.1, 0]])
    got = sample_bilinear(image, xy)
    np.testing.assert_allclose(got[:3], [5 * 2.25 + 1.5, 0, 19])
    assert np.isnan(got[3:]).all()
