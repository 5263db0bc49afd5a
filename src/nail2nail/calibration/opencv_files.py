"""Calibrations in OpenCV ``FileStorage`` files (XML, YAML): import into and export from a rig.

Three layouts (``docs/capture-format.md``, "OpenCV calibration files"):

``slstudio``
    SLStudio's ``calibration.xml``: one camera and the projector, ``Kc kc Kp kp Rp Tp
    frameWidth frameHeight screenResX screenResY``. ``Rp``, ``Tp`` are those of
    ``cv::stereoCalibrate`` from the camera to the projector: ``x_proj = Rp x_cam + Tp``, mm.
``stereo``
    OpenCV's ``stereo_calib`` sample (``intrinsics.yml`` and ``extrinsics.yml``, one file or
    both): ``M1 D1 M2 D2 R T`` with the projector as the second device
    (``x_proj = R x_cam + T``), and the image sizes ``size1``, ``size2`` (``[W, H]``) when
    written by nail2nail, else given as options.
``nail2nail``
    Several cameras and the projector, world frame as stored::

        format: "nail2nail-opencv-rig"
        version: 1
        cameras:                 # a sequence of maps
          - { name: cam0, K: 3x3, dist: 1x5, R: 3x3, t: 3x1, size: [W, H] (1x2 int) }
          ...
        projector: { K, dist, R, t, size }   # shared by every camera, unless a camera's map
                                             # holds its own "projector" map

Every model is an OpenCV pinhole model (:class:`nail2nail.calibration.camera_models.Pinhole`,
``x_cam = R x_world + t``, distortion ``(k1, k2, p1, p2, k3)``). For the one-camera layouts the
world frame is the camera's, and the camera is named ``cam0``. Distortion vectors of 4 or 5
coefficients are read as they are; longer ones (8, 12, 14: the rational, thin-prism and tilt
models) only when the coefficients beyond ``k3`` are zero. Rotations stored as float32 are
re-orthonormalised with a warning (:func:`nail2nail.calibration.camera_models.nearest_rotation`).

Export writes the same keys in float64 (the ``FileStorage`` text holds every double exactly:
export then import gives the same rig bit for bit). A DLT matrix is decomposed into ``K``,
``R``, ``t`` (:func:`nail2nail.calibration.camera_models.pinhole_from_dlt`, no distortion) with a
warning.
The thesis's projector radial distortion (``projector_distortion``: centre and ρ) has no OpenCV
form: export refuses a calibration that has one.
"""

from __future__ import annotations

import contextlib
import os
import warnings
from pathlib import Path

import numpy as np

from nail2nail.calibration.camera_models import Pinhole, pinhole_from_dlt
from nail2nail.calibration.files import CameraCalibration, RigCalibration
from nail2nail.io._atomic import atomic_path
from nail2nail.scan.patterns import PANEL_SIZE

__all__ = [
    "LAYOUTS",
    "RIG_FORMAT",
    "detect_layout",
    "read_opencv_calibration",
    "write_opencv_calibration",
]

#: The layouts of :func:`read_opencv_calibration` and :func:`write_opencv_calibration`.
LAYOUTS = ("slstudio", "stereo", "nail2nail")
#: ``format`` of the nail2nail multi-camera layout.
RIG_FORMAT = "nail2nail-opencv-rig"

_SUFFIXES = (".xml", ".yml", ".yaml", ".json")
_DIST_SIZES = (4, 5, 8, 12, 14)
_DIST_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tx",
               "ty")
_SLSTUDIO_KEYS = ("Kc", "kc", "Kp", "kp", "Rp", "Tp")
_STEREO_KEYS = ("M1", "D1", "M2", "D2", "R", "T")


@contextlib.contextmanager
def _quiet_opencv():
    """OpenCV's own error log (a line on stderr) silenced: errors are raised as ours."""
    import cv2

    logging = getattr(getattr(cv2, "utils", None), "logging", None)
    if logging is None:  # pragma: no cover - every supported OpenCV has it
        yield
        return
    level = logging.getLogLevel()
    logging.setLogLevel(logging.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        logging.setLogLevel(level)


class _Storage:
    """The top-level nodes of one or several ``FileStorage`` files (a key in two files must
    hold the same value), with errors naming the file and the key."""

    def __init__(self, paths):
        import cv2

        self.paths = [Path(p) for p in paths]
        self.where = ", ".join(str(p) for p in self.paths)
        self.nodes: dict = {}
        self.origin: dict = {}
        self._storages = []
        for path in self.paths:
            try:
                text = path.read_text(encoding="utf-8")
            except UnicodeDecodeError as exc:
                raise ValueError(f"{path}: not an OpenCV FileStorage file (not UTF-8 text: "
                                 f"{exc.reason})") from exc
            except OSError as exc:
                raise ValueError(f"{path}: cannot read ({exc.strerror or exc})") from exc
            if not text.strip():
                raise ValueError(f"{path}: not an OpenCV FileStorage file (empty)")
            try:
                with _quiet_opencv():
                    fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
            except (cv2.error, SystemError) as exc:
                cause = exc.__cause__ or exc.__context__ or exc
                detail = str(cause).strip().splitlines()
                raise ValueError(f"{path}: not a valid OpenCV FileStorage file (XML or YAML: "
                                 f"{detail[-1] if detail else type(cause).__name__})") from exc
            if not fs.isOpened():
                raise ValueError(f"{path}: not a valid OpenCV FileStorage file")
            self._storages.append(fs)
            root = fs.root()
            for key in root.keys():
                node = root.getNode(key)
                if key in self.nodes and not _same(self.nodes[key], node):
                    raise ValueError(f"{path}: key {key!r} differs from its value in "
                                     f"{self.origin[key]}")
                self.nodes.setdefault(key, node)
                self.origin.setdefault(key, path)

    def keys(self) -> list[str]:
        return list(self.nodes)

    def file_of(self, key: str) -> str:
        return str(self.origin.get(key, self.where))

    def node(self, key: str):
        if key not in self.nodes:
            raise ValueError(f"{self.where}: missing key {key!r}")
        return self.nodes[key]


def _same(a, b) -> bool:
    va, vb = _values(a), _values(b)
    if va is None or vb is None:
        return False
    return va.shape == vb.shape and np.array_equal(va, vb)


def _values(node) -> np.ndarray | None:
    """A node's numbers: a matrix, a sequence of numbers or one number; None otherwise."""
    if node is None or node.empty():
        return None
    if node.isMap():
        mat = node.mat()
        return None if mat is None else np.asarray(mat)
    if node.isSeq():
        items = [node.at(i) for i in range(node.size())]
        if not items or not all(i.isReal() or i.isInt() for i in items):
            return None
        return np.array([i.real() for i in items])
    if node.isReal() or node.isInt():
        return np.array(node.real())
    return None


def _array(node, where: str, key: str, sizes: tuple[int, ...], what: str) -> np.ndarray:
    """The float64 numbers of `node`, flattened, of one of `sizes`; ValueError otherwise."""
    values = _values(node)
    if values is None:
        raise ValueError(f"{where}: {key}: expected {what} (an OpenCV matrix or a sequence of "
                         "numbers)")
    if values.dtype.kind not in "fiu":
        raise ValueError(f"{where}: {key}: expected numbers, got {values.dtype}")
    flat = values.astype(np.float64).ravel()
    if flat.size not in sizes:
        raise ValueError(f"{where}: {key}: expected {what}, got shape {values.shape}")
    if not np.all(np.isfinite(flat)):
        raise ValueError(f"{where}: {key}: contains NaN or infinity")
    return flat


def _matrix3(node, where, key) -> np.ndarray:
    return _array(node, where, key, (9,), "a 3x3 matrix").reshape(3, 3)


def _vector3(node, where, key) -> np.ndarray:
    return _array(node, where, key, (3,), "3 numbers (a 3x1 translation, mm)")


def _distortion(node, where, key) -> np.ndarray:
    dist = _array(node, where, key, _DIST_SIZES, "4, 5, 8, 12 or 14 distortion coefficients")
    beyond = {name: float(v) for name, v in zip(_DIST_NAMES[5:], dist[5:], strict=False) if v}
    if beyond:
        listed = ", ".join(f"{k}={v:.6g}" for k, v in beyond.items())
        raise ValueError(f"{where}: {key}: coefficients beyond k3 must be zero (nail2nail's "
                         f"pinhole model is (k1, k2, p1, p2, k3); the rational, thin-prism and "
                         f"tilt models are not supported), got {listed}")
    return np.pad(dist[:5], (0, 5 - min(dist.size, 5)))


def _size(node, where, key) -> tuple[int, int]:
    values = _array(node, where, key, (2,), "[W, H] in pixels")
    if not np.all((values == np.round(values)) & (values > 0) & (values < 2**31)):
        raise ValueError(f"{where}: {key}: expected [W, H], two positive integers, got "
                         f"{values.tolist()}")
    return int(values[0]), int(values[1])


def _int(node, where, key) -> int:
    values = _array(node, where, key, (1,), "a positive integer")
    value = values[0]
    if not (value == round(value) and 0 < value < 2**31):
        raise ValueError(f"{where}: {key}: expected a positive integer, got {value:g}")
    return int(value)


def _pinhole(where: str, keys: str, **fields) -> Pinhole:
    """A :class:`Pinhole` of read fields; its warnings (a float32 rotation) and errors name
    the file and the keys."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            model = Pinhole(**fields)
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{where}: {keys}: {exc}") from exc
    for w in caught:
        warnings.warn(f"{where}: {keys}: {w.message}", w.category, stacklevel=4)
    return model


def _check_size_option(where, key, stored, option, flag) -> tuple[int, int]:
    if stored is None and option is None:
        raise ValueError(f"{where}: no image size (key {key!r}); give {flag} W H")
    if stored is not None and option is not None and tuple(option) != tuple(stored):
        raise ValueError(f"{where}: {key} is {stored[0]} x {stored[1]} but {flag} gives "
                         f"{option[0]} x {option[1]}")
    return tuple(stored if stored is not None else option)


def detect_layout(keys) -> str:
    """The layout of a file with these top-level keys; ``ValueError`` if none fits.

    Examples
    --------
    >>> detect_layout(["Kc", "kc", "Kp", "kp", "Rp", "Tp", "frameWidth"])
    'slstudio'
    >>> detect_layout(["M1", "D1", "M2", "D2"])
    'stereo'
    """
    keys = set(keys)
    if "cameras" in keys or "format" in keys:
        return "nail2nail"
    if {"Kc", "Kp"} <= keys:
        return "slstudio"
    if {"M1", "M2"} <= keys or {"R", "T"} <= keys:
        return "stereo"
    raise ValueError(
        f"unknown layout (top-level keys {sorted(keys)}): expected SLStudio's "
        f"{' '.join(_SLSTUDIO_KEYS)}, OpenCV's stereo {' '.join(_STEREO_KEYS)} or nail2nail's "
        "'cameras' and 'projector'")


def read_opencv_calibration(
    paths,
    *,
    layout: str = "auto",
    camera_size=None,
    projector_size=None,
    allow_mirrored: bool = False,
) -> RigCalibration:
    """Read an OpenCV ``FileStorage`` calibration (module docstring) into a rig calibration.

    Parameters
    ----------
    paths : path-like or sequence of path-like
        One file, or several whose top-level keys together make the layout (OpenCV's
        ``stereo_calib`` writes ``intrinsics.yml`` and ``extrinsics.yml``).
    layout : {"auto", "slstudio", "stereo", "nail2nail"}
        ``"auto"`` picks it from the keys (:func:`detect_layout`).
    camera_size, projector_size : (int, int), optional
        ``(W, H)`` in pixels where the file holds none (``stereo``: ``size1``, ``size2``);
        a size that contradicts the file's is refused.
    allow_mirrored : bool
        Accept a mirrored camera or projector
        (:func:`nail2nail.calibration.files.check_handedness`).

    Returns
    -------
    RigCalibration
        Pinhole models; for ``slstudio`` and ``stereo`` one camera ``cam0`` whose frame is
        the world frame (``R = I``, ``t = 0``) and the projector in it; ``extra`` records the
        source file(s), the layout and the world frame.

    Raises
    ------
    ValueError
        One line naming the file and the key: an unreadable or invalid file, a missing key,
        a wrong shape, a non-zero coefficient beyond ``k3``, a matrix that is not a rotation
        (beyond float32 rounding), a missing size, a mirrored or rank-deficient model.

    Warns
    -----
    UserWarning
        A rotation re-orthonormalised (stored as float32), naming the file and the key.
    """
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    paths = list(paths)
    if not paths:
        raise ValueError("paths: expected at least one calibration file")
    if layout not in ("auto", *LAYOUTS):
        raise ValueError(f"layout: expected 'auto' or one of {LAYOUTS}, got {layout!r}")
    storage = _Storage(paths)
    if layout == "auto":
        try:
            layout = detect_layout(storage.keys())
        except ValueError as exc:
            raise ValueError(f"{storage.where}: {exc}") from exc
    if layout == "nail2nail":
        rig = _read_rig(storage, camera_size, projector_size)
    else:
        rig = _read_one_camera(storage, layout, camera_size, projector_size)
    rig.extra = {"source": storage.where, "source_layout": layout, **rig.extra}
    # the checks of a calibration file (rank, handedness), naming the source
    return RigCalibration.from_dict(rig.to_dict(), where=storage.where,
                                    allow_mirrored=allow_mirrored)


def _read_one_camera(storage: _Storage, layout: str, camera_size, projector_size):
    names = dict(zip(("K1", "D1", "K2", "D2", "R", "T"),
                     _SLSTUDIO_KEYS if layout == "slstudio" else _STEREO_KEYS, strict=True))
    where = storage.file_of
    values = {}
    for role, key in names.items():
        node = storage.node(key)
        if role.startswith("K"):
            values[role] = _matrix3(node, where(key), key)
        elif role.startswith("D"):
            values[role] = _distortion(node, where(key), key)
        elif role == "R":
            values[role] = _matrix3(node, where(key), key)
        else:
            values[role] = _vector3(node, where(key), key)
    if layout == "slstudio":
        stored_camera = stored_projector = None
        if "frameWidth" in storage.nodes or "frameHeight" in storage.nodes:
            stored_camera = (_int(storage.node("frameWidth"), where("frameWidth"), "frameWidth"),
                             _int(storage.node("frameHeight"), where("frameHeight"),
                                  "frameHeight"))
        if "screenResX" in storage.nodes or "screenResY" in storage.nodes:
            stored_projector = (_int(storage.node("screenResX"), where("screenResX"),
                                     "screenResX"),
                                _int(storage.node("screenResY"), where("screenResY"),
                                     "screenResY"))
        size_keys = ("frameWidth", "screenResX")
    else:
        stored_camera = (_size(storage.node("size1"), where("size1"), "size1")
                         if "size1" in storage.nodes else None)
        stored_projector = (_size(storage.node("size2"), where("size2"), "size2")
                            if "size2" in storage.nodes else None)
        size_keys = ("size1", "size2")
    cam_size = _check_size_option(storage.where, size_keys[0], stored_camera, camera_size,
                                  "--camera-size")
    proj_size = _check_size_option(storage.where, size_keys[1], stored_projector,
                                   projector_size, "--projector-size")
    camera = _pinhole(where(names["K1"]), f"{names['K1']}, {names['D1']}", K=values["K1"],
                      R=np.eye(3), t=np.zeros(3), dist=values["D1"], size=cam_size)
    projector = _pinhole(where(names["R"]),
                         f"{names['K2']}, {names['D2']}, {names['R']}, {names['T']}",
                         K=values["K2"], R=values["R"], t=values["T"], dist=values["D2"],
                         size=proj_size)
    return RigCalibration(cameras=[CameraCalibration("cam0", camera, projector, cam_size)],
                          extra={"world_frame": "cam0"})


def _model_map(storage: _Storage, node, where: str, label: str, size_option, flag) -> Pinhole:
    if node is None or node.empty() or not node.isMap():
        raise ValueError(f"{where}: {label}: expected a map with K, dist, R, t, size")
    fields = {}
    for key in ("K", "dist", "R", "t"):
        sub = node.getNode(key)
        if sub.empty():
            raise ValueError(f"{where}: missing key '{label}.{key}'")
        name = f"{label}.{key}"
        fields[key] = (_matrix3(sub, where, name) if key in ("K", "R")
                       else _distortion(sub, where, name) if key == "dist"
                       else _vector3(sub, where, name))
    sub = node.getNode("size")
    stored = None if sub.empty() else _size(sub, where, f"{label}.size")
    size = _check_size_option(where, f"{label}.size", stored, size_option, flag)
    return _pinhole(where, label, size=size, **fields)


def _read_rig(storage: _Storage, camera_size, projector_size) -> RigCalibration:
    where = storage.file_of("cameras")
    if "format" in storage.nodes:
        fmt = storage.node("format")
        if not fmt.isString() or fmt.string() != RIG_FORMAT:
            raise ValueError(f"{storage.file_of('format')}: format: expected {RIG_FORMAT!r}")
    if "version" in storage.nodes:
        version = _values(storage.node("version"))
        if version is None or version.shape != () or float(version) != 1:
            raise ValueError(f"{storage.file_of('version')}: version: expected 1 (written by a "
                             "newer nail2nail?)")
    cams = storage.node("cameras")
    if not cams.isSeq() or cams.size() == 0:
        raise ValueError(f"{where}: cameras: expected a non-empty sequence of maps")
    shared = storage.nodes.get("projector")
    cameras = []
    for i in range(cams.size()):
        node = cams.at(i)
        label = f"cameras[{i}]"
        if not node.isMap():
            raise ValueError(f"{where}: {label}: expected a map with name, K, dist, R, t, size")
        name_node = node.getNode("name")
        if name_node.empty() or not name_node.isString():
            raise ValueError(f"{where}: missing key '{label}.name' (a string)")
        camera = _model_map(storage, node, where, label, camera_size, "--camera-size")
        own = node.getNode("projector")
        if not own.empty():
            projector = _model_map(storage, own, where, f"{label}.projector", projector_size,
                                   "--projector-size")
        elif shared is not None:
            projector = _model_map(storage, shared, storage.file_of("projector"), "projector",
                                   projector_size, "--projector-size")
        else:
            raise ValueError(f"{storage.where}: missing key 'projector'")
        cameras.append(CameraCalibration(name_node.string(), camera, projector, camera.size))
    return RigCalibration(cameras=cameras)


# -- export ------------------------------------------------------------------------------------

def _as_pinhole(model, size, what: str, notes: list[str]) -> Pinhole:
    if isinstance(model, Pinhole):
        return model
    notes.append(f"{what}: DLT matrix decomposed into K, R, t (pinhole_from_dlt, RQ "
                 "decomposition; no distortion)")
    return pinhole_from_dlt(model, size=size)


def _write_model(fs, model: Pinhole) -> None:
    fs.write("K", model.K)
    fs.write("dist", model.dist.reshape(1, 5))
    fs.write("R", model.R)
    fs.write("t", model.t.reshape(3, 1))
    fs.write("size", np.array([model.size], np.int32))


def _same_model(a: Pinhole, b: Pinhole) -> bool:
    return all(np.array_equal(getattr(a, k), getattr(b, k)) for k in ("K", "dist", "R", "t")) \
        and tuple(a.size) == tuple(b.size)


def write_opencv_calibration(
    path: str | os.PathLike,
    calibration: RigCalibration,
    *,
    layout: str = "nail2nail",
    camera: str | None = None,
    projector_size=None,
) -> list[str]:
    """Write `calibration` as an OpenCV ``FileStorage`` file (atomically).

    Parameters
    ----------
    path : path-like
        ``.xml``, ``.yml``, ``.yaml`` (or ``.json``): the suffix picks the format.
    calibration : RigCalibration
    layout : {"nail2nail", "slstudio", "stereo"}
        The module docstring's layouts. ``slstudio`` and ``stereo`` hold one camera
        (`camera`) in its own frame: the projector's pose is re-expressed relative to it
        (``R_p R_cᵀ``, ``t_p − R_p R_cᵀ t_c``) when the camera is not at the world origin.
    camera : str, optional
        The camera of a one-camera layout; needed when the calibration has several.
    projector_size : (int, int), optional
        Panel ``(W, H)`` of a DLT projector (by default 1280 × 1040, with a note).

    Returns
    -------
    list of str
        Notes on what was converted (a DLT matrix decomposed, a pose re-expressed), each also
        issued as a ``UserWarning``.

    Raises
    ------
    ValueError
        An unknown suffix or layout; a projector radial distortion (no OpenCV form); a
        one-camera layout without `camera` for a rig of several, or an unknown camera.
    """
    import cv2

    path = Path(path)
    if path.suffix.lower() not in _SUFFIXES:
        raise ValueError(f"{path}: expected a .xml, .yml or .yaml file name (the suffix picks "
                         "the FileStorage format)")
    if layout not in LAYOUTS:
        raise ValueError(f"layout: expected one of {LAYOUTS}, got {layout!r}")
    if calibration.projector_distortion is not None:
        raise ValueError(
            "calibration: its projector radial distortion (thesis eq. 3.34: centre "
            f"{list(calibration.projector_distortion.center)}, rho "
            f"{calibration.projector_distortion.rho}) has no OpenCV form; export "
            "refused (pre-distort the patterns with its look-up table and recalibrate without "
            "it, or keep the nail2nail JSON file)")
    notes: list[str] = []
    # the thesis's panel for a DLT projector when none is given (docs/conventions.md)
    panel = PANEL_SIZE if projector_size is None else tuple(int(v) for v in projector_size)
    models = []
    guessed = False  # a DLT projector's panel size: the default, said once
    for cam in calibration.cameras:
        cam_size = cam.size or (cam.camera.size if isinstance(cam.camera, Pinhole) else None)
        if cam_size is None:
            raise ValueError(f"calibration: camera {cam.name!r} is a DLT matrix without an "
                             "image size: the pinhole model needs one")
        if not isinstance(cam.projector, Pinhole) and projector_size is None and not guessed:
            guessed = True
            notes.append(f"projector size not known for a DLT projector: {panel[0]} x "
                         f"{panel[1]} written (give the projector size)")
        models.append((cam.name,
                       _as_pinhole(cam.camera, cam_size, f"camera {cam.name!r}", notes),
                       _as_pinhole(cam.projector, panel, f"the projector of {cam.name!r}",
                                   notes)))
    fs = cv2.FileStorage(path.suffix, cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    if layout == "nail2nail":
        fs.write("format", RIG_FORMAT)
        fs.write("version", 1)
        shared = all(_same_model(p, models[0][2]) for _, _, p in models)
        fs.startWriteStruct("cameras", cv2.FileNode_SEQ)
        for name, cam_model, proj_model in models:
            fs.startWriteStruct("", cv2.FileNode_MAP)
            fs.write("name", name)
            _write_model(fs, cam_model)
            if not shared:
                fs.startWriteStruct("projector", cv2.FileNode_MAP)
                _write_model(fs, proj_model)
                fs.endWriteStruct()
            fs.endWriteStruct()
        fs.endWriteStruct()
        if shared:
            fs.startWriteStruct("projector", cv2.FileNode_MAP)
            _write_model(fs, models[0][2])
            fs.endWriteStruct()
    else:
        names = [m[0] for m in models]
        if camera is None:
            if len(models) > 1:
                raise ValueError(f"layout {layout!r} holds one camera: give the camera "
                                 f"(one of {', '.join(names)})")
            camera = names[0]
        if camera not in names:
            raise ValueError(f"camera: expected one of {', '.join(names)}, got {camera!r}")
        _, cam_model, proj_model = models[names.index(camera)]
        R, t = proj_model.R, proj_model.t
        if not (np.array_equal(cam_model.R, np.eye(3)) and not np.any(cam_model.t)):
            R = proj_model.R @ cam_model.R.T
            t = proj_model.t - R @ cam_model.t
            notes.append(f"the projector's pose re-expressed in camera {camera!r}'s frame "
                         f"(the {layout} layout's world frame)")
        keys = _SLSTUDIO_KEYS if layout == "slstudio" else _STEREO_KEYS
        for key, value in zip(keys, (cam_model.K, cam_model.dist.reshape(1, 5), proj_model.K,
                                     proj_model.dist.reshape(1, 5), R, t.reshape(3, 1)),
                              strict=True):
            fs.write(key, np.asarray(value, dtype=np.float64))
        if layout == "slstudio":
            for key, pixels in zip(("frameWidth", "frameHeight", "screenResX", "screenResY"),
                                   (*cam_model.size, *proj_model.size), strict=True):
                fs.write(key, int(pixels))
        else:
            fs.write("size1", np.array([cam_model.size], np.int32))
            fs.write("size2", np.array([proj_model.size], np.int32))
    text = fs.releaseAndGetString()
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    for note in notes:
        warnings.warn(f"{path}: {note}", UserWarning, stacklevel=2)
    return notes
