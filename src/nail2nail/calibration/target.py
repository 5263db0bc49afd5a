"""Joint calibration of the cameras and one shared projector on the thesis's cylinder target.

The thesis's machined cylinder carries marks at known positions
(:mod:`nail2nail.calibration.markers`);
:func:`calibrate_rig_joint` refines pinhole cameras and one projector with the thesis's radial
distortion (eq. 3.34) on the marks' camera and decoded projector coordinates, optionally with
dense surface constraints; :func:`calibrate_from_observations` is the entry point of
``nail2nail calibrate-capture`` (DLT per camera, :mod:`.dlt`, or the joint model).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nail2nail.calibration.camera_models import Pinhole, dlt_from_pinhole, pinhole_from_dlt
from nail2nail.calibration.distortion import (
    ProjectorDistortion,
    as_projector_distortion,
    ideal_from_panel,
)
from nail2nail.calibration.dlt import (
    calibrate_points,
    check_calibration_points,
    fit_projection_matrix,
)
from nail2nail.calibration.files import CameraCalibration, RigCalibration
from nail2nail.scan.triangulation import reconstruct_points_ray

__all__ = [
    "JointCalibration",
    "TargetObservations",
    "calibrate_from_observations",
    "calibrate_projectors_from_observations",
    "calibrate_projectors_joint",
    "calibrate_rig_joint",
]


@dataclass
class TargetObservations:
    """Reference points of the calibration target as seen by one camera.

    Attributes
    ----------
    name : str
        Camera name.
    xyz_world : (N, 3) float64
        Ideal world coordinates, mm.
    xy_camera : (N, 2) float64
        Camera coordinates, px.
    xy_projector : (N, 2) float64
        Decoded projector panel coordinates ``(xp, yp)``, px.
    size : (2,) int
        Camera image ``(W, H)``.
    grid : (N, 2) int or None
        Target grid identity ``(row, col)`` of each point, if known.
    surface_xy_camera, surface_xy_projector : (M, 2) float64 or None
        Pixels on the target's surface between the marks and their decoded projector panel
        coordinates: dense constraints for :func:`calibrate_rig_joint`'s ``surface`` option.
    """

    name: str
    xyz_world: np.ndarray
    xy_camera: np.ndarray
    xy_projector: np.ndarray
    size: tuple[int, int] = (1024, 1280)
    grid: np.ndarray | None = None
    surface_xy_camera: np.ndarray | None = None
    surface_xy_projector: np.ndarray | None = None


@dataclass
class JointCalibration:
    """Result of :func:`calibrate_rig_joint`.

    Attributes
    ----------
    cameras : list of Pinhole
        One pinhole model per camera.
    projector : Pinhole
        The one projector model shared by every camera.
    projector_distortion : ProjectorDistortion or None
        The radial model (eq. 3.34; centre = the projector's principal point).
    camera_rms_px, projector_rms_px : list of float
        RMS reprojection residual per camera, camera px and projector panel px.
    """

    cameras: list
    projector: Pinhole
    projector_distortion: ProjectorDistortion | None
    camera_rms_px: list
    projector_rms_px: list


def _pack(model) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    K = model.K
    return np.r_[
        K[0, 0], K[1, 1], K[0, 2], K[1, 2], Rotation.from_matrix(model.R).as_rotvec(), model.t
    ]


def _unpack(p: np.ndarray, size) -> object:
    from scipy.spatial.transform import Rotation

    K = np.array([[p[0], 0.0, p[2]], [0.0, p[1], p[3]], [0.0, 0.0, 1.0]])
    return Pinhole(K=K, R=Rotation.from_rotvec(p[4:7]).as_matrix(), t=p[7:10], size=size)


def _mark_quadrature(target, grid, *, n_radial: int = 6, n_angular: int = 24):
    """Quadrature of every mark's bright area on the cylindrical target.

    A mark is a disc (the key a ring) drawn by arc length on the cylinder: in the unrolled
    coordinates ``(s, v)`` (arc length about the axis, ``Y``) it is a flat disc or ring. Its area
    is sampled by Gauss–Legendre in the radius (weight ``r dr``) times a uniform angular rule.

    Returns
    -------
    xyz_world : (M, S, 3) float64
        Sample points on the surface, mm.
    normal : (M, S, 3) float64
        Outward unit normals there.
    weight : (M, S) float64
        Surface area of each sample, mm².
    """
    grid = np.asarray(grid, dtype=int).reshape(-1, 2)
    x, wx = np.polynomial.legendre.leggauss(n_radial)
    phi = 2 * np.pi * (np.arange(n_angular) + 0.5) / n_angular
    is_key = (grid[:, 0] == target.key[0]) & (grid[:, 1] == target.key[1])
    r_in = np.where(is_key, target.key_inner_diameter / 2, 0.0)[:, None]
    r_out = np.where(is_key, target.key_outer_diameter / 2, target.mark_diameter / 2)[:, None]
    r = 0.5 * (r_out - r_in) * x + 0.5 * (r_out + r_in)  # (M, n_radial)
    w_r = 0.5 * (r_out - r_in) * wx * r
    s = (r[:, :, None] * np.cos(phi)).reshape(len(grid), -1)
    v = (r[:, :, None] * np.sin(phi)).reshape(len(grid), -1)
    weight = np.repeat(w_r * (2 * np.pi / n_angular), n_angular, axis=1)
    theta = np.radians(np.asarray(target.column_angles_deg))[grid[:, 1], None] + s / target.radius
    y = np.asarray(target.row_y)[grid[:, 0], None] + v
    normal = np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], axis=-1)
    xyz = normal * target.radius
    xyz[..., 1] = y
    return xyz, normal, weight


def _mark_centroids(camera, quadrature) -> np.ndarray:
    """Image centroids ``(M, 2)`` of the marks' projected areas (what the mark finder measures).

    The image area of a surface element ``dA`` at ``X`` (normal ``n``) is proportional to
    ``n · (C − X) / z³ dA`` for a pinhole camera at ``C`` (``z`` the depth of ``X``): the solid
    angle ``n · (C − X) dA / |C − X|³`` times the image area per solid angle ``f² / cos³α``.
    Seen obliquely on the curved target, this centroid lies up to ~0.4 px (at full scale)
    from the projection of the mark's centre, towards the side that faces the camera.
    """
    xyz, normal, weight = quadrature
    p = camera.to_camera(xyz)
    facing = np.sum(normal * (camera.center - xyz), axis=-1)
    w = weight * np.clip(facing, 0.0, None) / p[..., 2] ** 3
    xy = camera.project(xyz)
    with np.errstate(invalid="ignore", divide="ignore"):  # a mark seen edge-on: NaN
        return np.sum(w[..., None] * xy, axis=1) / np.sum(w, axis=1)[:, None]


def _ray_cylinder(camera, xy, radius: float) -> np.ndarray:
    """World points ``(N, 3)`` where the camera rays through pixels `xy` first meet the
    cylinder ``hypot(X, Z) = radius`` (NaN where they miss it)."""
    origin, d = camera.rays(xy)
    a = d[:, 0] ** 2 + d[:, 2] ** 2
    b = origin[0] * d[:, 0] + origin[2] * d[:, 2]
    c = origin[0] ** 2 + origin[2] ** 2 - radius**2
    disc = b * b - a * c
    with np.errstate(invalid="ignore"):
        t = (-b - np.sqrt(disc)) / a
    return origin + t[:, None] * d


def calibrate_rig_joint(
    observations: list[TargetObservations],
    *,
    projector_size=(1280, 1040),
    distortion: bool = True,
    initial_rho: float = 0.0,
    initial_center=None,
    surface=None,
    surface_weight: float = 30.0,
    target=None,
) -> JointCalibration:
    """Calibrate all cameras and **one shared projector** together (bundle adjustment).

    The thesis calibrates each camera with its own projector matrix (eq. 3.11), so each camera's
    projector matrix absorbs the projector's distortion differently and the scans do not merge.
    Here every camera's target points constrain the same projector model, a pinhole with the
    thesis's radial distortion (eq. 3.34; its centre tied to the principal point), and all
    parameters are refined together by non-linear least squares on the camera residuals (px) and
    the projector residuals in ideal projector coordinates (px). The linear DLT fits
    (:func:`fit_projection_matrix`) give the starting point.

    Parameters
    ----------
    observations : list of TargetObservations
        One per camera, at least 6 non-coplanar points each.
    projector_size : (2,) int
        Projector panel ``(W, H)``.
    distortion : bool
        Estimate the projector's radial distortion ρ (else ρ = 0).
    initial_rho : float
        Starting value of ρ (e.g. from :mod:`nail2nail.calibration.distortion`'s estimate).
    initial_center : (2,) float, optional
        The distortion centre that goes with `initial_rho`; the starting projector model is
        fitted to the panel coordinates undistorted with both.
    surface : callable, optional
        Signed distance ``f(xyz (M, 3)) -> (M,)`` in mm from the target's known surface (for the
        thesis's cylinder ``hypot(X, Z) − r``). With it, every surface sample of the observations
        (``surface_xy_camera``, ``surface_xy_projector``) is triangulated with the current
        parameters and its distance to the surface is a residual too: thousands of dense
        constraints next to a few dozen marks, which removes the depth bias that small mark
        centroid errors leave in a marks-only calibration.
    surface_weight : float
        Weight of a surface residual (mm) relative to the reprojection residuals (px); the
        default, about the cameras' px per mm, makes 1 µm count like 0.03 px.
    target : TargetGeometry, optional
        The cylindrical mark target (:class:`nail2nail.calibration.markers.TargetGeometry`) whose
        marks the
        observations measured (their ``grid`` identities are needed). With it, a camera residual
        compares a measured mark centroid with the modelled centroid of the mark's projected
        disc (or ring), not with the projection of its centre: seen obliquely on the curved
        target the two differ by up to ~0.4 px at full scale, a bias that a marks-only or
        surface-refined calibration turns into a depth error of several µm. The projector
        residual then uses the surface point that the camera sees at the measured centroid
        (where the projector coordinates were sampled), not the mark's centre.

    Returns
    -------
    JointCalibration
    """
    if not observations:
        raise ValueError("observations: need at least one camera")
    return _bundle([observations], [projector_size], distortion=distortion,
                   initial_rhos=[initial_rho], initial_centers=[initial_center],
                   surface=surface, surface_weight=surface_weight, target=target)[0]


def calibrate_projectors_joint(
    observation_sets: list[list[TargetObservations]],
    *,
    projector_sizes=None,
    distortion: bool = True,
    initial_rhos=None,
    initial_centers=None,
    surface=None,
    surface_weight: float = 30.0,
    target=None,
) -> list[JointCalibration]:
    """Calibrate all cameras and **several projectors** together (one bundle adjustment).

    A rig of several projectors (issue 26, :mod:`nail2nail.simulation.projectors`) captures the
    target once per projector, the target and the cameras still. Calibrated one projector at a
    time (:func:`calibrate_rig_joint` on each capture), every camera gets one model per
    projector, and the scans of one camera under two projectors, which should be the same
    points, disagree by what those models disagree. Here the cameras are one set of parameters
    that every projector's observations constrain, and each projector has its own pinhole and
    radial distortion (eq. 3.34): the residuals of :func:`calibrate_rig_joint` for every
    (projector, camera) pair, minimised together. With one projector it is
    :func:`calibrate_rig_joint`, to the last digit.

    Parameters
    ----------
    observation_sets : list of list of TargetObservations
        Per projector, its target capture's observations, one per camera, the cameras in the
        same order in every set (matched by name).
    projector_sizes : list of (2,) int, optional
        Per projector, its panel ``(W, H)``; default 1280 × 1040 each.
    distortion : bool
        Estimate each projector's radial distortion ρ.
    initial_rhos, initial_centers : list, optional
        Per projector, the starting ρ and its centre (as :func:`calibrate_rig_joint`'s).
    surface, surface_weight, target
        As :func:`calibrate_rig_joint`, for every projector's observations.

    Returns
    -------
    list of JointCalibration
        One per projector; their ``cameras`` are the same objects (one camera model each).

    Raises
    ------
    ValueError
        For no projector, a set without cameras, or sets whose cameras differ.
    """
    sets = [list(obs) for obs in observation_sets]
    if not sets:
        raise ValueError("observation_sets: need at least one projector")
    names = [o.name for o in sets[0]]
    for k, obs in enumerate(sets):
        if not obs:
            raise ValueError(f"observation_sets[{k}]: need at least one camera")
        if [o.name for o in obs] != names:
            raise ValueError(f"observation_sets[{k}]: cameras {[o.name for o in obs]}, but "
                             f"projector 0's are {names}: every projector's capture must list "
                             "the same cameras in the same order")
    n = len(sets)
    sizes = [(1280, 1040)] * n if projector_sizes is None else list(projector_sizes)
    rhos = [0.0] * n if initial_rhos is None else [float(r) for r in initial_rhos]
    centers = [None] * n if initial_centers is None else list(initial_centers)
    for label, values in (("projector_sizes", sizes), ("initial_rhos", rhos),
                          ("initial_centers", centers)):
        if len(values) != n:
            raise ValueError(f"{label}: expected {n} entries (one per projector), got "
                             f"{len(values)}")
    return _bundle(sets, sizes, distortion=distortion, initial_rhos=rhos,
                   initial_centers=centers, surface=surface, surface_weight=surface_weight,
                   target=target)


def _bundle(sets, projector_sizes, *, distortion, initial_rhos, initial_centers, surface,
            surface_weight, target) -> list[JointCalibration]:
    """The bundle adjustment of :func:`calibrate_projectors_joint` (`sets[k][i]`: camera ``i``
    under projector ``k``). Parameters: every camera, then every projector, then every ρ³."""
    from scipy.optimize import least_squares

    if len(sets) == 1:  # one projector: every camera must see the target lit by it
        for obs in sets[0]:
            check_calibration_points(obs.xyz_world, obs.xy_camera, name=obs.name)
            check_calibration_points(obs.xyz_world, obs.xy_projector, name=obs.name)
    # several: a side projector lights only part of the target, and a camera may see few or
    # none of the marks it lights; each camera starts from the set where it sees most, each
    # projector from all its cameras' points, and a (projector, camera) pair without marks
    # adds no residual
    observations = [max((obs_set[i] for obs_set in sets), key=lambda o: len(o.xyz_world))
                    for i in range(len(sets[0]))]
    for obs in observations:
        check_calibration_points(obs.xyz_world, obs.xy_camera, name=obs.name)
    cams0 = [
        pinhole_from_dlt(
            fit_projection_matrix(o.xyz_world, o.xy_camera, method="normalized"), size=o.size
        )
        for o in observations
    ]
    projs0 = []
    for k, (obs_set, size, rho, center) in enumerate(zip(sets, projector_sizes, initial_rhos,
                                                         initial_centers, strict=True)):
        xyz_all = np.concatenate([o.xyz_world for o in obs_set])
        panel_all = np.concatenate([o.xy_projector for o in obs_set])
        check_calibration_points(xyz_all, panel_all, name=f"projector {k}")
        if rho and center is not None:
            panel_all = ideal_from_panel(panel_all, center, rho)
        projs0.append(pinhole_from_dlt(
            fit_projection_matrix(xyz_all, panel_all, method="normalized"), size=size))
    radius = None if target is None else float(target.radius)

    def mark_image(cam, obs, quad):
        return cam.project(obs.xyz_world) if quad is None else _mark_centroids(cam, quad)

    def mark_point(cam, obs, quad):
        return obs.xyz_world if quad is None else _ray_cylinder(cam, obs.xy_camera, radius)

    quadratures = [[None] * len(obs_set) for obs_set in sets]
    if target is not None:
        for k, obs_set in enumerate(sets):
            for i, obs in enumerate(obs_set):
                if not len(obs.xyz_world):
                    continue
                if obs.grid is None:
                    raise ValueError(
                        f"{obs.name}: target needs the marks' grid identities (grid)")
                if len(obs.grid) != len(obs.xyz_world):
                    raise ValueError(f"{obs.name}: grid has {len(obs.grid)} rows for "
                                     f"{len(obs.xyz_world)} points")
                quadratures[k][i] = _mark_quadrature(target, obs.grid)
    n_cam, n_proj = len(observations), len(sets)
    # The solver works on k = ρ³ (the model is linear in it; dρ³/dρ = 0 at ρ = 0), scaled to O(1).
    k_scale = 1e8
    x0 = np.concatenate(
        [*(_pack(c) for c in cams0), *(_pack(p) for p in projs0),
         [r**3 * k_scale for r in initial_rhos] if distortion else []]
    )

    def split(x):
        cams = [_unpack(x[10 * i : 10 * i + 10], o.size) for i, o in enumerate(observations)]
        base = 10 * n_cam
        projs = [_unpack(x[base + 10 * k : base + 10 * k + 10], size)
                 for k, size in enumerate(projector_sizes)]
        rhos = ([float(np.cbrt(v / k_scale)) for v in x[base + 10 * n_proj:]] if distortion
                else [0.0] * n_proj)
        return cams, projs, rhos

    def residuals(x, with_surface=True):
        cams, projs, rhos = split(x)
        res = []
        for obs_set, quads, proj, rho in zip(sets, quadratures, projs, rhos, strict=True):
            for cam, obs, quad in zip(cams, obs_set, quads, strict=True):
                if not len(obs.xyz_world):
                    continue
                # a mark seen edge-on has no modelled centroid (NaN): it adds nothing, as a
                # projector residual without a surface point does
                res.append(np.nan_to_num(mark_image(cam, obs, quad) - obs.xy_camera).ravel())
                ideal = ideal_from_panel(obs.xy_projector, proj.K[:2, 2], rho)
                res_p = proj.project(mark_point(cam, obs, quad)) - ideal
                res.append(np.nan_to_num(res_p).ravel())
                if with_surface and surface is not None and obs.surface_xy_camera is not None:
                    ideal_s = ideal_from_panel(obs.surface_xy_projector, proj.K[:2, 2], rho)
                    # on the camera ray (pixel centres are exact): reconstruct_points_lsq with
                    # the camera equations' weight taken to infinity, compiled
                    xyz = reconstruct_points_ray(
                        dlt_from_pinhole(cam),
                        dlt_from_pinhole(proj),
                        *obs.surface_xy_camera.T,
                        *ideal_s.T,
                    )
                    res.append(surface_weight * np.nan_to_num(surface(xyz), nan=0.0))
        return np.concatenate(res)

    # Marks first; then, from there, marks and surface together (the surface residuals alone
    # have false minima far from a good start).
    fit = least_squares(
        residuals, x0, x_scale="jac", method="lm", max_nfev=4000, kwargs={"with_surface": False}
    )
    if surface is not None:
        fit = least_squares(residuals, fit.x, x_scale="jac", method="lm", max_nfev=4000)
    cams, projs, rhos = split(fit.x)
    out = []
    for obs_set, quads, proj, rho in zip(sets, quadratures, projs, rhos, strict=True):
        cam_rms, proj_rms = [], []
        for cam, obs, quad in zip(cams, obs_set, quads, strict=True):
            if not len(obs.xyz_world):
                cam_rms.append(float("nan"))
                proj_rms.append(float("nan"))
                continue
            res_c = mark_image(cam, obs, quad) - obs.xy_camera
            cam_rms.append(_rms(res_c))
            ideal = ideal_from_panel(obs.xy_projector, proj.K[:2, 2], rho)
            res_p = proj.project(mark_point(cam, obs, quad)) - ideal
            proj_rms.append(_rms(res_p))
        dist = (ProjectorDistortion(center=(float(proj.K[0, 2]), float(proj.K[1, 2])),
                                    rho=float(rho)) if distortion else None)
        out.append(JointCalibration(cams, proj, dist, cam_rms, proj_rms))
    return out


def _rms(residuals) -> float:
    """RMS of the finite residuals (NaN when there is none)."""
    r = np.asarray(residuals, dtype=np.float64)
    r = r[np.isfinite(r)]
    return float(np.sqrt(np.mean(r**2))) if r.size else float("nan")


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
    target=None,
):
    """Calibration of a rig, and a per-camera summary, from target observations.

    Parameters
    ----------
    observations : list of TargetObservations
        One per camera (e.g. :func:`nail2nail.calibration.observe.target_observations`).
    model : {"dlt", "joint"}
        ``"dlt"``: each camera and its own projector matrix (thesis eq. 3.11).
        ``"joint"``: pinhole cameras and one shared projector with radial distortion
        (:func:`calibrate_rig_joint`).
    method, use
        Estimator and reconstruction of the DLT model (:func:`calibrate_points`).
    projector_size : (2,) int
        Projector panel ``(W, H)``, px.
    surface : callable, optional
        Joint model: the target's signed distance in mm (e.g.
        :meth:`nail2nail.calibration.markers.TargetGeometry.signed_distance`) for dense constraints.
    initial_distortion : dict, optional
        Joint model: starting ``{"center", "rho"}`` (e.g. the flat-plane estimate).
    projector_distortion : dict, optional
        DLT model: a known ``{"center", "rho"}``; the decoded panel coordinates are undistorted
        first and the calibration carries the distortion, so that scans compensate it in the
        model (:func:`nail2nail.scan.triangulation.reconstruct_image`) instead of with
        pre-distorted patterns.
    target : TargetGeometry, optional
        Joint model: the mark target, to model the marks' measured centroids
        (:func:`calibrate_rig_joint`); the observations need their ``grid``.

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
        cameras = []
        dist = as_projector_distortion(projector_distortion)
        for obs in observations:
            xy_projector = obs.xy_projector
            if dist is not None:
                xy_projector = dist.ideal_from_panel(xy_projector)
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
            projector_distortion=dist,
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
        target=target,
    )
    return _rig_from_joint(observations, joint, {"model": "joint"})


def _rig_from_joint(observations, joint: JointCalibration, extra: dict):
    """The :class:`RigCalibration` of one projector's joint fit and its per-camera summary
    (``points``, ``camera_rms_px``, ``projector_rms_px``)."""
    cameras = [CameraCalibration(o.name, cam, joint.projector, size=o.size)
               for o, cam in zip(observations, joint.cameras, strict=True)]
    summary = {o.name: {"points": len(o.xyz_world), "camera_rms_px": c_rms,
                        "projector_rms_px": p_rms}
               for o, c_rms, p_rms in zip(observations, joint.camera_rms_px,
                                          joint.projector_rms_px, strict=True)}
    calib = RigCalibration(cameras=cameras, projector_distortion=joint.projector_distortion,
                           extra=extra)
    return calib, summary


def calibrate_projectors_from_observations(
    observation_sets,
    *,
    projector_sizes=None,
    surface=None,
    initial_distortions=None,
    target=None,
):
    """Calibrations of a rig of several projectors, one per projector, from one bundle.

    :func:`calibrate_projectors_joint` on each projector's target observations; the result is
    one :class:`~nail2nail.calibration.files.RigCalibration` per projector (the joint model:
    pinhole cameras, that projector and its radial distortion), every one with the same camera
    models, to scan that projector's captures with.

    Parameters
    ----------
    observation_sets : list of list of TargetObservations
        Per projector, one per camera (the same cameras in the same order).
    projector_sizes : list of (2,) int, optional
        Per projector, its panel ``(W, H)`` (default 1280 × 1040).
    surface, target
        As :func:`calibrate_from_observations` (joint model).
    initial_distortions : list of dict, optional
        Per projector, a starting ``{"center", "rho"}``.

    Returns
    -------
    calibrations : list of RigCalibration
    summaries : list of dict
        Per projector, per camera name: ``points``, ``camera_rms_px``, ``projector_rms_px``.
    """
    sets = [list(obs) for obs in observation_sets]
    inits = [d or {} for d in (initial_distortions or [None] * len(sets))]
    joints = calibrate_projectors_joint(
        sets, projector_sizes=projector_sizes, surface=surface, target=target,
        initial_rhos=[float(d.get("rho", 0.0)) for d in inits],
        initial_centers=[d.get("center") for d in inits])
    calibrations, summaries = [], []
    for k, (obs_set, joint) in enumerate(zip(sets, joints, strict=True)):
        calib, summary = _rig_from_joint(
            obs_set, joint, {"model": "joint", "projectors": len(sets), "projector": k})
        calibrations.append(calib)
        summaries.append(summary)
    return calibrations, summaries
