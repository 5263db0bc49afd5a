"""Rigid alignment of scans by ICP (Open3D): the baseline that calibration is compared with.

Aligning each camera's scan to its neighbour by iterative closest points hides calibration
errors that a rigid motion can absorb, but not those that bend the scan (a projector distortion
absorbed differently by each camera's matrices). nail2nail's merge instead comes from the
calibration itself (:func:`nail2nail.calibration.target.calibrate_rig_joint`); this module measures
what ICP would give. Open3D is an optional dependency: ``pip install nail2nail[icp]``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from nail2nail.scan.results import Scan

__all__ = ["icp_align", "transform_scan"]


def _open3d():
    try:
        import open3d
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(
            "ICP alignment needs Open3D: pip install 'nail2nail[icp]' (open3d==0.19.0)"
        ) from exc
    return open3d


def icp_align(moving: Scan, fixed: Scan, *, max_distance_mm: float = 0.3,
              stride: int = 2, normal_radius_mm: float = 0.5,
              max_iterations: int = 100) -> np.ndarray:
    """Rigid transform ``(4, 4)`` that moves `moving`'s points onto `fixed`'s surface.

    Point-to-plane ICP (Open3D ``registration_icp``) over the valid points of both scans,
    every `stride`-th pixel, pairs farther than `max_distance_mm` ignored (so only the overlap
    counts), starting from the identity (the scans are already in one world frame).

    Parameters
    ----------
    moving, fixed : Scan
        Scans in world mm.
    max_distance_mm : float
        Largest distance of an ICP pair, mm.
    stride : int
        Pixel subsampling of both scans.
    normal_radius_mm : float
        Neighbourhood radius for the target's normals, mm.
    max_iterations : int
        Largest number of ICP iterations.

    Returns
    -------
    (4, 4) float64
        ``T`` with ``x_fixed ≈ T[:3, :3] @ x_moving + T[:3, 3]``.
    """
    o3d = _open3d()

    def cloud(scan: Scan):
        xyz = scan.xyz[::stride, ::stride][scan.mask[::stride, ::stride]].astype(np.float64)
        if len(xyz) < 100:
            raise ValueError(f"{scan.name}: too few valid points for ICP ({len(xyz)})")
        return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))

    source, target = cloud(moving), cloud(fixed)
    target.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=normal_radius_mm,
                                                                 max_nn=30))
    reg = o3d.pipelines.registration
    result = reg.registration_icp(
        source, target, max_distance_mm, np.eye(4),
        reg.TransformationEstimationPointToPlane(),
        reg.ICPConvergenceCriteria(max_iteration=max_iterations),
    )
    return np.asarray(result.transformation, dtype=np.float64)


def transform_scan(scan: Scan, transform) -> Scan:
    """A copy of `scan` with its points moved by the rigid ``(4, 4)`` `transform`."""
    T = np.asarray(transform, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"transform: expected shape (4, 4), got {T.shape}")
    xyz = (scan.xyz.astype(np.float64) @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
    center = None if scan.camera_center is None else T[:3, :3] @ scan.camera_center + T[:3, 3]
    return replace(scan, xyz=xyz, camera_center=center)
