"""Board views from captures: detection, decoding and the projector's board points.

Each pose of the board is a capture directory (``docs/capture-format.md``) with the phase
patterns. For every camera the frames are decoded (:func:`nail2nail.scan.decoding.decode`), the
board is
detected (:func:`nail2nail.calibration.boards.detect_board`) on the all-lit frame when the pattern
set has
one, else on the decoded mean intensity (the phase frames' mean, the thesis's C image), and the
projector coordinates of each feature are read off the decoded ``(xp, yp)`` by a local
homography (:func:`projector_points`, Moreno & Taubin 2012). The views feed
:func:`nail2nail.calibration.board.calibrate_board`.

References
----------
D. Moreno and G. Taubin, "Simple, accurate, and robust projector-camera calibration", 3DIMPVT
2012, doi:10.1109/3DIMPVT.2012.77.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field

import numpy as np

from nail2nail._interpolate import bilinear
from nail2nail._progress import progress_bar
from nail2nail.calibration.board import BoardView
from nail2nail.calibration.boards import detect_board, half_turn_ids
from nail2nail.calibration.camera_models import Pinhole
from nail2nail.calibration.markers import find_target_marks
from nail2nail.calibration.markers import mark_diameter_px as nominal_diameter
from nail2nail.calibration.target import TargetObservations
from nail2nail.io.capture import projector_captures, read_capture
from nail2nail.scan.capture import decode_camera
from nail2nail.scan.decoding import decode
from nail2nail.scan.patterns import frame_table

__all__ = ["BoardCaptures", "agree_on_half_turn", "board_views", "check_poses",
           "projector_points"]


def projector_points(xy_camera, xp, yp, mask=None, *, window_px: float = 12.0,
                     min_pixels: int = 30, min_fraction: float = 0.25,
                     outlier_sigma: float = 3.0) -> np.ndarray:
    """Projector panel coordinates of camera features on a flat surface, by local homographies.

    For each feature, a homography from camera pixels to projector coordinates is fitted by
    least squares (``cv2.findHomography``, Hartley-normalised DLT) on the validly decoded pixels
    in the square window of half-size `window_px` around it, refitted once without the pixels
    beyond `outlier_sigma` robust standard deviations, and the feature is mapped through it. A
    plane's camera-to-projector map is a homography up to the lenses' distortion, which is
    smooth over the window; the fit averages the decoding noise over hundreds of pixels and
    bridges the board's dark features, where decoding is noisy or invalid (Moreno & Taubin 2012,
    sec. 3).

    Parameters
    ----------
    xy_camera : (N, 2) float
        Features in the camera image, px (pixel-centre convention).
    xp, yp : (H, W) float
        Decoded projector coordinates (:class:`nail2nail.scan.results.Decoded`), NaN where invalid.
    mask : (H, W) bool, optional
        Pixels to use (default: where `xp` and `yp` are finite).
    window_px : float
        Half-size of the window, camera px.
    min_pixels : int
        Fewest valid pixels for a fit.
    min_fraction : float
        Fewest valid pixels as a fraction of the window's.
    outlier_sigma : float
        Refit without pixels farther from the first fit than this many robust standard
        deviations (1.4826 × median absolute residual); ``inf`` for one plain fit.

    Returns
    -------
    (N, 2) float64
        ``(xp, yp)`` per feature, panel px; NaN where the window has too few valid pixels.

    Raises
    ------
    ValueError
        Mismatched shapes or a window that is not positive.

    References
    ----------
    D. Moreno and G. Taubin, "Simple, accurate, and robust projector-camera calibration",
    3DIMPVT 2012, doi:10.1109/3DIMPVT.2012.77.

    Examples
    --------
    >>> yy, xx = np.mgrid[0:60, 0:80].astype(float)
    >>> xp, yp = 2 * xx + 5, 3 * yy - 1  # an affine map is a homography
    >>> projector_points([[40.3, 30.7]], xp, yp).round(6).tolist()
    [[85.6, 91.1]]
    """
    import cv2

    xy = np.asarray(xy_camera, dtype=float).reshape(-1, 2)
    xp = np.asarray(xp, dtype=float)
    yp = np.asarray(yp, dtype=float)
    if xp.ndim != 2 or xp.shape != yp.shape:
        raise ValueError(f"xp, yp: expected two (H, W) images of one shape, got {xp.shape} "
                         f"and {yp.shape}")
    valid = np.isfinite(xp) & np.isfinite(yp)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != xp.shape:
            raise ValueError(f"mask: expected shape {xp.shape}, got {mask.shape}")
        valid &= mask
    if not window_px > 0:
        raise ValueError(f"window_px: expected a positive number, got {window_px!r}")
    H, W = xp.shape
    h = int(np.ceil(window_px))
    need = max(min_pixels, min_fraction * (2 * h + 1) ** 2)
    out = np.full((len(xy), 2), np.nan)
    for i, (x, y) in enumerate(xy):
        cx, cy = round(x), round(y)
        c0, c1 = max(0, cx - h), min(W, cx + h + 1)
        r0, r1 = max(0, cy - h), min(H, cy + h + 1)
        if c1 <= c0 or r1 <= r0:
            continue
        ok = valid[r0:r1, c0:c1]
        if ok.sum() < need:
            continue
        rr, cc = np.nonzero(ok)
        # centred on the feature: well conditioned, and the feature maps to H's last column
        src = np.stack([cc + c0 - x, rr + r0 - y], axis=1)
        dst = np.stack([xp[r0:r1, c0:c1][ok], yp[r0:r1, c0:c1][ok]], axis=1)
        shift = dst.mean(axis=0)
        dst = dst - shift
        hom, _ = cv2.findHomography(src, dst, 0)
        if hom is not None and np.isfinite(outlier_sigma):
            pred = src @ hom[:2, :2].T + hom[:2, 2]
            pred /= (src @ hom[2, :2] + hom[2, 2])[:, None]
            r = np.hypot(*(pred - dst).T)
            keep = r <= outlier_sigma * 1.4826 * np.median(r) + 1e-12
            if keep.sum() >= need and not keep.all():
                hom, _ = cv2.findHomography(src[keep], dst[keep], 0)
        if hom is None or not np.all(np.isfinite(hom)) or hom[2, 2] == 0:
            continue
        out[i] = hom[:2, 2] / hom[2, 2] + shift
    return out


@dataclass
class BoardCaptures:
    """The board views of a set of pose captures (:func:`board_views`).

    Attributes
    ----------
    views : list of BoardView
        One per camera and pose where the board was found.
    camera_sizes : dict of str to (int, int)
        Image ``(W, H)`` per camera, in the order the cameras were first met.
    projector_size : (int, int), or dict of str to (int, int)
        Panel ``(W, H)``; with several projectors, per projector name.
    poses : list of str
        The pose directories, in pose order (``BoardView.pose`` indexes them).
    refused : list of dict
        ``{"pose", "camera", "reason"}`` of each view skipped (board not found, ...).
    """

    views: list
    camera_sizes: dict
    projector_size: tuple | dict
    poses: list
    refused: list = field(default_factory=list)


def _white_frame(pattern_set) -> int | None:
    """Index of an all-lit frame in the pattern set's frame order, if it has one."""

    for info in frame_table(pattern_set):
        if getattr(info, "kind", None) == "white":
            return int(info.index)
    return None


def check_poses(capture_dirs) -> tuple[dict[str, tuple[int, int]], tuple | dict]:
    """Check board pose captures from their manifests and first frames' headers (cheap), before
    any is decoded: each with a pattern set coding both projector directions, one projector
    panel, and one image size per camera across the poses. A pose of a rig of several
    projectors is a directory with ``projectors.json`` (:func:`board_views`); every pose must
    then name the same projectors, and each projector's captures are checked as above.

    Returns
    -------
    sizes : dict of str to (int, int)
        Image ``(width, height)`` per camera name.
    projector_size : tuple of int, or dict of str to tuple of int
        The projector panel ``(width, height)``; per projector name with several.

    Raises
    ------
    ValueError
        Naming the pose: no pattern set, one direction only, another panel or image size,
        other projectors than the first pose's.
    """
    jobs, names = _pose_captures(capture_dirs)
    sizes: dict[str, tuple[int, int]] = {}
    panels: dict[str, tuple[int, ...]] = {}
    for name in names:
        cams, panels[name] = _check_captures([path for _, n, path in jobs if n == name])
        for cam, size in cams.items():
            if sizes.setdefault(cam, size) != size:
                raise ValueError(f"projector {name}'s captures: camera {cam} has "
                                 f"{size[0]}x{size[1]} images, {sizes[cam][0]}x"
                                 f"{sizes[cam][1]} under another projector")
    return sizes, panels[names[0]] if len(names) == 1 else panels


def _pose_captures(capture_dirs) -> tuple[list[tuple[int, str, str]], list[str]]:
    """``([(pose, projector, capture directory)], projector names)`` of board pose
    directories: a capture each (projector ``"projector"``), or a capture of several
    projectors each (``projectors.json``), the same projectors in every pose."""
    if not capture_dirs:
        raise ValueError("capture_dirs: need at least one pose capture")
    jobs: list[tuple[int, str, str]] = []
    names: list[str] | None = None
    for k, d in enumerate(capture_dirs):
        layout = projector_captures(d)
        mine = [("projector", os.fspath(d))] if layout is None else [
            (name, os.fspath(path)) for name, path in layout]
        if names is None:
            names = [n for n, _ in mine]
        elif [n for n, _ in mine] != names:
            raise ValueError(f"{d}: projectors {[n for n, _ in mine]}, the first pose's are "
                             f"{names}; every pose is captured under the same projectors")
        jobs.extend((k, n, path) for n, path in mine)
    assert names is not None
    return jobs, names


def _check_captures(capture_dirs) -> tuple[dict[str, tuple[int, int]], tuple[int, ...]]:
    """:func:`check_poses` of one projector's captures."""
    sizes: dict[str, tuple[int, int]] = {}
    panel: tuple[int, ...] | None = None
    for path in capture_dirs:
        capture = read_capture(path, load=False)
        ps = capture.pattern_set
        if ps is None:
            raise ValueError(f"{path}: the manifest names no pattern set")
        if not (ps.x and ps.y):
            raise ValueError(f"{path}: the pattern set codes one projector direction; board "
                             "calibration needs both (xp and yp)")
        projector = capture.manifest.get("projector")
        size = tuple(int(v) for v in (projector.get("size", ps.panel_size)
                                      if isinstance(projector, dict) else ps.panel_size))
        if panel is not None and size != panel:
            raise ValueError(f"{path}: projector panel {size}, the first pose's is {panel}")
        panel = size
        for name in capture.camera_names:  # the first frame's header only
            h, w = capture.frame_shape(name)
            if sizes.setdefault(name, (w, h)) != (w, h):
                raise ValueError(f"{path}: camera {name} has {w}x{h} images, "
                                 f"{sizes[name][0]}x{sizes[name][1]} in an earlier pose")
    if panel is None:
        raise ValueError("capture_dirs: need at least one pose capture")
    return sizes, panel


def board_views(capture_dirs, board, *, window_px: float | None = None, edge_px: int = 3,
                decode_options: dict | None = None, progress: bool = False) -> BoardCaptures:
    """Detect the board and measure its projector points in every camera of every pose.

    Parameters
    ----------
    capture_dirs : sequence of path-like
        One directory per pose: a capture with a pattern set coding both projector directions,
        or, for a rig of several projectors, a directory with ``projectors.json`` and one such
        capture per projector (:func:`nail2nail.io.capture.projector_captures`; every pose
        with the same projectors). Each view is labelled with its projector
        (:attr:`BoardView.projector`: ``"projector"``, or the capture's name).
    board : nail2nail.calibration.boards.Board
    window_px : float, optional
        Half-size of the local homography's window (:func:`projector_points`), camera px; by
        default half the board's spacing in the image (at least 8 px).
    decode_options : dict, optional
        Passed to :func:`nail2nail.scan.decoding.decode`.
    progress : bool
        Show a progress bar on stderr (a terminal only: :mod:`nail2nail._progress`).

    Returns
    -------
    BoardCaptures

    Raises
    ------
    ValueError
        A capture that cannot be read, has no pattern set or codes one direction only, a
        camera whose image size differs between poses, captures of different projectors (one
        projector's panel changing between poses), or poses of different projectors.

    Warns
    -----
    UserWarning
        For each camera and pose where the board is not found (the view is skipped).
    """
    sizes, panels = check_poses(capture_dirs)  # before any pose is decoded
    jobs, names = _pose_captures(capture_dirs)
    views: list[BoardView] = []
    refused: list = []
    by_pose: dict[int, list[BoardView]] = {}
    for k, name, path in progress_bar(jobs, desc="poses", unit="capture", enabled=progress):
        found, rejected = _capture_board_views(path, k, name, board, window_px=window_px,
                                               edge_px=edge_px, decode_options=decode_options)
        refused.extend(rejected)
        by_pose.setdefault(k, []).extend(found)
    for k in sorted(by_pose):
        pose_views = by_pose[k]
        if board.half_turn_symmetric and len(names) > 1:
            pose_views = _agree_across_projectors(pose_views, board)
        views.extend(pose_views)
    return BoardCaptures(views=views, camera_sizes=sizes, projector_size=panels,
                         poses=[os.fspath(d) for d in capture_dirs], refused=refused)


def _capture_board_views(path: str, k: int, projector: str, board, *, window_px, edge_px,
                         decode_options) -> tuple[list[BoardView], list[dict]]:
    """:func:`board_views` of one capture (pose `k`, lit by `projector`): its views and the
    refused ones (warned)."""
    import cv2

    capture = read_capture(path, load=False)
    ps = capture.pattern_set
    assert ps is not None  # check_poses
    white = _white_frame(ps)
    object_xy = board.object_points()[:, :2]
    pose_views, refused = [], []
    for name in capture.camera_names:
        frames = capture.load_frames(name, raw=True)
        decoded = decode(frames, ps, full_scale=2**capture.bit_depth - 1,
                         **{"method": "numba", **(decode_options or {})})
        image = decoded.albedo if white is None else frames[white]
        del frames
        found = detect_board(image, board)
        if found is None:
            reason = "board not found"
            refused.append({"pose": path, "camera": name, "reason": reason})
            warnings.warn(f"{path}: camera {name}: {reason}; view skipped", stacklevel=3)
            continue
        ids, xy = found
        half = window_px
        if half is None:
            hom, _ = cv2.findHomography(object_xy[ids], xy, 0)
            # px per mm at the board's centre: the square root of the local area ratio
            centre = object_xy[ids].mean(axis=0)
            J = _homography_jacobian(hom, centre)
            half = max(8.0, 0.5 * board.spacing * np.sqrt(abs(np.linalg.det(J))))
        mask = decoded.mask
        if edge_px:
            mask = mask & ~_near_dark(decoded.albedo, edge_px)
        xy_p = projector_points(xy, decoded.xp, decoded.yp, mask, window_px=half)
        pose_views.append(BoardView(name, k, ids, xy, xy_p, projector=projector))
    if board.half_turn_symmetric:
        pose_views, unoriented = agree_on_half_turn(pose_views, board)
        for v in unoriented:
            reason = ("a board symmetric under a half turn, and no projector points to "
                      "label it like the other cameras")
            refused.append({"pose": path, "camera": v.camera, "reason": reason})
            warnings.warn(f"{path}: camera {v.camera}: {reason}; view skipped", stacklevel=3)
    return pose_views, refused


def _agree_across_projectors(views: list[BoardView], board) -> list[BoardView]:
    """One pose's views under several projectors, a half-turn symmetric board labelled as the
    first projector's view of the same camera labels it: the affine map from board to camera
    coordinates is ``A`` for one labelling and ``-A`` for the other, and one camera sees the
    board in the same place under every projector."""
    obj = board.object_points()[:, :2]

    def camera_map(v: BoardView) -> np.ndarray:
        design = np.column_stack([obj[v.ids], np.ones(len(v.ids))])
        coef, *_ = np.linalg.lstsq(design, v.xy_camera, rcond=None)
        return coef[:2].T

    reference: dict[str, np.ndarray] = {}
    out = []
    for v in views:
        m = camera_map(v)
        ref = reference.setdefault(v.camera, m)
        out.append(_half_turned(v, board) if float(np.sum(m * ref)) < 0 else v)
    return out


def _half_turned(view: BoardView, board) -> BoardView:
    """`view` with the board's labels turned by half a turn (:func:`half_turn_ids`), ids
    sorted."""
    ids = half_turn_ids(board, view.ids)
    order = np.argsort(ids)
    xy_p = None if view.xy_projector is None else view.xy_projector[order]
    return BoardView(view.camera, view.pose, ids[order], view.xy_camera[order], xy_p,
                     projector=view.projector)


def agree_on_half_turn(views: list[BoardView], board) -> tuple[list[BoardView], list]:
    """The views of one pose of a half-turn symmetric board, labelled alike.

    Each camera labels a symmetric board by its own image (:func:`detect_board`: the board's
    ``+x`` to the image's right), so two cameras that see the board from opposite sides, or a
    camera mounted upside down, can label it turned by half a turn against each other. The
    projector's decoded coordinates are the same for every camera: the affine map from board to
    projector coordinates fitted on each view's features is ``A`` with one labelling and ``-A``
    with the other. The view with the most projector points keeps its labels; a view whose map
    points the other way (``sum(A_view * A_ref) < 0``) is relabelled (:func:`half_turn_ids`).

    Parameters
    ----------
    views : list of BoardView
        One pose's views (every camera that found the board).
    board : Board
        A :attr:`~nail2nail.calibration.boards.Board.half_turn_symmetric` board.

    Returns
    -------
    views : list of BoardView
        Labelled alike (ids sorted); the first view as it was when no view has projector points.
    unoriented : list of BoardView
        The views that could not be compared (fewer than 3 projector points) while other views
        of the pose exist; left out of `views`.
    """
    obj = board.object_points()[:, :2]
    maps: list[np.ndarray | None] = []
    for v in views:
        if v.xy_projector is None:
            maps.append(None)
            continue
        ok = np.all(np.isfinite(v.xy_projector), axis=1)
        if ok.sum() < 3:
            maps.append(None)
            continue
        design = np.column_stack([obj[v.ids[ok]], np.ones(int(ok.sum()))])
        coef, *_ = np.linalg.lstsq(design, v.xy_projector[ok], rcond=None)
        maps.append(coef[:2].T)  # projector = A board + b
    usable = [i for i, m in enumerate(maps) if m is not None]
    if not usable:
        return views[:1], views[1:]
    def n_points(view: BoardView) -> int:
        xy = view.xy_projector
        return 0 if xy is None else int(np.isfinite(xy).all(axis=1).sum())

    ref = maps[max(usable, key=lambda i: n_points(views[i]))]
    out, unoriented = [], []
    for v, m in zip(views, maps, strict=True):
        if m is None:
            unoriented.append(v)
            continue
        out.append(_half_turned(v, board) if float(np.sum(m * ref)) < 0 else v)
    return out, unoriented


def _near_dark(albedo: np.ndarray, distance_px: int) -> np.ndarray:
    """Pixels within `distance_px` of one darker than half its neighbourhood's white level
    (the board's ink): there the camera's blur mixes the ink's weak fringes into the paper's
    and biases the decoded phase along its gradient."""
    from scipy import ndimage

    albedo = np.nan_to_num(np.asarray(albedo, dtype=np.float32))
    white = ndimage.maximum_filter(albedo, size=4 * distance_px + 9)
    dark = albedo < 0.5 * white
    return ndimage.binary_dilation(dark, iterations=int(distance_px))


def _homography_jacobian(hom: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """``(2, 2)`` derivative of the homography `hom` at the point `xy`."""
    x, y = xy
    w = hom[2, 0] * x + hom[2, 1] * y + hom[2, 2]
    u = (hom[0, 0] * x + hom[0, 1] * y + hom[0, 2]) / w
    v = (hom[1, 0] * x + hom[1, 1] * y + hom[1, 2]) / w
    return np.array([[hom[0, 0] - u * hom[2, 0], hom[0, 1] - u * hom[2, 1]],
                     [hom[1, 0] - v * hom[2, 0], hom[1, 1] - v * hom[2, 1]]]) / w


def sample_bilinear(image, xy) -> np.ndarray:
    """Bilinear samples of `image` ``(H, W)`` at pixel coordinates `xy` ``(N, 2)``.

    NaN where any of the four neighbours is NaN or the point is outside the image.
    """
    image = np.asarray(image, dtype=float)
    xy = np.asarray(xy, dtype=float)
    H, W = image.shape
    x, y = xy[:, 0], xy[:, 1]
    inside = (x >= 0) & (x <= W - 1) & (y >= 0) & (y <= H - 1)
    value, _, _ = bilinear(image, y, x)
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
        The camera's decode (:func:`nail2nail.scan.decoding.decode`).
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


def target_observations(
    capture,
    *,
    mark_diameter_px: float | None = None,
    progress: bool = False,
    surface_stride: int = 8,
    refine_marks: bool = False,
    **decode_options,
) -> list:
    """Decode a capture of the cylindrical target and measure its reference marks.

    For each camera: decode the frames, find and identify the marks in the albedo image
    (:func:`nail2nail.calibration.markers.find_target_marks`, sub-pixel centroids) and sample the
    decoded
    projector coordinates there (bilinear). Marks without a valid decode are dropped.

    Parameters
    ----------
    capture : Capture
        A capture of the target scene.
    mark_diameter_px : float, optional
        Approximate mark diameter in the images; by default from the nominal rig in the capture
        manifest.
    refine_marks : bool
        Re-measure each mark against a plane fitted to the surface around it
        (:func:`nail2nail.calibration.markers.find_target_marks` with ``refine=True``): unbiased
        centroids
        for a calibration that models the marks' projected discs (``target=`` of
        :func:`nail2nail.calibration.target.calibrate_from_observations`).

    Returns
    -------
    list of TargetObservations
        One per camera (world mm, camera px, projector panel px, and the grid identities in
        ``.grid``). (:func:`projector_target_observations` of this one capture.)
    """
    return projector_target_observations([capture], mark_diameter_px=mark_diameter_px,
                                         progress=progress, surface_stride=surface_stride,
                                         refine_marks=refine_marks, **decode_options)[0]


def projector_target_observations(
    captures,
    *,
    mark_diameter_px: float | None = None,
    progress: bool = False,
    surface_stride: int = 8,
    refine_marks: bool = False,
    **decode_options,
) -> list[list[TargetObservations]]:
    """:func:`target_observations` of a rig of several projectors: one capture of the still
    target per projector, the cameras the same.

    A side projector lights only part of the target, and a camera on the other side sees that
    part dark: it may not find the key mark there at all. So each camera's marks are found once,
    in the sum of its captures' mean images (the target lit from every side; the brightest
    of them at each pixel instead leaves a seam where the light changes projector, and the
    centre camera of the ±45° pair took a seam for the key mark), and every projector's decoded
    coordinates are sampled at those marks where that projector lights them (marks it does not
    light are left out of its set).

    Parameters
    ----------
    captures : sequence of Capture
        Per projector, its capture of the target (same cameras, same order).
    mark_diameter_px, progress, surface_stride, refine_marks, **decode_options
        As :func:`target_observations`.

    Returns
    -------
    list of list of TargetObservations
        Per projector, one per camera (``sets[k][i]``: camera ``i`` under projector ``k``):
        the marks' world points (mm), their centroids (camera px, pixel-centre convention)
        and projector ``k``'s panel coordinates there (panel px), the grid identities, and
        the surface samples between the marks; a camera's marks are the same in every set
        but for those the projector does not light.

    Raises
    ------
    ValueError
        For captures whose cameras differ, or a camera whose marks cannot be identified even
        lit by every projector.
    """
    captures = list(captures)
    if not captures:
        raise ValueError("captures: need at least one projector's capture")
    names = list(captures[0].camera_names)
    for capture in captures[1:]:
        if list(capture.camera_names) != names:
            raise ValueError(f"{capture.path}: cameras {list(capture.camera_names)}, but "
                             f"{captures[0].path} has {names}: every projector's capture must "
                             "have the same cameras")
    sets: list[list[TargetObservations]] = [[] for _ in captures]
    for name in progress_bar(names, desc="target", unit="camera", enabled=progress):
        decoded = [decode_camera(capture, name, **decode_options) for capture in captures]
        diameter = mark_diameter_px
        if diameter is None:
            if "rig" not in captures[0].manifest:
                raise ValueError(
                    f"{captures[0].path}: no nominal rig in the manifest to predict the marks' "
                    "size from; give the mark diameter in px (mark_diameter_px=, "
                    "`nail2nail calibrate --mark-diameter-px`)")
            diameter = nominal_diameter(_nominal_camera(captures[0], name))
        lit = decoded[0].albedo if len(decoded) == 1 else \
            np.sum([np.nan_to_num(d.albedo) for d in decoded], axis=0)
        try:
            marks = find_target_marks(lit, mark_diameter_px=diameter, refine=refine_marks)
        except ValueError as exc:  # "image: …": say which camera of which capture
            where = (f"{captures[0].path}: camera {name!r}" if len(captures) == 1 else
                     f"{', '.join(str(c.path) for c in captures)}: camera {name!r}, lit by "
                     "every projector")
            raise ValueError(f"{where}: {str(exc).removeprefix('image: ')}") from exc
        for k, d in enumerate(decoded):
            xp = sample_bilinear(d.xp, marks.xy)
            yp = sample_bilinear(d.yp, marks.xy)
            ok = np.isfinite(xp) & np.isfinite(yp)
            H, W = d.shape
            surf_xy, surf_panel = surface_samples(d, marks.xy, diameter, stride=surface_stride)
            sets[k].append(TargetObservations(
                name, marks.xyz_world[ok], marks.xy[ok], np.column_stack([xp[ok], yp[ok]]),
                size=(W, H), grid=marks.grid[ok], surface_xy_camera=surf_xy,
                surface_xy_projector=surf_panel))
    return sets


def _nominal_camera(capture, name: str) -> Pinhole:
    """Camera `name` of the nominal rig in a virtual capture's manifest, as a pinhole."""
    where = f"{capture.path}: the manifest's rig"
    cameras = capture.manifest["rig"].get("cameras")
    for i, camera in enumerate(cameras if isinstance(cameras, list) else []):
        if isinstance(camera, dict) and camera.get("name", f"cam{i}") == name:
            try:
                return Pinhole.from_dict(camera)
            except (TypeError, ValueError, KeyError) as exc:
                raise ValueError(f"{where}: camera {name!r}: {exc}") from exc
    raise ValueError(f"{where}: no camera {name!r}")
