"""Calibration of the cameras and the projector from a flat board seen in several poses.

Each pose of the board is a capture with the usual phase patterns. In every camera the board's
features (corners or circle centres) are detected on the all-lit image (or the decoded mean
intensity), and the projector coordinates of each feature are read off the decoded ``(xp, yp)``
through a **local homography** fitted on the decoded pixels around it
(:mod:`nail2nail.calibration.observe`): the board is flat, so near a feature the
camera-to-projector map is a homography, and a least-squares fit over many pixels gives the
projector point of the feature to a fraction of the decoding noise (Moreno & Taubin 2012). The
projector is then calibrated as an inverse camera on those points.

Steps (:func:`calibrate_board`):

1. each camera, and the projector, by Zhang's method (``cv2.calibrateCamera``) on its own
   views: intrinsics, OpenCV distortion and the pose of the board in each view;
2. the rig: every device's pose in the world frame (a camera's frame, or the board's frame in
   a pose) from the per-view board poses, chained through the poses the devices share and
   averaged (rotation mean): what ``cv2.stereoCalibrate`` does per pair, for all devices at
   once and without needing one camera to see every pose;
3. a joint bundle adjustment (``scipy.optimize.least_squares``, Levenberg–Marquardt) of all
   intrinsics, distortions, device poses and board poses on the camera residuals (camera px)
   and projector residuals (panel px), the projector with OpenCV's distortion or the thesis's
   radial model (eq. 3.34; centre tied to the principal point, as
   :func:`nail2nail.calibration.target.calibrate_rig_joint`); after a first fit each group of points
   (a camera's, the projector's through each camera) is weighted by the inverse of its noise
   estimated from the residuals, points beyond 5 of those standard deviations are dropped and
   the fit is repeated.

The result is a :class:`BoardCalibration` whose :meth:`~BoardCalibration.rig_calibration` is a
:class:`nail2nail.calibration.files.RigCalibration` of pinhole models (the same projector for
every camera).

A rig of several projectors (``docs/projectors.md``) is calibrated in the same bundle: each pose
is captured once per projector, each :class:`BoardView` names the projector whose coordinates
it carries (:attr:`BoardView.projector`), every projector is a device of its own (its
intrinsics, lens and pose; the thesis model: each its own ρ) and the cameras are one set of
parameters for all of them (:meth:`BoardCalibration.rig_calibrations`: one
``RigCalibration`` per projector, the same cameras).

References
----------
D. Moreno and G. Taubin, "Simple, accurate, and robust projector-camera calibration", 3DIMPVT
2012, doi:10.1109/3DIMPVT.2012.77.
Z. Zhang, "A flexible new technique for camera calibration", IEEE TPAMI 22(11), 2000,
doi:10.1109/34.888718.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from nail2nail._uncertainty import gauss_newton_std
from nail2nail.calibration.camera_models import Pinhole
from nail2nail.calibration.distortion import ProjectorDistortion, ideal_from_panel
from nail2nail.calibration.files import CameraCalibration, RigCalibration

__all__ = [
    "PROJECTOR_MODELS",
    "BoardCalibration",
    "BoardView",
    "calibrate_board",
    "calibrate_device",
    "projector_points_by_pose",
]

PROJECTOR_MODELS = ("opencv", "thesis")
#: Fewest views of a device (camera or projector) that Zhang's method is run on.
MIN_VIEWS = 3
#: Fewest features of a view.
MIN_FEATURES = 6
#: The cameras' OpenCV distortion terms fitted (indices into ``(k1, k2, p1, p2, k3)``).
CAMERA_DISTORTION = {"radial": (0, 1), "none": (), "full": (0, 1, 2, 3, 4)}
#: OpenCV's distortion terms in its order; a distortion spec names a preset of
#: :data:`CAMERA_DISTORTION` or a comma-separated subset of these (``"k1"``, ``"k1,k2,k3"``).
DISTORTION_TERMS = ("k1", "k2", "p1", "p2", "k3")


def distortion_terms(spec: str) -> tuple[int, ...]:
    """The indices (OpenCV's order ``k1, k2, p1, p2, k3``) of the distortion terms fitted.

    `spec` is a preset (``"radial"`` = k1, k2; ``"none"``; ``"full"`` = all five) or the terms
    by name, comma-separated (``"k1"``, ``"k1,k2,p1,p2"``); the others are fixed at 0, as
    OpenCV's ``CALIB_FIX_K1`` … ``CALIB_FIX_K3`` and ``CALIB_ZERO_TANGENT_DIST`` do, so ``p1``
    and ``p2`` come together.

    Examples
    --------
    >>> distortion_terms("radial"), distortion_terms("k1,k3"), distortion_terms("none")
    ((0, 1), (0, 4), ())
    """
    if spec in CAMERA_DISTORTION:
        return CAMERA_DISTORTION[spec]
    names = [t.strip() for t in str(spec).split(",") if t.strip()]
    unknown = [t for t in names if t not in DISTORTION_TERMS]
    if unknown or not names or len(set(names)) != len(names):
        raise ValueError(f"distortion: expected one of {tuple(CAMERA_DISTORTION)} or distinct "
                         f"terms among {', '.join(DISTORTION_TERMS)}, got {spec!r}")
    if ("p1" in names) != ("p2" in names):
        raise ValueError(f"distortion: p1 and p2 are fitted together (OpenCV's "
                         f"CALIB_ZERO_TANGENT_DIST fixes both), got {spec!r}")
    return tuple(sorted(DISTORTION_TERMS.index(t) for t in names))
#: The solver works on k = ρ³ of the thesis model, scaled to O(1).
_K_SCALE = 1e8


@dataclass
class BoardView:
    """The board's features seen by one camera in one pose.

    Attributes
    ----------
    camera : str
        Camera name.
    pose : int
        Index of the board pose (the same index for every camera's view of that pose).
    ids : (N,) int
        Index of each feature in the board's object points.
    xy_camera : (N, 2) float64
        Feature positions in the camera image, px (pixel-centre convention).
    xy_projector : (N, 2) float64 or None
        Projector panel coordinates ``(xp, yp)`` of each feature, px, NaN where none could be
        measured; ``None`` when the view gives no projector points.
    projector : str
        The projector whose coordinates `xy_projector` are (a rig of several projectors: the
        capture's name, ``"p0"``, ``"p1"`` …); ``"projector"`` for the one projector.
    """

    camera: str
    pose: int
    ids: np.ndarray
    xy_camera: np.ndarray
    xy_projector: np.ndarray | None = None
    projector: str = "projector"

    def __post_init__(self):
        self.ids = np.asarray(self.ids, dtype=int).reshape(-1)
        self.xy_camera = np.asarray(self.xy_camera, dtype=float).reshape(-1, 2)
        n = len(self.ids)
        if len(self.xy_camera) != n:
            raise ValueError(f"view {self.camera}/pose {self.pose}: {n} ids but "
                             f"{len(self.xy_camera)} camera points")
        if len(np.unique(self.ids)) != n:
            raise ValueError(f"view {self.camera}/pose {self.pose}: repeated feature ids")
        if not np.all(np.isfinite(self.xy_camera)):
            raise ValueError(f"view {self.camera}/pose {self.pose}: camera points not finite")
        if self.xy_projector is not None:
            self.xy_projector = np.asarray(self.xy_projector, dtype=float).reshape(-1, 2)
            if len(self.xy_projector) != n:
                raise ValueError(f"view {self.camera}/pose {self.pose}: {n} ids but "
                                 f"{len(self.xy_projector)} projector points")


@dataclass
class BoardCalibration:
    """Result of :func:`calibrate_board`.

    Attributes
    ----------
    camera_names : list of str
    cameras : list of Pinhole
        Camera models, poses ``T_cam_world``.
    projector : Pinhole
        The projector (ideal coordinates with the thesis model, panel coordinates with OpenCV's
        distortion in ``dist``); with several projectors, the first of :attr:`projectors`.
    projector_distortion : ProjectorDistortion or None
        ``{"center": [x, y], "rho": ρ}`` of the thesis model (eq. 3.34), else ``None``; with
        several projectors, the first's.
    board_poses : dict of int to (4, 4) float64
        ``T_world_board`` of every pose used.
    camera_rms_px : dict of str to float
        RMS reprojection residual of each camera, px (both coordinates together).
    projector_rms_px : float
        RMS residual of the projector points, panel px (ideal px with the thesis model); every
        projector's together.
    projector_rms_by_camera_px : dict of str to float
        The same, over the projector points measured through each camera.
    pose_rms_px : dict of int to dict
        Per pose: ``{"camera": {name: rms}, "projector": rms}``, px.
    views_used, views_refused : list of (str, int)
        ``(camera, pose)`` of the views fitted, and of those refused (too few features).
    points_dropped : int
        Residual outliers dropped before the final fit.
    world : str
        The world frame: a camera's name, or ``"board"`` (the board in the first pose).
    projector_model : {"opencv", "thesis"}
    parameter_std : dict of str to float
        Standard deviation of each fitted parameter, ``"cam0.fx"``, ``"projector.k1"``,
        ``"projector.rho"``, ``"cam1.tz"`` … (:meth:`_BundleAdjustment.parameter_std`: px, no
        unit, degrees, mm), from the Jacobian at the solution.
    n_poses : int
        Board poses in the fit.
    projector_names : list of str
        The projectors (:attr:`BoardView.projector`), in the order first met; ``["projector"]``
        for one.
    projectors : dict of str to Pinhole
        Each projector's model, as :attr:`projector`.
    projector_distortions : dict of str to ProjectorDistortion or None
        Each projector's thesis distortion, as :attr:`projector_distortion`.
    projector_rms_by_projector_px : dict of str to float
        RMS residual of each projector's points, panel px.
    """

    camera_names: list
    cameras: list
    projector: Pinhole
    projector_distortion: ProjectorDistortion | None
    board_poses: dict
    camera_rms_px: dict
    projector_rms_px: float
    projector_rms_by_camera_px: dict
    pose_rms_px: dict
    views_used: list
    views_refused: list = field(default_factory=list)
    points_dropped: int = 0
    world: str = "cam0"
    projector_model: str = "opencv"
    parameter_std: dict = field(default_factory=dict)
    n_poses: int = 0
    projector_names: list = field(default_factory=lambda: ["projector"])
    projectors: dict = field(default_factory=dict)
    projector_distortions: dict = field(default_factory=dict)
    projector_rms_by_projector_px: dict = field(default_factory=dict)

    def rig_calibration(self, *, extra: dict | None = None,
                        projector: str | None = None) -> RigCalibration:
        """The calibration as a :class:`~nail2nail.calibration.files.RigCalibration` (pinhole
        cameras, the same projector for every camera): of `projector` (a name of
        :attr:`projector_names`; the first by default)."""
        name = self.projector_names[0] if projector is None else projector
        if name not in self.projector_names:
            raise ValueError(f"projector: expected one of {self.projector_names}, got {name!r}")
        model = self.projectors.get(name, self.projector)
        cameras = [CameraCalibration(cam_name, cam, model, size=cam.size)
                   for cam_name, cam in zip(self.camera_names, self.cameras, strict=True)]
        rms = self.projector_rms_by_projector_px.get(name, self.projector_rms_px)
        info = {"model": "board", "projector_model": self.projector_model, "world": self.world,
                "camera_rms_px": self.camera_rms_px, "projector_rms_px": rms}
        if len(self.projector_names) > 1:
            info["projector"] = name
        return RigCalibration(cameras=cameras,
                              projector_distortion=self.projector_distortions.get(
                                  name, self.projector_distortion),
                              extra={**info, **(extra or {})})

    def rig_calibrations(self, *, extra: dict | None = None) -> dict[str, RigCalibration]:
        """Every projector's :meth:`rig_calibration`, by name (the same cameras in each)."""
        return {name: self.rig_calibration(extra=extra, projector=name)
                for name in self.projector_names}

    def poses_needed(self, *, focal: float = 1e-3, principal_point_px: float = 1.0) -> int:
        """Poses for every device's focal length within `focal` (fraction) and principal point
        within `principal_point_px` (one standard deviation), at the uncertainty of this fit:
        a parameter's deviation shrinks as ``1 / sqrt(poses)``, so ``n (σ / target)²``. At
        least the poses used."""
        need = float(self.n_poses)
        models = dict(zip(self.camera_names, self.cameras, strict=True))
        models.update(self.projectors or {"projector": self.projector})
        for name, model in models.items():
            f = float(model.K[1, 1])
            for key, target in (("f", focal * f), ("fx", focal * f), ("fy", focal * f),
                                ("cx", principal_point_px), ("cy", principal_point_px)):
                sigma = self.parameter_std.get(f"{name}.{key}")
                if sigma is not None and np.isfinite(sigma):
                    need = max(need, self.n_poses * (sigma / target) ** 2)
        return int(np.ceil(need))

    def summary(self) -> dict:
        """JSON-ready figures: RMS per camera and projector, per pose, views used/refused."""
        return {
            "world": self.world,
            "projector_model": self.projector_model,
            "camera_rms_px": self.camera_rms_px,
            "projector_rms_px": self.projector_rms_px,
            "projector_rms_by_camera_px": self.projector_rms_by_camera_px,
            **({"projector_rms_by_projector_px": self.projector_rms_by_projector_px}
               if len(self.projector_names) > 1 else {}),
            "poses": {str(k): v for k, v in self.pose_rms_px.items()},
            "views_used": [list(v) for v in self.views_used],
            "views_refused": [list(v) for v in self.views_refused],
            "points_dropped": self.points_dropped,
            "projector_distortion": (None if self.projector_distortion is None
                                     else self.projector_distortion.to_dict()),
            **({"projector_distortions": {
                k: None if v is None else v.to_dict()
                for k, v in self.projector_distortions.items()}}
               if len(self.projector_names) > 1 else {}),
            "parameter_std": self.parameter_std,
            "n_poses": self.n_poses,
            "poses_needed": self.poses_needed(),
        }


# ------------------------------------------------------------------------------------------------
# Single-device calibration (Zhang's method, OpenCV)
# ------------------------------------------------------------------------------------------------
def _transform(rvec, tvec) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(np.ravel(rvec)).as_matrix()
    T[:3, 3] = np.ravel(tvec)
    return T


def calibrate_device(object_points, image_points, size, *, name: str = "device",
                     distortion: str = "full", fix_aspect_ratio: bool = False,
                     fix_principal_point: bool = False) -> tuple[Pinhole, list, float]:
    """Intrinsics and per-view board poses of one camera (or projector) by Zhang's method.

    Parameters
    ----------
    object_points : list of (N_i, 3) float
        Board points of each view in the board frame (``z = 0``), mm.
    image_points : list of (N_i, 2) float
        Their image (or panel) coordinates, px.
    size : (2,) int
        Image ``(W, H)``, px.
    name : str
        How messages name the device.
    distortion : {"full", "radial", "none"}
        OpenCV's terms to fit: all of ``(k1, k2, p1, p2, k3)``, ``k1, k2`` or none.

    Returns
    -------
    model : Pinhole
        Intrinsics and distortion, identity pose.
    T_device_board : list of (4, 4) float64
        The board's pose in each view.
    rms_px : float
        OpenCV's RMS reprojection error, px.

    Raises
    ------
    ValueError
        Fewer than :data:`MIN_VIEWS` views or fewer than :data:`MIN_FEATURES` points in a view.

    References
    ----------
    Z. Zhang, "A flexible new technique for camera calibration", IEEE TPAMI 22(11), 2000,
    doi:10.1109/34.888718.
    """
    import cv2

    if len(object_points) != len(image_points):
        raise ValueError(f"{name}: {len(object_points)} object point sets but "
                         f"{len(image_points)} image point sets")
    if len(object_points) < MIN_VIEWS:
        raise ValueError(f"{name}: {len(object_points)} view(s) of the board; need at least "
                         f"{MIN_VIEWS}")
    obj = [np.ascontiguousarray(np.asarray(o, dtype=np.float32).reshape(-1, 1, 3))
           for o in object_points]
    img = [np.ascontiguousarray(np.asarray(p, dtype=np.float32).reshape(-1, 1, 2))
           for p in image_points]
    for k, (o, p) in enumerate(zip(obj, img, strict=True)):
        if len(o) != len(p) or len(o) < MIN_FEATURES:
            raise ValueError(f"{name}: view {k} has {len(o)} object and {len(p)} image points; "
                             f"need at least {MIN_FEATURES} of each, as many")
    free = distortion_terms(distortion)
    flags = ((0 if 0 in free else cv2.CALIB_FIX_K1) | (0 if 1 in free else cv2.CALIB_FIX_K2)
             | (0 if 4 in free else cv2.CALIB_FIX_K3)
             | (0 if 2 in free else cv2.CALIB_ZERO_TANGENT_DIST)
             | (cv2.CALIB_FIX_ASPECT_RATIO if fix_aspect_ratio else 0)
             | (cv2.CALIB_FIX_PRINCIPAL_POINT if fix_principal_point else 0))
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    # without CALIB_USE_INTRINSIC_GUESS OpenCV reads only fx / fy (kept at 1 with
    # CALIB_FIX_ASPECT_RATIO) and puts the principal point at ((W - 1) / 2, (H - 1) / 2)
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(  # type: ignore[call-overload]
        obj, img, tuple(int(v) for v in size), np.eye(3), None, flags=flags,
        criteria=criteria)
    model = Pinhole(K=K, R=np.eye(3), t=np.zeros(3), dist=np.ravel(dist)[:5], size=size)
    return model, [_transform(r, t) for r, t in zip(rvecs, tvecs, strict=True)], float(rms)


# ------------------------------------------------------------------------------------------------
# Joint refinement
# ------------------------------------------------------------------------------------------------
def _rotations(rvecs: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(rvecs.reshape(-1, 3)).as_matrix()


def _rvec(R) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_rotvec()


def _project(intr: np.ndarray, dist: np.ndarray, xyz_device: np.ndarray) -> np.ndarray:
    """Pixels ``(N, 2)`` of points ``(N, 3)`` in a device frame; `intr` = ``(fx, fy, cx, cy)``,
    `dist` OpenCV's ``(k1, k2, p1, p2, k3)`` (as :meth:`Pinhole.project`)."""
    x = xyz_device[:, 0] / xyz_device[:, 2]
    y = xyz_device[:, 1] / xyz_device[:, 2]
    k1, k2, p1, p2, k3 = dist
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([intr[0] * xd + intr[2], intr[1] * yd + intr[3]], axis=1)


def _average_transform(transforms: list) -> np.ndarray:
    """Mean of rigid transforms ``(4, 4)``: chordal rotation mean, mean translation."""
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_matrix(np.array([t[:3, :3] for t in transforms])).mean().as_matrix()
    T[:3, 3] = np.mean([t[:3, 3] for t in transforms], axis=0)
    return T


def _initial_poses(T_dev_board: dict, devices: list, poses: list, world) -> tuple[dict, dict]:
    """Device poses ``T_dev_world`` and board poses ``T_world_board`` from per-view board poses.

    `T_dev_board` maps ``(device, pose)`` to the board's pose in that view; `world` is a device
    (its frame is the world) or ``("board", pose)``. Poses and devices are reached by turns
    through the views they share; each is the mean over the views linking it to those known.
    """
    T_dev_world: dict = {}
    T_world_board: dict = {}
    if isinstance(world, tuple):
        T_world_board[world[1]] = np.eye(4)
    else:
        T_dev_world[world] = np.eye(4)
    while True:
        grown = False
        for pose in poses:
            if pose in T_world_board:
                continue
            links = [np.linalg.inv(T_dev_world[d]) @ T_dev_board[d, pose] for d in T_dev_world
                     if (d, pose) in T_dev_board]
            if links:
                T_world_board[pose] = _average_transform(links)
                grown = True
        for dev in devices:
            if dev in T_dev_world:
                continue
            links = [T_dev_board[dev, p] @ np.linalg.inv(T_world_board[p]) for p in T_world_board
                     if (dev, p) in T_dev_board]
            if links:
                T_dev_world[dev] = _average_transform(links)
                grown = True
        if not grown:
            break
    missing = [d for d in devices if d not in T_dev_world]
    if missing:
        raise ValueError(f"{missing[0]}: shares no board pose with the others (directly or "
                         "through other cameras); its place in the rig is unknown")
    return T_dev_world, T_world_board


def calibrate_board(
    views: list[BoardView],
    object_points,
    camera_sizes: dict,
    *,
    projector_size=(1280, 1040),
    projector_model: str = "opencv",
    world: str | None = None,
    camera_distortion: str = "radial",
    outlier_sigma: float = 5.0,
    projector_lens: str = "full",
    fix_aspect_ratio: bool = False,
    fix_principal_point: bool = False,
) -> BoardCalibration:
    """Calibrate every camera and the projector from views of a flat board in several poses.

    Parameters
    ----------
    views : list of BoardView
        Every camera's view of every pose (a pose a camera does not see is simply absent).
        Views with fewer than :data:`MIN_FEATURES` features are refused (listed in the result).
        With several projectors, a view per camera, pose and projector
        (:attr:`BoardView.projector`): each projector is fitted as a device of its own, the
        cameras' points of a pose are taken from the first projector's view of it.
    object_points : (M, 3) float
        The board's features in the board frame (``z = 0``), mm; ``BoardView.ids`` index them.
    camera_sizes : dict of str to (2,) int
        Image ``(W, H)`` of each camera; its order is the order of the cameras in the result.
    projector_size : (2,) int, or dict of str to (2,) int
        Projector panel ``(W, H)``, px; per projector name when they differ.
    projector_model : {"opencv", "thesis"}
        The projector's lens: OpenCV's ``(k1, k2, p1, p2, k3)`` in the panel coordinates, or
        the thesis's radial model (eq. 3.34, ``docs/conventions.md``), its centre the principal
        point, written as ``projector_distortion``.
    world : str, optional
        The world frame: a camera's name (its frame, ``x`` right, ``y`` down, ``z`` forward),
        or ``"board"`` (the board's frame in the first pose). Default: the first camera.
    camera_distortion : {"radial", "none", "full"}
        The cameras' OpenCV distortion terms fitted: ``k1, k2`` (default), none, or all five
        ``(k1, k2, p1, p2, k3)``. The scanner's cameras see a narrow field (about 12°), where
        higher terms are not determined by a board and trade off with the principal point.
    projector_lens : str
        The projector's OpenCV distortion terms fitted with ``projector_model="opencv"``: a
        spec as `camera_distortion` (:func:`distortion_terms`; default all five, ``"k1"`` or
        ``"k1,k2"`` for a radial model of one or two terms). Ignored by the thesis model (ρ).
    fix_aspect_ratio, fix_principal_point : bool
        As OpenCV's ``CALIB_FIX_ASPECT_RATIO`` (``fx = fy``) and ``CALIB_FIX_PRINCIPAL_POINT``
        (at ``((W − 1) / 2, (H − 1) / 2)``), for every camera and the projector.
    outlier_sigma : float
        After a first fit, each group of points (a camera's, and the projector's measured
        through each camera) is weighted by the inverse of its noise (estimated robustly from
        the residuals: median ``|r|`` / 1.1774 per coordinate), points beyond `outlier_sigma`
        times it are dropped and the fit is repeated; ``inf`` keeps every point.

    Returns
    -------
    BoardCalibration

    Raises
    ------
    ValueError
        An unknown model or world, `outlier_sigma` not > 0 (NaN), a camera with fewer than
        :data:`MIN_VIEWS` usable views, no projector points in enough poses, or a device that
        shares no pose with the others.
    """
    terms = {}
    for option, spec in (("camera_distortion", camera_distortion),
                         ("projector_lens", projector_lens)):
        try:
            terms[option] = distortion_terms(spec)
        except ValueError as exc:
            raise ValueError(f"{option}: {str(exc).removeprefix('distortion: ')}") from exc
    camera_terms, projector_terms = terms["camera_distortion"], terms["projector_lens"]
    if isinstance(outlier_sigma, bool) or not (isinstance(outlier_sigma, int | float | np.number)
                                               and outlier_sigma > 0):
        raise ValueError(f"outlier_sigma: expected a positive number (inf keeps every point), "
                         f"got {outlier_sigma!r}")
    if projector_model not in PROJECTOR_MODELS:
        raise ValueError(f"projector_model: expected one of {PROJECTOR_MODELS}, got "
                         f"{projector_model!r}")
    obj = np.asarray(object_points, dtype=float)
    if obj.ndim != 2 or obj.shape[1] != 3 or not np.all(np.isfinite(obj)):
        raise ValueError(f"object_points: expected finite (M, 3) mm, got shape {obj.shape}")
    if np.max(np.abs(obj[:, 2])) > 1e-9 * max(1.0, np.max(np.abs(obj))):
        raise ValueError("object_points: the board's points must lie in its plane z = 0")
    names = list(camera_sizes)
    if not names:
        raise ValueError("camera_sizes: need at least one camera")
    world = names[0] if world is None else world
    if world != "board" and world not in names:
        raise ValueError(f"world: expected 'board' or a camera name {names}, got {world!r}")
    thesis = projector_model == "thesis"
    used, refused = _usable_views(views, obj, camera_sizes)
    poses = sorted({v.pose for v in used})
    projectors = list(dict.fromkeys(v.projector for v in used if v.xy_projector is not None))
    projectors = projectors or ["projector"]
    if set(projectors) & set(names) or "board" in projectors:
        raise ValueError(f"views: a projector is named like a camera or 'board' "
                         f"({projectors}); name them apart")
    panels = _projector_sizes(projector_size, projectors)

    # 1. Zhang's method per camera, then for each projector on its points of every pose
    fixed = {"fix_aspect_ratio": bool(fix_aspect_ratio),
             "fix_principal_point": bool(fix_principal_point)}
    init, T_dev_board = _initial_devices(used, obj, camera_sizes, panels, poses,
                                         camera_distortion=camera_distortion, **fixed)
    # 2. the rig
    devices = [*names, *projectors]
    T_dev_world, T_world_board = _initial_poses(
        T_dev_board, devices, poses, ("board", poses[0]) if world == "board" else world)
    # 3. bundle adjustment, then again with each group of points weighted by its noise
    free_dist = {n: list(camera_terms) for n in names}
    free_dist.update({p: [] if thesis else list(projector_terms) for p in projectors})
    sizes = {**camera_sizes, **panels}
    problem = _BundleAdjustment(devices, poses, world, free_dist, thesis, sizes=sizes,
                                projectors=projectors, **fixed)
    x0 = problem.start(init, T_dev_world, T_world_board)
    blocks = _observation_blocks(used, devices, names, obj, poses, projectors)
    x = problem.solve(x0, blocks).x
    blocks, dropped = problem.reweighted(x, blocks, outlier_sigma)
    fit = problem.solve(x, blocks)
    return _board_result(problem, fit, blocks, names, camera_sizes, panels, used,
                         refused, dropped, world, projector_model)


def _projector_sizes(projector_size, projectors: list) -> dict:
    """Each projector's panel ``(W, H)`` from one size for all or a dict by name."""
    if isinstance(projector_size, dict):
        missing = [p for p in projectors if p not in projector_size]
        if missing:
            raise ValueError(f"projector_size: no panel size for projector {missing[0]!r}")
        return {p: tuple(int(v) for v in projector_size[p]) for p in projectors}
    return {p: tuple(int(v) for v in projector_size) for p in projectors}


def _camera_views(used: list) -> list:
    """One view per (camera, pose): the first (with several projectors a pose is seen once per
    projector, and its camera points once)."""
    seen: set = set()
    out = []
    for v in used:
        if (v.camera, v.pose) not in seen:
            seen.add((v.camera, v.pose))
            out.append(v)
    return out


def _usable_views(views, obj: np.ndarray, camera_sizes: dict) -> tuple[list, list]:
    """The views with at least :data:`MIN_FEATURES` features, and those refused (warned)."""
    names = list(camera_sizes)
    used: list = []
    refused: list = []
    for v in views:
        if v.camera not in camera_sizes:
            raise ValueError(f"view of pose {v.pose}: unknown camera {v.camera!r} (has {names})")
        if np.any((v.ids < 0) | (v.ids >= len(obj))):
            raise ValueError(f"view {v.camera}/pose {v.pose}: feature ids outside "
                             f"0..{len(obj) - 1}")
        (used if len(v.ids) >= MIN_FEATURES else refused).append(v)
    for v in refused:
        warnings.warn(f"{v.camera}: pose {v.pose} has {len(v.ids)} board features (fewer than "
                      f"{MIN_FEATURES}); view skipped", stacklevel=3)
    return used, refused


def _initial_devices(used: list, obj: np.ndarray, camera_sizes: dict, panels: dict, poses,
                     *, camera_distortion: str, fix_aspect_ratio: bool,
                     fix_principal_point: bool) -> tuple[dict, dict]:
    """Zhang's method (:func:`calibrate_device`) per camera, then for each projector (`panels`:
    its panel size by name) on its board points of every pose (averaged over the cameras that
    measured them): ``(models by device, T_device_board by (device, pose))``."""
    T_dev_board: dict = {}
    init: dict = {}
    camera_views = _camera_views(used)
    for name in camera_sizes:
        mine = [v for v in camera_views if v.camera == name]
        model, T, _ = calibrate_device([obj[v.ids] for v in mine], [v.xy_camera for v in mine],
                                       camera_sizes[name], name=f"camera {name}",
                                       distortion=camera_distortion,
                                       fix_aspect_ratio=fix_aspect_ratio,
                                       fix_principal_point=fix_principal_point)
        init[name] = model
        T_dev_board.update({(name, v.pose): t for v, t in zip(mine, T, strict=True)})
    for projector, panel in panels.items():
        by_pose = projector_points_by_pose([v for v in used if v.projector == projector], poses)
        proj_obj = [obj[ids] for ids, _ in by_pose.values()]
        proj_img = [xy for _, xy in by_pose.values()]
        proj_poses = list(by_pose)
        model, T, _ = calibrate_device(proj_obj, proj_img, panel, name=projector,
                                       fix_aspect_ratio=fix_aspect_ratio,
                                       fix_principal_point=fix_principal_point)
        init[projector] = model
        T_dev_board.update({(projector, p): t for p, t in zip(proj_poses, T, strict=True)})
    return init, T_dev_board


def projector_points_by_pose(views: list, poses) -> dict:
    """The projector's board points of each pose, averaged over the cameras that measured them.

    Parameters
    ----------
    views : list of BoardView
    poses : iterable of int
        The poses to gather, in order.

    Returns
    -------
    dict of int to (ids (K,) int64, xy (K, 2) float64)
        Per pose with at least :data:`MIN_FEATURES` measured features: their board indices
        (sorted) and mean panel coordinates, px; poses with fewer are left out.
    """
    out = {}
    for pose in poses:
        ids, xy = [], []
        for v in views:
            if v.pose == pose and v.xy_projector is not None:
                ok = np.all(np.isfinite(v.xy_projector), axis=1)
                ids.append(v.ids[ok])
                xy.append(v.xy_projector[ok])
        if not ids:
            continue
        all_ids, all_xy = np.concatenate(ids), np.concatenate(xy)
        uniq, inv = np.unique(all_ids, return_inverse=True)
        if len(uniq) < MIN_FEATURES:
            continue
        mean = np.zeros((len(uniq), 2))
        np.add.at(mean, inv, all_xy)
        mean /= np.bincount(inv)[:, None]
        out[pose] = (uniq, mean)
    return out


def _observation_blocks(used: list, devices: list, names: list, obj: np.ndarray,
                        poses: list, projectors: list) -> list[dict]:
    """Per device: pose index per point, board point, measurement, camera of origin, weight."""
    pose_index = {p: i for i, p in enumerate(poses)}
    camera_views = _camera_views(used)
    blocks = []
    for dev in devices:
        if dev in projectors:
            mine = [(v, v.xy_projector) for v in used
                    if v.xy_projector is not None and v.projector == dev]
        else:
            mine = [(v, v.xy_camera) for v in camera_views if v.camera == dev]
        pi, ids, meas, cam = [], [], [], []
        for v, xy in mine:
            ok = np.all(np.isfinite(xy), axis=1)
            pi.append(np.full(ok.sum(), pose_index[v.pose]))
            ids.append(v.ids[ok])
            meas.append(xy[ok])
            cam.append(np.full(ok.sum(), names.index(v.camera)))
        blocks.append({"device": dev, "pose": np.concatenate(pi), "xyz": obj[np.concatenate(ids)],
                       "meas": np.concatenate(meas), "camera": np.concatenate(cam),
                       "weight": np.ones(sum(len(p) for p in pi))})
    return blocks


class _BundleAdjustment:
    """The joint fit of :func:`calibrate_board`: per device fx, fy, cx, cy, its free
    distortion terms (the thesis projector: ``k = ρ³``) and 6 for its pose; 6 per board pose;
    the world device's (or the first board pose's) pose is fixed."""

    def __init__(self, devices: list, poses: list, world: str, free_dist: dict,
                 thesis: bool, *, sizes: dict, projectors=("projector",),
                 fix_aspect_ratio: bool = False, fix_principal_point: bool = False) -> None:
        self.devices, self.poses, self.world = devices, poses, world
        self.projectors = list(projectors)
        self.free_dist, self.thesis = free_dist, thesis
        self.fix_aspect_ratio, self.fix_principal_point = fix_aspect_ratio, fix_principal_point
        # OpenCV's principal point without a guess (CALIB_FIX_PRINCIPAL_POINT)
        self.centre = {d: ((w - 1) / 2.0, (h - 1) / 2.0) for d, (w, h) in sizes.items()}
        self.pose_index = {p: i for i, p in enumerate(poses)}
        self.layout: dict = {}

    def start(self, init: dict, T_dev_world: dict, T_world_board: dict) -> np.ndarray:
        """The parameter vector of the initial models and poses (and its layout)."""
        x0: list = []

        def add(key, values):
            self.layout[key] = slice(sum(len(v) for v in x0),
                                     sum(len(v) for v in x0) + len(values))
            x0.append(np.asarray(values, dtype=float))

        for dev in self.devices:
            m = init[dev]
            if self.fix_aspect_ratio:
                add((dev, "f"), [m.K[1, 1]])
            else:
                add((dev, "f"), [m.K[0, 0], m.K[1, 1]])
            if not self.fix_principal_point:
                add((dev, "c"), [m.K[0, 2], m.K[1, 2]])
            if dev in self.projectors and self.thesis:
                # OpenCV's k1 on normalised panel coordinates is -ρ³ f² of eq. 3.34 to first
                # order
                add((dev, "k"), [-m.dist[0] / (m.K[0, 0] * m.K[1, 1]) * _K_SCALE])
            if self.free_dist[dev]:
                add((dev, "dist"), m.dist[self.free_dist[dev]])
            if dev != self.world:
                T = T_dev_world[dev]
                add((dev, "pose"), [*_rvec(T[:3, :3]), *T[:3, 3]])
        for pose in self.poses:
            if self.world == "board" and pose == self.poses[0]:
                continue
            T = T_world_board[pose]
            add(("board", pose), [*_rvec(T[:3, :3]), *T[:3, 3]])
        return np.concatenate(x0)

    def unpack(self, x):
        """``(R_world_board (P, 3, 3), t_world_board (P, 3), {device: (R, t)})`` of `x`."""
        layout = self.layout
        R_wb = np.repeat(np.eye(3)[None], len(self.poses), axis=0)
        t_wb = np.zeros((len(self.poses), 3))
        for pose, i in self.pose_index.items():
            if ("board", pose) in layout:
                p = x[layout["board", pose]]
                R_wb[i], t_wb[i] = _rotations(p[:3])[0], p[3:]
        dev_pose = {}
        for dev in self.devices:
            if (dev, "pose") in layout:
                p = x[layout[dev, "pose"]]
                dev_pose[dev] = (_rotations(p[:3])[0], p[3:])
            else:
                dev_pose[dev] = (np.eye(3), np.zeros(3))
        return R_wb, t_wb, dev_pose

    def intrinsics(self, x, dev) -> np.ndarray:
        """``(fx, fy, cx, cy)`` of a device in `x` (the fixed ones filled in)."""
        f = x[self.layout[dev, "f"]]
        fx, fy = (f[0], f[0]) if self.fix_aspect_ratio else (f[0], f[1])
        cx, cy = (self.centre[dev] if self.fix_principal_point
                  else tuple(x[self.layout[dev, "c"]]))
        return np.array([fx, fy, cx, cy], dtype=float)

    def distortion(self, x, dev) -> np.ndarray:
        """The device's five OpenCV distortion terms, its free ones from `x`."""
        dist = np.zeros(5)
        if self.free_dist[dev]:
            dist[self.free_dist[dev]] = x[self.layout[dev, "dist"]]
        return dist

    def projector_rho(self, x, projector: str = "projector") -> float:
        """A thesis projector's ρ (eq. 3.34)."""
        return float(np.cbrt(x[self.layout[projector, "k"]][0] / _K_SCALE))

    def block_residuals(self, x, block, R_wb, t_wb, dev_pose) -> np.ndarray:
        """Reprojection residuals ``(N, 2)`` of one device's block, px."""
        dev = block["device"]
        R, t = dev_pose[dev]
        xyz_world = np.einsum("nij,nj->ni", R_wb[block["pose"]], block["xyz"]) + t_wb[block["pose"]]
        xyz_dev = xyz_world @ R.T + t
        intr = self.intrinsics(x, dev)
        if dev in self.projectors and self.thesis:
            ideal = ideal_from_panel(block["meas"], intr[2:4], self.projector_rho(x, dev))
            return _project(intr, np.zeros(5), xyz_dev) - ideal
        return _project(intr, self.distortion(x, dev), xyz_dev) - block["meas"]

    def residuals(self, x, blocks) -> np.ndarray:
        R_wb, t_wb, dev_pose = self.unpack(x)
        return np.concatenate([(b["weight"][:, None] * self.block_residuals(x, b, R_wb, t_wb,
                                                                            dev_pose)).ravel()
                               for b in blocks])

    def solve(self, x_start, blocks):
        """Levenberg–Marquardt (MINPACK) on the dense finite-difference Jacobian: the narrow
        field makes focal length and distance nearly interchangeable, a valley along which a
        trust-region solver on the sparse Jacobian crawls; a few hundred parameters at most."""
        return least_squares(self.residuals, x_start, x_scale="jac", method="lm", ftol=1e-12,
                             xtol=1e-12, gtol=1e-12, max_nfev=100 * (len(x_start) + 1),
                             args=(blocks,))

    def parameter_std(self, fit) -> dict[str, float]:
        """Standard deviation of every fitted intrinsic and distortion parameter, and of the
        devices' poses, from the Jacobian at the solution: ``s² (JᵀJ)⁻¹`` with ``s²`` the
        weighted residuals' variance per degree of freedom (Gauss–Newton). Units: px for
        ``fx, fy, cx, cy``, none for OpenCV's distortion terms, ρ for the thesis projector,
        degrees for a pose's rotation vector ``rx, ry, rz`` and mm for ``tx, ty, tz``."""
        jac, r = np.asarray(fit.jac), np.asarray(fit.fun)
        dof = max(r.size - jac.shape[1], 1)
        std = gauss_newton_std(jac, float(r @ r) / dof)
        out: dict[str, float] = {}
        for (who, what), where in self.layout.items():
            values = std[where]
            if who == "board":
                continue
            if what == "f":
                names = ["f"] if self.fix_aspect_ratio else ["fx", "fy"]
            elif what == "c":
                names = ["cx", "cy"]
            elif what == "dist":
                names = [DISTORTION_TERMS[i] for i in self.free_dist[who]]
            elif what == "k":  # k = ρ³ K_SCALE: dρ = dk / (3 ρ² K_SCALE)
                rho = self.projector_rho(fit.x, who)
                values = values / (3 * rho**2 * _K_SCALE) if rho else values * np.inf
                names = ["rho"]
            else:  # pose
                values = np.concatenate([np.degrees(values[:3]), values[3:]])
                names = ["rx", "ry", "rz", "tx", "ty", "tz"]
            out.update({f"{who}.{n}": float(v) for n, v in zip(names, values, strict=True)})
        return out

    def reweighted(self, x, blocks: list, outlier_sigma: float) -> tuple[list, int]:
        """Each group of points (a camera's; the projector's through each camera) weighted by
        1 / its noise, estimated from the fit's residuals (the projector points through an
        oblique camera carry its detection error times the steep fringe gradient), outliers
        dropped: ``(blocks, points dropped)``."""
        R_wb, t_wb, dev_pose = self.unpack(x)
        dropped = 0
        out = list(blocks)
        for i, b in enumerate(blocks):
            r = np.hypot(*self.block_residuals(x, b, R_wb, t_wb, dev_pose).T)
            keep = np.ones(len(r), dtype=bool)
            weight = np.ones(len(r))
            for cam in np.unique(b["camera"]):
                group = b["camera"] == cam
                # per-coordinate sigma: the median of |r| of a 2D Gaussian is 1.1774 sigma
                sigma = max(float(np.median(r[group])) / 1.1774, 1e-6)
                weight[group] = 1.0 / sigma
                keep[group] = r[group] <= outlier_sigma * sigma
            dropped += int((~keep).sum())
            out[i] = {**{k: (v[keep] if isinstance(v, np.ndarray) else v) for k, v in b.items()},
                      "weight": weight[keep] / np.median(weight)}
        return out, dropped


def _rms(r: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(r**2, axis=1)))) if len(r) else float("nan")


def _board_result(problem: _BundleAdjustment, fit, blocks: list, names: list,
                  camera_sizes: dict, panels: dict, used: list, refused: list, dropped: int,
                  world: str, projector_model: str) -> BoardCalibration:
    """The :class:`BoardCalibration` of the fit (``least_squares``'s result): models, poses,
    RMS, the parameters' standard deviations."""
    x = fit.x
    R_wb, t_wb, dev_pose = problem.unpack(x)
    projectors = problem.projectors
    models = {}
    for dev in problem.devices:
        intr = problem.intrinsics(x, dev)
        K = np.array([[intr[0], 0, intr[2]], [0, intr[1], intr[3]], [0, 0, 1]])
        size = panels[dev] if dev in projectors else camera_sizes[dev]
        R, t = dev_pose[dev]
        models[dev] = Pinhole(K=K, R=R, t=t, dist=problem.distortion(x, dev), size=size)
    pdist: dict = dict.fromkeys(projectors)
    if problem.thesis:
        for dev in projectors:
            intr = problem.intrinsics(x, dev)
            pdist[dev] = ProjectorDistortion(center=(float(intr[2]), float(intr[3])),
                                             rho=problem.projector_rho(x, dev))
    res = {b["device"]: problem.block_residuals(x, b, R_wb, t_wb, dev_pose) for b in blocks}
    bmap = {b["device"]: b for b in blocks}
    # every projector's points together (one projector: its own)
    proj_res = np.concatenate([res[p] for p in projectors])
    proj_pose = np.concatenate([bmap[p]["pose"] for p in projectors])
    proj_camera = np.concatenate([bmap[p]["camera"] for p in projectors])
    pose_rms = {}
    T_board = {}
    for pose, i in problem.pose_index.items():
        pose_rms[pose] = {
            "camera": {n: _rms(res[n][bmap[n]["pose"] == i]) for n in names
                       if np.any(bmap[n]["pose"] == i)},
            "projector": _rms(proj_res[proj_pose == i]),
        }
        T_pose = np.eye(4)
        T_pose[:3, :3], T_pose[:3, 3] = R_wb[i], t_wb[i]
        T_board[pose] = T_pose
    return BoardCalibration(
        camera_names=names,
        cameras=[models[n] for n in names],
        projector=models[projectors[0]],
        projector_distortion=pdist[projectors[0]],
        board_poses=T_board,
        camera_rms_px={n: _rms(res[n]) for n in names},
        projector_rms_px=_rms(proj_res),
        projector_rms_by_camera_px={
            n: _rms(proj_res[proj_camera == j]) for j, n in enumerate(names)},
        pose_rms_px=pose_rms,
        views_used=list(dict.fromkeys((v.camera, v.pose) for v in used)),
        views_refused=list(dict.fromkeys((v.camera, v.pose) for v in refused)),
        points_dropped=dropped,
        world=world,
        projector_model=projector_model,
        parameter_std=problem.parameter_std(fit),
        n_poses=len(problem.poses),
        projector_names=list(projectors),
        projectors={p: models[p] for p in projectors},
        projector_distortions=pdist,
        projector_rms_by_projector_px={p: _rms(res[p]) for p in projectors},
    )
