"""Issue 9 on the virtual scanner: the fused surface of a finger is clean (scale 0.5, ~30 s).

The finger is rendered at half resolution, scanned with the rig's true calibration and fused;
every fused vertex must lie within 50 µm of the true surface, and the merge report must count
its rejections per reason and keep the statistics from before rejection.
"""

from __future__ import annotations

import numpy as np
import pytest

from nail2nail.calibration.files import RigCalibration
from nail2nail.io.capture import read_capture, read_truth
from nail2nail.merge import REJECT_REASONS, correspond
from nail2nail.merge.fusion import fuse_scans
from nail2nail.scan.capture import scan_capture
from nail2nail.simulation.capture import simulate_capture
from nail2nail.simulation.rig import Rig, default_rig, ideal_calibration

SCALE = 0.5


@pytest.fixture(scope="module")
def finger(tmp_path_factory):
    out = tmp_path_factory.mktemp("finger")
    simulate_capture(out, "finger", rig=default_rig(SCALE, projector_distortion="none"), seed=3)
    capture = read_capture(out, load=False)
    calib = RigCalibration.from_dict(ideal_calibration(Rig.from_capture(capture)))
    # scan_capture scales max_gradient (stated for a 1024 x 1280 camera) to the camera's size
    scans = scan_capture(capture, calib, max_gradient=2.0)
    return out, scans


def test_issue9_no_fused_vertex_beyond_50_um(finger):
    out, scans = finger
    sup = fuse_scans(scans)
    for k, scan in enumerate(scans):
        truth = read_truth(out, scan.name)
        sel = sup.camera == k
        r, c = sup.pixel[sel].T
        assert truth["mask"][r, c].all()
        # distance to the true surface, first order: along the true normal of the pixel
        d = np.sum((sup.vertices[sel] - truth["xyz"][r, c]) * truth["normal"][r, c], axis=-1)
        assert np.abs(d).max() < 0.050, (scan.name, np.abs(d).max())
    summary = sup.summary()
    assert set(summary["points_rejected"]) == {s.name for s in scans}
    assert all(set(v) == set(REJECT_REASONS) for v in summary["rejected_pairs"].values())
    assert sum(summary["rejected_pairs"]["0-1"].values()) > 0  # grazing views of the finger


def test_issue9_merge_statistics_before_and_after_rejection(finger):
    _, scans = finger
    for i, j in ((0, 1), (1, 2)):
        stats = correspond(scans[i], scans[j]).statistics()
        before = stats["before_rejection"]
        assert before["pairs"] == stats["pairs"] + sum(stats["rejected"].values())
        assert stats["sampled"] == stats["pairs"] + sum(stats["dropped"].values())
        assert sum(stats["rejected"].values()) < 0.05 * before["pairs"]  # few, not a cull
        assert stats["distance_mm"]["max"] < 0.050
        assert stats["distance_mm"]["median"] < 0.005
        assert stats["distance_mm"]["max"] <= before["distance_mm"]["max"]
