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

A file is checked before OpenCV parses it, and that same text is parsed
(``FILE_STORAGE_MEMORY``): a regular file of at most :data:`MAX_FILE_BYTES`, nested at most
:data:`MAX_NESTING` levels (OpenCV's parsers recurse per level and crashed on deep files), no
integer beyond 32 bits where one is read (OpenCV wraps it silently), matrix headers within
:data:`MAX_MATRIX_ELEMENTS` and matching their data; the values read are checked against the
physical ranges of :func:`nail2nail.calibration.files.check_pinhole_values`.

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
import re
import stat
import warnings
from pathlib import Path

import numpy as np

from nail2nail._validation import file_kind
from nail2nail.calibration.camera_models import Pinhole, pinhole_from_dlt
from nail2nail.calibration.files import (
    MAX_SIZE_PX,
    CameraCalibration,
    RigCalibration,
    check_pinhole_values,
    check_size,
)
from nail2nail.io._atomic import atomic_path, check_output_file
from nail2nail.scan.patterns import PANEL_SIZE

__all__ = [
    "LAYOUTS",
    "MAX_FILE_BYTES",
    "MAX_MATRIX_ELEMENTS",
    "MAX_NESTING",
    "RIG_FORMAT",
    "detect_layout",
    "read_opencv_calibration",
    "write_opencv_calibration",
]

#: The layouts of :func:`read_opencv_calibration` and :func:`write_opencv_calibration`.
LAYOUTS = ("slstudio", "stereo", "nail2nail")
#: ``format`` of the nail2nail multi-camera layout.
RIG_FORMAT = "nail2nail-opencv-rig"

#: Largest calibration file read, bytes. A calibration of these layouts is a few kilobytes
#: (SLStudio's calibration.xml and stereo_calib's files about 1 to 3 KB, a rig of several
#: cameras under 20 KB); 1 MiB leaves room for other keys beside them and bounds the memory and
#: the time of the checks below (about 1 s at worst: a 300 MB file of spaces, /dev/zero).
MAX_FILE_BYTES = 2**20
#: Deepest nesting of maps, sequences and XML elements read. A calibration is 3 to 7 levels
#: deep (cameras, a camera's map, its projector map, a matrix map, its data); OpenCV's parsers
#: recurse once per level and a file 100 000 levels deep killed the process (segmentation
#: fault), so deeper files are refused before OpenCV sees them.
MAX_NESTING = 32
#: Largest matrix read, rows × cols × channels. The largest of a calibration has 14 numbers
#: (a distortion vector); 10⁶ (8 MB of doubles) bounds what OpenCV allocates for a matrix
#: header, checked before it allocates (a header claiming 100 000 × 100 000 doubles asked for
#: 80 GB).
MAX_MATRIX_ELEMENTS = 1_000_000
#: OpenCV's matrix element types (``dt``), with an optional channel count first (``"3d"``).
_DT = re.compile(r"\s*(\d*)\s*([ucwsifdh])\s*")
#: OpenCV reads integers as 32-bit ``int``: larger ones wrap around silently (a width of
#: 10000000000 px was read as 1410065408, 4294967552 as 256).
_INT32 = 2**31
#: The keys whose integers nail2nail reads (sizes, matrix headers and data, version): a key
#: and its value in YAML/JSON (a flow sequence up to its closing bracket) and in XML.
_INT_KEYS = ("frameWidth|frameHeight|screenResX|screenResY|size|size1|size2|version|rows|cols|"
             "sizes|data")
_YAML_INT_VALUE = re.compile(
    rf"(?:^|[\s{{,])[\"']?({_INT_KEYS})[\"']?[ \t]*:[ \t]*(\[[^\]]*\]?|[^\n#]*)", re.M)
_XML_INT_VALUE = re.compile(rf"<({_INT_KEYS})(?:\s[^<>]*)?>([^<]*)")
_BIG_INT = re.compile(r"(?<![\w.])[-+]?\d{10,}(?![\w.])")
#: A YAML (or JSON) line's indentation with its sequence dashes, a quoted scalar, a comment,
#: a flow bracket.
_YAML_TOKEN = re.compile(r"""
    (?P<line>^[ \t]*(?:-[ \t]+)*(?=[^ \t\n]))
    | "(?:[^"\\\n]|\\.)*"? | '[^'\n]*'? | \#[^\n]*
    | (?P<open>[\[{]) | (?P<close>[\]}])
""", re.M | re.X)

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


def _read_text(path: Path) -> str:
    """The text of the calibration file `path`: a regular file (checked before it is opened,
    so a FIFO or a device never blocks or streams), at most :data:`MAX_FILE_BYTES`, UTF-8
    without NUL characters, not blank; ``ValueError`` naming `path` otherwise."""
    try:
        info = os.stat(path)
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    too_big = (f"{path}: larger than {MAX_FILE_BYTES // 2**20} MiB, not a calibration file "
               "(one is a few kilobytes)")
    if not stat.S_ISREG(info.st_mode):
        raise ValueError(f"{path}: not a regular file ({file_kind(info.st_mode)}); give the "
                         "calibration file itself")
    if info.st_size > MAX_FILE_BYTES:
        raise ValueError(too_big)
    try:  # non-blocking: a FIFO put in its place since the check does not hang the open
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
        with os.fdopen(fd, "rb") as fh:
            if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
                raise ValueError(f"{path}: not a regular file; give the calibration file "
                                 "itself")
            data = fh.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    if len(data) > MAX_FILE_BYTES:
        raise ValueError(too_big)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not an OpenCV FileStorage file (not UTF-8 text: "
                         f"{exc.reason})") from exc
    if "\0" in text:
        raise ValueError(f"{path}: not an OpenCV FileStorage file (binary data: a NUL "
                         f"character at byte {data.index(0)})")
    if not text.strip():
        raise ValueError(f"{path}: not an OpenCV FileStorage file (empty)")
    return text.replace("\r\n", "\n").replace("\r", "\n")  # as a text-mode read


def _line(text: str, pos: int) -> int:
    return text.count("\n", 0, pos) + 1


def _too_deep(path: Path, text: str, pos: int):
    return ValueError(
        f"{path}: nested deeper than {MAX_NESTING} levels (line {_line(text, pos)}); a "
        "calibration file is a few levels deep: refused before OpenCV parses it")


def _check_yaml_nesting(path: Path, text: str) -> None:
    """Refuse YAML (or JSON) text nested deeper than :data:`MAX_NESTING`: block levels by
    indentation (and sequence dashes), flow levels by brackets outside quotes and comments.
    An upper bound of the levels OpenCV's parser recurses into."""
    block: list[int] = []  # indentation columns of the open block levels
    flow = 0
    for m in _YAML_TOKEN.finditer(text):
        kind = m.lastgroup
        if kind == "open":
            flow += 1
            if len(block) + flow > MAX_NESTING:
                raise _too_deep(path, text, m.start())
        elif kind == "close":
            flow = max(flow - 1, 0)
        elif kind == "line" and flow == 0:  # not a flow sequence's next line
            line = m.group()
            if not line:  # column 0: a top-level line
                block[:] = [0]
                continue
            columns = [i for i, c in enumerate(line) if c == "-"] + [len(line)]
            for col in columns:
                while block and block[-1] > col:
                    block.pop()
                if not block or block[-1] < col:
                    block.append(col)
            if len(block) > MAX_NESTING:
                raise _too_deep(path, text, m.start())


def _check_xml_nesting(path: Path, text: str) -> None:
    """Refuse XML text with elements nested deeper than :data:`MAX_NESTING` (comments,
    declarations and CDATA skipped); linear in the text."""
    depth, pos = 0, 0
    ends = {"<!--": "-->", "<![CDATA[": "]]>", "<?": "?>", "<!": ">"}
    while (start := text.find("<", pos)) >= 0:
        for opening, closing in ends.items():
            if text.startswith(opening, start):
                end = text.find(closing, start + len(opening))
                pos = -1 if end < 0 else end + len(closing)
                break
        else:
            end = text.find(">", start + 1)
            if end < 0:
                return
            pos = end + 1
            tag = text[start + 1:end]
            if tag.startswith("/"):
                depth = max(depth - 1, 0)
            elif not tag.endswith("/"):
                depth += 1
                if depth > MAX_NESTING:
                    raise _too_deep(path, text, start)
        if pos < 0:
            return


def _check_integers(path: Path, text: str) -> None:
    """Refuse an integer beyond 32 bits in a key whose integers are read (sizes, matrix
    headers and data, version): OpenCV would read it wrapped around, silently."""
    for pattern in (_YAML_INT_VALUE, _XML_INT_VALUE):
        for m in pattern.finditer(text):
            for number in _BIG_INT.finditer(m.group(2)):
                if abs(int(number.group())) >= _INT32:
                    raise ValueError(
                        f"{path}: {m.group(1)}: {number.group()} (line "
                        f"{_line(text, m.start(2) + number.start())}) is beyond the 32-bit "
                        "integers OpenCV reads (it would read it wrapped around)")


def _check_text(path: Path, text: str) -> None:
    """The checks of a file's text before OpenCV parses it: nesting (both syntaxes: an upper
    bound whatever OpenCV takes the text for) and integers beyond 32 bits."""
    _check_yaml_nesting(path, text)
    _check_xml_nesting(path, text)
    _check_integers(path, text)


def _cv_detail(exc: BaseException) -> str:
    cause = exc.__cause__ or exc.__context__ or exc
    lines = str(cause).strip().splitlines()
    return lines[-1].strip() if lines else type(cause).__name__


class _Storage:
    """The top-level nodes of one or several ``FileStorage`` files (a key in two files must
    hold the same value), with errors naming the file and the key.

    Each file is read by :func:`_read_text` and checked by :func:`_check_text`; OpenCV then
    parses that same text from memory (``FILE_STORAGE_MEMORY``), so what was checked is what
    it parses.
    """

    def __init__(self, paths):
        import cv2

        self.paths = [Path(p) for p in paths]
        self.where = ", ".join(str(p) for p in self.paths)
        self.nodes: dict = {}
        self.origin: dict = {}
        self._storages = []
        for path in self.paths:
            text = _read_text(path)
            _check_text(path, text)
            try:
                with _quiet_opencv():
                    fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
            except (cv2.error, SystemError) as exc:
                raise ValueError(f"{path}: not a valid OpenCV FileStorage file (XML or YAML: "
                                 f"{_cv_detail(exc)})") from exc
            if not fs.isOpened():
                raise ValueError(f"{path}: not a valid OpenCV FileStorage file")
            self._storages.append(fs)
            root = fs.root()
            for key in root.keys():
                node = root.getNode(key)
                if key in self.nodes and not _same(self.nodes[key], node,
                                                   (str(self.origin[key]), str(path)), key):
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


def _same(a, b, where: tuple[str, str], key: str) -> bool:
    va, vb = _values(a, where[0], key), _values(b, where[1], key)
    if va is None or vb is None:
        return False
    return va.shape == vb.shape and np.array_equal(va, vb)


def _whole(node, where: str, name: str) -> int:
    """A matrix header's integer (``rows``, ``cols``, an entry of ``sizes``), ≥ 0."""
    value = node.real() if node.isInt() or node.isReal() else float("nan")
    if not (np.isfinite(value) and value == int(value) and value >= 0):
        raise ValueError(f"{where}: {name}: expected an integer >= 0, got "
                         f"{value if np.isfinite(value) else node.string() or '(none)'}")
    return int(value)


def _matrix(node, where: str, key: str) -> np.ndarray | None:
    """An OpenCV matrix map's numbers, its header checked before OpenCV allocates it: a known
    ``dt``, at most :data:`MAX_MATRIX_ELEMENTS` elements, as many numbers in ``data``. None
    for a map that is not a matrix (no ``dt``)."""
    dt_node = node.getNode("dt")
    if dt_node.empty() or not dt_node.isString():
        return None
    dt = dt_node.string()
    m = _DT.fullmatch(dt)
    if m is None:
        raise ValueError(f"{where}: {key}.dt: expected an OpenCV element type (u c w s i f d "
                         f"h, with a channel count first, e.g. 'd' or '3d'), got {dt!r}")
    channels = int(m.group(1) or 1)
    sizes = node.getNode("sizes")
    if not sizes.empty():
        if not sizes.isSeq() or not 1 <= sizes.size() <= 32:
            raise ValueError(f"{where}: {key}.sizes: expected 1 to 32 dimensions")
        dims = [_whole(sizes.at(i), where, f"{key}.sizes[{i}]") for i in range(sizes.size())]
        shown = " x ".join(map(str, dims))
    else:
        dims = [_whole(node.getNode(k), where, f"{key}.{k}") for k in ("rows", "cols")]
        shown = f"{dims[0]} x {dims[1]}"
    elements = int(np.prod(dims, dtype=object)) * channels
    if not 1 <= channels <= 512 or elements > MAX_MATRIX_ELEMENTS:
        raise ValueError(f"{where}: {key}: a {shown} matrix of {channels} channel(s) "
                         f"({elements} numbers): beyond {MAX_MATRIX_ELEMENTS} numbers, not a "
                         "calibration matrix")
    data = node.getNode("data")
    n = 0 if data.empty() else data.size()
    if n != elements:
        raise ValueError(f"{where}: {key}: a {shown} matrix of {channels} channel(s) needs "
                         f"{elements} numbers, its data holds {n}")
    import cv2

    try:
        with _quiet_opencv():
            mat = node.mat()
    except (cv2.error, SystemError) as exc:
        raise ValueError(f"{where}: {key}: not a valid OpenCV matrix ({_cv_detail(exc)})") \
            from exc
    return None if mat is None else np.asarray(mat)


def _values(node, where: str, key: str) -> np.ndarray | None:
    """A node's numbers: a matrix, a sequence of numbers or one number; None otherwise."""
    if node is None or node.empty():
        return None
    if node.isMap():
        return _matrix(node, where, key)
    if node.isSeq():
        if node.size() > MAX_MATRIX_ELEMENTS:
            raise ValueError(f"{where}: {key}: a sequence of {node.size()} items, beyond "
                             f"{MAX_MATRIX_ELEMENTS}: not a calibration value")
        items = [node.at(i) for i in range(node.size())]
        if not items or not all(i.isReal() or i.isInt() for i in items):
            return None
        return np.array([i.real() for i in items])
    if node.isReal() or node.isInt():
        return np.array(node.real())
    return None


def _array(node, where: str, key: str, sizes: tuple[int, ...], what: str) -> np.ndarray:
    """The float64 numbers of `node`, flattened, of one of `sizes`; ValueError otherwise."""
    values = _values(node, where, key)
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
    if not np.all((values == np.round(values)) & (values > 0)):
        raise ValueError(f"{where}: {key}: expected [W, H], two positive integers, got "
                         f"{values.tolist()}")
    return check_size(values, f"{where}: {key}")


def _int(node, where, key) -> int:
    values = _array(node, where, key, (1,), "a positive integer")
    value = values[0]
    if not (value == round(value) and 0 < value):
        raise ValueError(f"{where}: {key}: expected a positive integer, got {value:g}")
    if value > MAX_SIZE_PX:
        raise ValueError(f"{where}: {key}: {value:g} px, beyond {MAX_SIZE_PX} px: not an "
                         "image or panel size")
    return int(value)


def _pinhole(where: str, keys: str, *, device: str, names: dict[str, str],
             **fields) -> Pinhole:
    """A :class:`Pinhole` of read fields; its warnings (a float32 rotation) and errors name
    the file and the keys. Its numbers are checked
    (:func:`nail2nail.calibration.files.check_pinhole_values`): the message names the file,
    `device` (the camera, or the projector as calibrated with it) and the field by `names`."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            model = Pinhole(**fields)
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{where}: {keys}: {exc}") from exc
    for w in caught:
        warnings.warn(f"{where}: {keys}: {w.message}", w.category, stacklevel=4)
    check_pinhole_values(model, f"{where}: {device}", keys=names)
    return model


def _check_size_option(where, key, stored, option, flag) -> tuple[int, int]:
    if option is not None:
        option = check_size(option, flag)
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
        (beyond float32 rounding), a missing size, a mirrored or rank-deficient model. Before
        OpenCV parses a file: not a regular file (a FIFO, a device, a directory), larger than
        :data:`MAX_FILE_BYTES`, nested deeper than :data:`MAX_NESTING`, an integer beyond 32
        bits in a size, a matrix header or data; before it allocates a matrix: more than
        :data:`MAX_MATRIX_ELEMENTS` numbers, an unknown ``dt``, a header that disagrees with
        its data. Numbers out of range (naming the camera and the field): a size beyond
        :data:`nail2nail.calibration.files.MAX_SIZE_PX`, an intrinsic beyond
        ``MAX_INTRINSIC_PX``, a translation beyond ``MAX_TRANSLATION_MM``. Every error of
        OpenCV's (``cv2.error``) is one of these, naming the file.

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
    import cv2

    storage = _Storage(paths)
    if layout == "auto":
        try:
            layout = detect_layout(storage.keys())
        except ValueError as exc:
            raise ValueError(f"{storage.where}: {exc}") from exc
    try:  # OpenCV's errors on reading a node are the file's: bad input, never internal
        with _quiet_opencv():
            if layout == "nail2nail":
                rig = _read_rig(storage, camera_size, projector_size)
            else:
                rig = _read_one_camera(storage, layout, camera_size, projector_size)
    except (cv2.error, SystemError) as exc:
        raise ValueError(f"{storage.where}: not a valid OpenCV FileStorage file "
                         f"({_cv_detail(exc)})") from exc
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
                      R=np.eye(3), t=np.zeros(3), dist=values["D1"], size=cam_size,
                      device="camera 'cam0'",
                      names={"K": names["K1"], "size": "image size"})
    projector = _pinhole(where(names["R"]),
                         f"{names['K2']}, {names['D2']}, {names['R']}, {names['T']}",
                         K=values["K2"], R=values["R"], t=values["T"], dist=values["D2"],
                         size=proj_size, device="the projector (of camera 'cam0')",
                         names={"K": names["K2"], "t": names["T"],
                                "size": "panel size"})
    return RigCalibration(cameras=[CameraCalibration("cam0", camera, projector, cam_size)],
                          extra={"world_frame": "cam0"})


def _model_map(storage: _Storage, node, where: str, label: str, size_option, flag, *,
               device: str) -> Pinhole:
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
    return _pinhole(where, label, size=size, device=device,
                    names={k: f"{label}.{k}" for k in ("K", "t", "size")}, **fields)


def _read_rig(storage: _Storage, camera_size, projector_size) -> RigCalibration:
    where = storage.file_of("cameras")
    if "format" in storage.nodes:
        fmt = storage.node("format")
        if not fmt.isString() or fmt.string() != RIG_FORMAT:
            raise ValueError(f"{storage.file_of('format')}: format: expected {RIG_FORMAT!r}")
    if "version" in storage.nodes:
        version = _values(storage.node("version"), storage.file_of("version"), "version")
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
        name = name_node.string()
        camera = _model_map(storage, node, where, label, camera_size, "--camera-size",
                            device=f"camera {name!r}")
        own = node.getNode("projector")
        if not own.empty():
            projector = _model_map(storage, own, where, f"{label}.projector", projector_size,
                                   "--projector-size", device=f"the projector of {name!r}")
        elif shared is not None:
            projector = _model_map(storage, shared, storage.file_of("projector"), "projector",
                                   projector_size, "--projector-size", device="the projector")
        else:
            raise ValueError(f"{storage.where}: missing key 'projector'")
        cameras.append(CameraCalibration(name, camera, projector, camera.size))
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
        one-camera layout without `camera` for a rig of several, or an unknown camera; the
        numbers import refuses (:func:`nail2nail.calibration.files.check_pinhole_values`);
        `path` a directory, or not writable (named as given, not the temporary file).
    """
    import cv2

    path = Path(path)
    if path.suffix.lower() not in _SUFFIXES:
        raise ValueError(f"{path}: expected a .xml, .yml or .yaml file name (the suffix picks "
                         "the FileStorage format)")
    check_output_file(path)
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
    for name, cam_model, proj_model in models:  # the numbers import would refuse
        check_pinhole_values(cam_model, f"calibration: camera {name!r}")
        check_pinhole_values(proj_model, f"calibration: the projector of {name!r}")
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
    try:
        with atomic_path(path) as tmp:
            tmp.write_text(text, encoding="utf-8")
    except OSError as exc:  # named by the user's path, not the hidden temporary file's
        raise ValueError(f"{path}: cannot write ({exc.strerror or exc})") from exc
    for note in notes:
        warnings.warn(f"{path}: {note}", UserWarning, stacklevel=2)
    return notes
