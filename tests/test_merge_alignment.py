"""ICP baseline (Open3D, optional) and rigid transforms of scans."""

from __future__ import annotations

import numpy as np
import pytest
from _synthetic import synthetic_scans

from nail2nail.merge import correspond
from nail2nail.merge.alignment import icp_align, transform_scan


def test_transform_scan_moves_points_and_centre():
    scan = synthetic_scans(size=(32, 40), shape="sphere")[1]
    T = np.eye(4)
    T[:3, 3] = [0.1, -0.2, 0.3]
    moved = transform_scan(scan, T)
    ok = scan.mask
    np.testing.assert_allclose(moved.xyz[ok] - scan.xyz[ok],
                               np.broadcast_to([0.1, -0.2, 0.3], (ok.sum(), 3)), atol=1e-5)
    assert np.isnan(moved.xyz[~ok]).all()
    assert moved.xp is scan.xp  # projector coordinates are unchanged
    with pytest.raises(ValueError, match=r"\(4, 4\)"):
        transform_scan(scan, np.eye(3))


def test_icp_puts_a_shifted_scan_back_on_the_surface():
    """ICP brings a shifted sphere scan back onto the sphere; it cannot tell a rotation about
    the centre (the surface slides on itself), so the merge error in projector space stays:
    the weakness of a rigid alignment as a substitute for calibration."""
    pytest.importorskip("open3d")
    scans = synthetic_scans(size=(96, 120), shape="sphere",
                            shifts=[(0.05, 0.0, -0.04), (0, 0, 0), (0, 0, 0)])

    def off_surface(scan):  # distance to the sphere of radius 10 mm about the origin
        return np.abs(np.linalg.norm(scan.xyz[scan.mask], axis=-1) - 10.0)

    moved = transform_scan(scans[0], icp_align(scans[0], scans[1], stride=1))
    assert np.median(off_surface(scans[0])) > 0.02
    assert np.median(off_surface(moved)) < 0.005
    assert np.median(correspond(moved, scans[1]).distance_mm) > 0.01
