"""From a capture to 3D scans: decode each camera's frames and reconstruct its points.

This is the glue of the pipeline's first three stages (capture → decode → reconstruct); the
work itself is done by :mod:`nail2nail.phase` and :mod:`nail2nail.reconstruction`.
"""

from __future__ import annotations

import numpy as np

from .calibration import calibrate_points, calibrate_rig_joint
from .io.calibration import CameraCalibration, RigCalibration
from .io.points import PointsTable
from .phase import decode
from .reconstruction import Scan, model_matrix, reconstruct_image

__all__ = [
    "calibrate_from_observations",
    "camera_center",
    "cylinder_distance",
    "points_table",
    "sample_bilinear",
    "scan_capture",
    "scan_frames",
    "surface_samples",
    "target_observations",
]


def camera_center(model) -> np.ndarray:
    """Optical centre (3,) in world mm of a DLT matrix or pinhole model (null space of M)."""
    M = model_matrix(model)
    return -np.linalg.solve(M[:, :3], M[:, 3])


def scan_frames(
    frames,
    pattern_set,
    camera: CameraCalibration,
    *,
    projector_distortion: dict | None = None,
    use: str = "xpyp",
    **decode_options,
) -> Scan:
    """One camera's scan from its frames.

    Parameters
    ----------
    frames : (n_frames, H, W) uint8/uint16/float
        The camera's capture, in the pattern set's frame order.
    pattern_set : PatternSet
        What the projector showed.
    camera : CameraCalibration
        The camera's model and the projector model calibrated with it.
    projector_distortion : dict, optional
        Projector radial distortion to compensate in the model (``{"center", "rho"}``); leave
        out when the patterns were pre-distorted.
    use : {"xpyp", "yp", "xp"}
        Projector coordinates used for triangulation (:func:`reconstruct_image`).
    **decode_options
        Passed to :func:`nail2nail.phase.decode` (``min_modulation`` …).

    Returns
    -------
    Scan
        ``xyz`` NaN (and ``mask`` False) where decoding failed.
    """
    decoded = decode(frames, pattern_set, **decode_options)
    if decoded.xp is None or decoded.yp is None:
        if use == "xpyp" or projector_distortion is not None:
            raise ValueError(
                "pattern set: both projector directions are needed for use='xpyp' or a "
                "projector distortion model; use 'yp' or 'xp' with one direction"
            )
    nan = np.full(decoded.shape, np.nan, np.float32)
    xp = decoded.xp if decoded.xp is not None else nan
    yp = decoded.yp if decoded.yp is not None else nan
    xyz = reconstruct_image(
        camera.camera, camera.projector, xp, yp, projector_distortion=projector_distortion, use=use
    )
    mask = decoded.mask & np.all(np.isfinite(xyz), axis=-1)
    xyz[~mask] = np.nan
    return Scan(
        name=camera.name,
        xyz=xyz.astype(np.float32),
        xp=np.where(mask, xp, np.nan).astype(np.float32),
        yp=np.where(mask, yp, np.nan).astype(np.float32),
        albedo=decoded.albedo,
        intensity=np.where(mask, decoded.intensity, 0).astype(np.float32),
        modulation=decoded.modulation,
        mask=mask,
        camera_center=camera_center(camera.camera),
    )


def scan_capture(
    capture,
    calibration: RigCalibration,
    *,
    use: str = "xpyp",
    progress: bool = False,
    max_gradient: float | None = 2.0,
    **decode_options,
) -> list[Scan]:
    """Scan every camera of a capture that the calibration knows.

    Pixels where the decoded projector coordinates change faster than `max_gradient` projector
    px per camera px are dropped (``phase.STEEP``): there, at grazing view, a camera pixel
    spans more than 1/8 of the finest fringe period (16 px) and blur biases the phase; on the
    virtual scanner at full scale they held every decoding error above 1 px.

    Parameters
    ----------
    capture : Capture
        From :func:`nail2nail.io.capture.read_capture`.
    calibration : RigCalibration
        Camera names must match the capture's.
    """
    from tqdm.auto import tqdm

    scans = []
    names = capture.camera_names
    for name in tqdm(names, desc="scan", unit="camera", disable=not progress):
        scans.append(
            scan_frames(
                capture.load_frames(name),
                capture.pattern_set,
                calibration.camera(name),
                projector_distortion=calibration.projector_distortion,
                use=use,
                max_gradient=max_gradient,
                **decode_options,
            )
        )
    return scans


def sample_bilinear(image, xy) -> np.ndarray:
    """Bilinear samples of `image` ``(H, W)`` at pixel coordinates `xy` ``(N, 2)``.

    NaN where any of the four neighbours is NaN or the point is outside the image.
    """
    image = np.asarray(image, dtype=float)
    xy = np.asarray(xy, dtype=float)
    H, W = image.shape
    x, y = xy[:, 0], xy[:, 1]
    inside = (x >= 0) & (x <= W - 1) & (y >= 0) & (y <= H - 1)
    x0 = np.clip(np.floor(x), 0, W - 2).astype(int)
    y0 = np.clip(np.floor(y), 0, H - 2).astype(int)
    fx, fy = x - x0, y - y0
    value = (
        image[y0, x0] * (1 - fx) * (1 - fy)
        + image[y0, x0 + 1] * fx * (1 - fy)
        + image[y0 + 1, x0] * (1 - fx) * fy
        + image[y0 + 1, x0 + 1] * fx * fy
    )
    return np.where(inside, value, np.nan)


def surface_samples(
    decoded,
    marks_xy,
    diameter_px: float,
    *,
    stride: int = 8,
    clearance: float = 1.2,
    border_px: int = 4,
):
    """Pixels of the target's plain surface (between the marks) and their projector coordinates.

    Every `stride`-th pixel that decoded validly, lies farther than ``clearance · d`` from every
    mark centre (the albedo edge of a mark biases the phase) and `border_px` inside the valid
    region.

    Parameters
    ----------
    decoded : Decoded
        The camera's decode (:func:`nail2nail.phase.decode`).
    marks_xy : (K, 2) float
        Mark centres, camera px.
    diameter_px : float
        Mark diameter ``d``, camera px.
    stride : int
        Sampling step along rows and columns, px.
    clearance : float
        Smallest distance from a mark centre, in mark diameters.
    border_px : int
        Erosion of the valid region, px.

    Returns
    -------
    xy_camera : (M, 2) float64
        Pixel centres ``(x, y) = (column, row)``, camera px.
    xy_projector : (M, 2) float64
        Decoded panel coordinates ``(xp, yp)`` there, projector px.
    """
    from scipy import ndimage

    valid = ndimage.binary_erosion(decoded.mask, iterations=border_px)
    H, W = valid.shape
    rows, cols = np.mgrid[0:H:stride, 0:W:stride]
    keep = valid[rows, cols]
    xy = np.column_stack([cols[keep], rows[keep]]).astype(float)
    if len(marks_xy) and len(xy):
        from scipy.spatial import cKDTree

        dist, _ = cKDTree(np.asarray(marks_xy, dtype=float)).query(xy)
        xy = xy[dist > clearance * diameter_px]
    r, c = xy[:, 1].astype(int), xy[:, 0].astype(int)
    return xy, np.column_stack([decoded.xp[r, c], decoded.yp[r, c]]).astype(float)


def cylinder_distance(radius: float):
    """Signed distance ``hypot(X, Z) − radius`` (mm) from a cylinder about the world Y axis."""
    return lambda xyz: np.hypot(xyz[..., 0], xyz[..., 2]) - radius


def target_observations(
    capture,
    *,
    mark_diameter_px: float | None = None,
    progress: bool = False,
    surface_stride: int = 8,
    **decode_options,
) -> list:
    """Decode a capture of the cylindrical target and measure its reference marks.

    For each camera: decode the frames, find and identify the marks in the albedo image
    (:func:`nail2nail.markers.find_target_marks`, sub-pixel centroids) and sample the decoded
    projector coordinates there (bilinear). Marks without a valid decode are dropped.

    Parameters
    ----------
    capture : Capture
        A capture of the target scene.
    mark_diameter_px : float, optional
        Approximate mark diameter in the images; by default from the nominal rig in the capture
        manifest.

    Returns
    -------
    list of TargetObservations
        One per camera (world mm, camera px, projector panel px, and the grid identities in
        ``.grid``).
    """
    from tqdm.auto import tqdm

    from .calibration import TargetObservations
    from .markers import find_target_marks
    from .markers import mark_diameter_px as nominal_diameter

    out = []
    for name in tqdm(capture.camera_names, desc="target", unit="camera", disable=not progress):
        decoded = decode(
            capture.load_frames(name), capture.pattern_set, keep_invalid=False, **decode_options
        )
        diameter = mark_diameter_px
        if diameter is None:
            if "rig" not in capture.manifest:
                raise ValueError(
                    f"{capture.path}: no nominal rig in the manifest; give the mark diameter in px"
                )
            rig = capture.rig()
            diameter = nominal_diameter(rig.cameras[rig.camera_names.index(name)])
        marks = find_target_marks(decoded.albedo, mark_diameter_px=diameter)
        # Sampling at the centroid itself: measured against the simulator's truth, the decoded
        # coordinates there are within 0.03 projector px (rms) of the true ones.
        xp = sample_bilinear(decoded.xp, marks.xy)
        yp = sample_bilinear(decoded.yp, marks.xy)
        ok = np.isfinite(xp) & np.isfinite(yp)
        H, W = decoded.shape
        surf_xy, surf_panel = surface_samples(decoded, marks.xy, diameter, stride=surface_stride)
        out.append(
            TargetObservations(
                name,
                marks.xyz_world[ok],
                marks.xy[ok],
                np.column_stack([xp[ok], yp[ok]]),
                size=(W, H),
                grid=marks.grid[ok],
                surface_xy_camera=surf_xy,
                surface_xy_projector=surf_panel,
            )
        )
    return out


def calibrate_from_observations(
    observations,
    *,
    model: str = "dlt",
    method: str = "thesis",
    use: str = "yp",
    projector_size=(1280, 1040),
    surface=None,
    initial_distortion=None,
    projector_distortion=None,
):
    """Calibration and per-camera summary from target observations.

    ``model="dlt"``: each camera and its own projector matrix (thesis eq. 3.11); with
    `projector_distortion` (``{"center", "rho"}``, e.g. the plane estimate) the decoded panel
    coordinates are undistorted first and the calibration carries the distortion, so that scans
    compensate it in the model (:func:`~nail2nail.reconstruction.reconstruct_image`) instead of
    with pre-distorted patterns;
    ``model="joint"``: pinhole cameras and one shared projector with radial distortion
    (:func:`~nail2nail.calibration.calibrate_rig_joint`), with the target's dense surface
    constraints when `surface` (a signed distance, e.g. :func:`cylinder_distance`) is given,
    starting from `initial_distortion` (``{"center", "rho"}``, e.g. the plane estimate) if given.

    Returns
    -------
    calibration : RigCalibration
    summary : dict
        Per camera name: ``points`` and ``camera_rms_px``, with ``rms_mm`` (DLT, X/Y/Z) or
        ``projector_rms_px`` (joint).

    Raises
    ------
    ValueError
        For an unknown `model`.
    """
    summary = {}
    if model == "dlt":
        from .distortion import ideal_from_panel

        cameras = []
        for obs in observations:
            xy_projector = obs.xy_projector
            if projector_distortion is not None:
                xy_projector = ideal_from_panel(
                    xy_projector, projector_distortion["center"], projector_distortion["rho"]
                )
            report = calibrate_points(
                obs.xyz_world, obs.xy_camera, xy_projector, method=method, use=use
            )
            cameras.append(
                CameraCalibration(
                    obs.name, report.camera_matrix, report.projector_matrix, size=obs.size
                )
            )
            summary[obs.name] = {
                "points": len(obs.xyz_world),
                "rms_mm": report.rms_mm.round(6).tolist(),
                "camera_rms_px": float(np.sqrt(np.mean(report.camera_residual_px**2))),
            }
        calib = RigCalibration(
            cameras=cameras,
            projector_distortion=None
            if projector_distortion is None
            else {
                "center": [float(c) for c in projector_distortion["center"]],
                "rho": float(projector_distortion["rho"]),
            },
            extra={"model": "dlt", "method": method},
        )
        return calib, summary
    if model != "joint":
        raise ValueError(f"model: expected 'dlt' or 'joint', got {model!r}")
    init = initial_distortion or {}
    joint = calibrate_rig_joint(
        observations,
        projector_size=projector_size,
        surface=surface,
        initial_rho=float(init.get("rho", 0.0)),
        initial_center=init.get("center"),
    )
    cameras = [
        CameraCalibration(o.name, cam, joint.projector, size=o.size)
        for o, cam in zip(observations, joint.cameras, strict=True)
    ]
    for o, c_rms, p_rms in zip(
        observations, joint.camera_rms_px, joint.projector_rms_px, strict=True
    ):
        summary[o.name] = {
            "points": len(o.xyz_world),
            "camera_rms_px": c_rms,
            "projector_rms_px": p_rms,
        }
    calib = RigCalibration(
        cameras=cameras, projector_distortion=joint.projector_distortion, extra={"model": "joint"}
    )
    return calib, summary


def points_table(obs) -> PointsTable:
    """A thesis-style points table of one camera's target observations."""
    columns = {
        "Xw": obs.xyz_world[:, 0],
        "Yw": obs.xyz_world[:, 1],
        "Zw": obs.xyz_world[:, 2],
        "xc": obs.xy_camera[:, 0],
        "yc": obs.xy_camera[:, 1],
        "xp": obs.xy_projector[:, 0],
        "yp": obs.xy_projector[:, 1],
    }
    if obs.grid is not None:
        columns["grid_row"] = obs.grid[:, 0].astype(float)
        columns["grid_col"] = obs.grid[:, 1].astype(float)
    return PointsTable(columns=columns, labels=[str(i + 1) for i in range(len(obs.xyz_world))])
