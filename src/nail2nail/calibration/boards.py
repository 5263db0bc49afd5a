"""Planar calibration boards: geometry, printed appearance and detection in images.

A :class:`Board` describes a printed planar target of one of four kinds, with the command-line
options ``--board KIND --rows R --cols C --spacing MM [--marker MM]``:

========================== ========================= =================== ====================
kind                       ``rows`` × ``cols`` count ``spacing``         ``marker``
========================== ========================= =================== ====================
``checkerboard``           squares                   square side, mm     (unused)
``charuco``                squares                   square side, mm     marker side, mm
``circles``                circles                   centre distance, mm circle diameter, mm
``asymmetric-circles``     rows; circles in a row    row distance, mm    circle diameter, mm
========================== ========================= =================== ====================

OpenCV's pattern size ``(points per row, points per column)`` is ``(C − 1, R − 1)`` (the inner
corners) for the checkerboard and ChArUco boards, ``(C, R)`` for both circle grids.

**Board frame** (mm, as OpenCV's): ``x`` along the columns (to the right on the printed sheet
held upright), ``y`` along the rows (down the sheet), ``z = x × y`` into the sheet, so the
printed face looks towards ``−z``; every feature has ``z = 0``.

- Checkerboard and ChArUco: the origin is the outer corner of the top-left square (black);
  square ``(i, j)`` covers ``x ∈ [j s, (j + 1) s]``, ``y ∈ [i s, (i + 1) s]`` and is black when
  ``i + j`` is even (OpenCV's ChArUco layout); inner corner ``k = i (C − 1) + j`` (``i < R − 1``,
  ``j < C − 1``) is at ``((j + 1) s, (i + 1) s)``, which is also its ChArUco id.
- Symmetric circles: circle ``k = i C + j`` is at ``(j s, i s)``.
- Asymmetric circles (OpenCV's layout): circle ``k = i C + j`` is at ``((2 j + i mod 2) s, i s)``:
  circles in a row are ``2 s`` apart, the rows ``s`` apart and shifted by ``s`` on alternate rows.

Circles are **dark on white**; squares black and white. The sheet is the bounding box of the
pattern grown by `margin` (white). The printed reflectance (:meth:`Board.albedo`) is
`white` (0.9) on white paper and `black` (0.05) on ink.

:func:`detect_board` finds a board in an image with OpenCV and labels the points with the
indices of :meth:`Board.object_points`, unambiguously: among the labellings that OpenCV's grid
admits (its start corner and direction), it keeps those with the printed face seen from the front
(not mirrored) and then, for a checkerboard, the one with the black squares where the board
has them. A board that looks the same turned by half a turn (:attr:`Board.half_turn_symmetric`:
a checkerboard whose ``R + C`` is even, a symmetric circle grid, an asymmetric one with an even
number of rows) has two labellings that fit the image equally: :func:`detect_board` puts the
board's ``+x`` axis towards the image's right (a board upright within ±90° of the image's
rows), and :func:`nail2nail.calibration.observe.board_views` then makes the labels of every
camera of a pose agree through the projector coordinates decoded on the board, which all
cameras share (:func:`half_turn_ids`). Only where no camera of a pose has projector points and
several cameras see it is there no cue, and the views are refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.ndimage as ndi

from nail2nail.calibration.markers import TargetGeometry
from nail2nail.io._atomic import atomic_path

__all__ = [
    "BOARD_KINDS",
    "Board",
    "Sheet",
    "board_sheet",
    "default_board",
    "detect_board",
    "half_turn_ids",
    "target_wrap_sheet",
    "to_uint8",
]

BOARD_KINDS = ("checkerboard", "charuco", "circles", "asymmetric-circles")

#: OpenCV ArUco dictionaries accepted for ChArUco boards
_DICTIONARY_PREFIX = "DICT_"


@dataclass(frozen=True)
class Board:
    """A printed planar calibration board (see the module docstring for the frame).

    Parameters
    ----------
    kind : {"checkerboard", "charuco", "circles", "asymmetric-circles"}
    rows, cols : int
        Squares (checkerboard, ChArUco) or circles (circle grids) along ``y`` and ``x``; for the
        asymmetric grid `cols` is the number of circles in one row.
    spacing : float
        Square side or circle centre distance (asymmetric: distance between rows), mm.
    marker : float, optional
        ChArUco marker side (default 0.7 `spacing`) or circle diameter (default 0.5 `spacing`
        for symmetric circles, 0.7 `spacing` for asymmetric ones), mm; unused by the
        checkerboard.
    dictionary : str
        OpenCV ArUco dictionary of a ChArUco board (``DICT_5X5_100``).
    margin : float, optional
        White border around the pattern, mm (default one `spacing`).
    white, black : float
        Reflectance of the paper and of the ink, in ``[0, 1]``.

    Examples
    --------
    >>> board = Board("checkerboard", rows=7, cols=10, spacing=2.0)
    >>> board.object_points().shape, board.pattern_size
    ((54, 3), (9, 6))
    >>> board.size_mm
    (24.0, 18.0)
    """

    kind: str
    rows: int
    cols: int
    spacing: float
    marker: float | None = None
    dictionary: str = "DICT_5X5_100"
    margin: float | None = None
    white: float = 0.9
    black: float = 0.05

    def __post_init__(self) -> None:
        if self.kind not in BOARD_KINDS:
            raise ValueError(f"board: expected a kind in {', '.join(BOARD_KINDS)}, "
                             f"got {self.kind!r}")
        for name in ("rows", "cols"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise TypeError(f"{name}: expected an integer, got {value!r}")
        low = 3 if self.kind in ("checkerboard", "charuco") else 2
        if self.rows < low or self.cols < low:
            raise ValueError(f"rows, cols: a {self.kind} board needs at least {low} of each, "
                             f"got {self.rows} x {self.cols}")
        if not (isinstance(self.spacing, (int, float)) and math.isfinite(self.spacing)
                and self.spacing > 0):
            raise ValueError(f"spacing: expected a positive length in mm, got {self.spacing!r}")
        marker = self.marker_mm
        limit = {"checkerboard": math.inf, "charuco": self.spacing,
                 "circles": self.spacing, "asymmetric-circles": math.sqrt(2) * self.spacing}
        if self.kind != "checkerboard" and not (math.isfinite(marker)
                                                 and 0 < marker < limit[self.kind]):
            raise ValueError(f"marker: expected a size in (0, {limit[self.kind]:g}) mm for a "
                             f"{self.kind} board of spacing {self.spacing:g}, got {marker!r}")
        if self.margin is not None and not (math.isfinite(self.margin) and self.margin >= 0):
            raise ValueError(f"margin: expected a length >= 0 mm, got {self.margin!r}")
        if not 0 <= self.black < self.white <= 1:
            raise ValueError(f"white, black: expected 0 <= black < white <= 1, got "
                             f"{self.white!r}, {self.black!r}")
        if self.kind == "charuco":
            n_markers = (self.rows * self.cols) // 2
            size = _dictionary_size(self.dictionary)
            if n_markers > size:
                raise ValueError(f"dictionary: {self.dictionary} has {size} markers, a ChArUco "
                                 f"board of {self.rows} x {self.cols} squares needs {n_markers}")

    # -- geometry ----------------------------------------------------------------------------
    @property
    def marker_mm(self) -> float:
        """ChArUco marker side or circle diameter, mm (the default when `marker` is None; 0 for
        a checkerboard)."""
        if self.kind == "checkerboard":
            return 0.0
        if self.marker is not None:
            return float(self.marker)
        return {"charuco": 0.7, "circles": 0.5,
                "asymmetric-circles": 0.7}[self.kind] * float(self.spacing)

    @property
    def margin_mm(self) -> float:
        """White border around the pattern, mm."""
        return float(self.spacing if self.margin is None else self.margin)

    @property
    def pattern_size(self) -> tuple[int, int]:
        """OpenCV's pattern size ``(points per row, rows of points)``."""
        if self.kind in ("checkerboard", "charuco"):
            return self.cols - 1, self.rows - 1
        return self.cols, self.rows

    @property
    def n_points(self) -> int:
        """Number of detectable points (inner corners or circles)."""
        w, h = self.pattern_size
        return w * h

    def object_points(self) -> np.ndarray:
        """Board points ``(n_points, 3)`` float64, mm, in the board frame (``z = 0``).

        Index ``k = i · w + j`` for point row ``i`` and column ``j`` (``w`` the points per row,
        :attr:`pattern_size`); positions in the module docstring.
        """
        w, h = self.pattern_size
        i, j = np.divmod(np.arange(w * h), w)
        s = float(self.spacing)
        if self.kind in ("checkerboard", "charuco"):
            x, y = (j + 1) * s, (i + 1) * s
        elif self.kind == "circles":
            x, y = j * s, i * s
        else:
            x, y = (2 * j + i % 2) * s, i * s
        return np.column_stack([x, y, np.zeros(w * h)]).astype(np.float64)

    @property
    def half_turn_symmetric(self) -> bool:
        """Whether the board looks the same turned by half a turn in its plane (its features'
        labels then come from a cue outside the image: module docstring)."""
        if self.kind == "checkerboard":
            return (self.rows + self.cols) % 2 == 0
        if self.kind == "circles":
            return True
        if self.kind == "asymmetric-circles":
            return self.rows % 2 == 0
        return False  # ChArUco: its markers

    def pattern_extent(self) -> tuple[float, float, float, float]:
        """``(x_min, x_max, y_min, y_max)`` of the printed pattern (no margin), mm."""
        s = float(self.spacing)
        if self.kind in ("checkerboard", "charuco"):
            return 0.0, self.cols * s, 0.0, self.rows * s
        r = self.marker_mm / 2
        pts = self.object_points()
        return (float(pts[:, 0].min() - r), float(pts[:, 0].max() + r),
                float(pts[:, 1].min() - r), float(pts[:, 1].max() + r))

    def extent(self) -> tuple[float, float, float, float]:
        """``(x_min, x_max, y_min, y_max)`` of the sheet (pattern plus margin), mm."""
        x0, x1, y0, y1 = self.pattern_extent()
        m = self.margin_mm
        return x0 - m, x1 + m, y0 - m, y1 + m

    @property
    def size_mm(self) -> tuple[float, float]:
        """``(width, height)`` of the sheet (pattern plus margin), mm."""
        x0, x1, y0, y1 = self.extent()
        return round(x1 - x0, 9), round(y1 - y0, 9)

    @property
    def center(self) -> np.ndarray:
        """Centre ``(3,)`` of the sheet in the board frame, mm."""
        x0, x1, y0, y1 = self.extent()
        return np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])

    def to_dict(self) -> dict:
        """JSON-ready description (kind, counts, sizes in mm; what `from_dict` reads)."""
        out = {"kind": self.kind, "rows": int(self.rows), "cols": int(self.cols),
               "spacing": float(self.spacing),
               "marker": None if self.kind == "checkerboard" else self.marker_mm,
               "margin": self.margin_mm, "white": self.white, "black": self.black,
               "pattern_size": list(self.pattern_size), "size_mm": list(self.size_mm)}
        if self.kind == "charuco":
            out["dictionary"] = self.dictionary
        return out

    @classmethod
    def from_dict(cls, data: dict) -> Board:
        """Inverse of :meth:`to_dict` (derived keys are ignored)."""
        if not isinstance(data, dict):
            raise ValueError(f"board: expected an object, got {type(data).__name__}")
        keys = ("kind", "rows", "cols", "spacing", "marker", "dictionary", "margin", "white",
                "black")
        missing = [k for k in ("kind", "rows", "cols", "spacing") if k not in data]
        if missing:
            raise ValueError(f"board: missing {', '.join(missing)}")
        options = {k: data[k] for k in keys if data.get(k) is not None}
        return cls(**options)

    # -- appearance ----------------------------------------------------------------------------
    def ink(self, x, y, *, footprint=0.0) -> np.ndarray:
        """Fraction of ink (0 paper, 1 black) at board coordinates, box-filtered.

        Parameters
        ----------
        x, y : array_like of float
            Board coordinates, mm (broadcast together).
        footprint : float or array_like of float
            Side of the square box filter, mm (0: point samples), one for all points or one per
            point (broadcast with `x`, `y`). The checkerboard is averaged exactly over the box;
            circles get a linear edge ramp of the box's width; a ChArUco board is sampled
            bilinearly from a raster of at least 40 px/mm box-filtered to the footprint
            (rounded to an odd number of raster pixels).

        Returns
        -------
        ndarray of float64, the broadcast shape of `x`, `y`, in ``[0, 1]``
        """
        x, y, w = np.broadcast_arrays(np.asarray(x, dtype=np.float64),
                                      np.asarray(y, dtype=np.float64),
                                      np.asarray(footprint, dtype=np.float64))
        if not np.all(np.isfinite(w) & (w >= 0)):
            raise ValueError("footprint: expected lengths >= 0 mm")
        if self.kind == "checkerboard":
            return self._checker_ink(x, y, w)
        if self.kind == "charuco":
            return self._raster_ink(x, y, w)
        return self._circle_ink(x, y, w)

    def albedo(self, x, y, *, footprint: float = 0.0) -> np.ndarray:
        """Reflectance of the printed board at board coordinates ``(x, y)`` mm.

        ``white − (white − black) · ink`` with :meth:`ink` (same shapes and `footprint`); the
        paper beyond the sheet is white too (the scene cuts the sheet).
        """
        return self.white - (self.white - self.black) * self.ink(x, y, footprint=footprint)

    def image(self, px_per_mm: float) -> np.ndarray:
        """The printed design, ``(H, W)`` uint8, 0 ink and 255 paper, of the whole sheet.

        Pixel ``(col, row)`` (centres at integers) shows the board point
        ``x = x_min + (col + ½) / px_per_mm``, ``y = y_min + (row + ½) / px_per_mm`` with
        ``x_min, y_min`` of :meth:`extent` (so ``W = round(width · px_per_mm)``); each pixel is the
        area average of the design over it (:meth:`ink` with ``footprint = 1 / px_per_mm``).
        """
        if not (isinstance(px_per_mm, (int, float)) and math.isfinite(px_per_mm)
                and px_per_mm > 0):
            raise ValueError(f"px_per_mm: expected a positive number, got {px_per_mm!r}")
        x0, x1, y0, y1 = self.extent()
        width = max(1, round((x1 - x0) * px_per_mm))
        height = max(1, round((y1 - y0) * px_per_mm))
        xs = x0 + (np.arange(width) + 0.5) / px_per_mm
        ys = y0 + (np.arange(height) + 0.5) / px_per_mm
        ink = self.ink(xs[None, :], ys[:, None], footprint=1.0 / px_per_mm)
        return np.rint(255.0 * (1.0 - ink)).astype(np.uint8)

    def pixel_from_board(self, xy_board, px_per_mm: float) -> np.ndarray:
        """Pixel ``(x, y)`` in :meth:`image` of board points ``(..., 2)`` mm (centres at 0, 1…)."""
        x0, _, y0, _ = self.extent()
        xy = np.asarray(xy_board, dtype=np.float64)
        return (xy - np.array([x0, y0])) * px_per_mm - 0.5

    def _checker_ink(self, x, y, w):
        s = float(self.spacing)
        u = _box_average_checker(x, s, self.cols, w)
        v = _box_average_checker(y, s, self.rows, w)
        # black iff floor(x/s) + floor(y/s) even, inside the pattern:
        # ink = (in(x) in(y) + q(x) q(y)) / 2 with q = ±1 inside, 0 outside (separable)
        return np.clip(0.5 * (u[0] * v[0] + u[1] * v[1]), 0.0, 1.0)

    def _circle_ink(self, x, y, w):
        s = float(self.spacing)
        r = self.marker_mm / 2
        i0 = np.rint(y / s)
        best = np.full(x.shape, np.inf)
        for di in (-1.0, 0.0, 1.0):
            i = np.clip(i0 + di, 0, self.rows - 1)
            if self.kind == "circles":
                j = np.clip(np.rint(x / s), 0, self.cols - 1)
                cx = j * s
            else:
                shift = np.mod(i, 2)
                j = np.clip(np.rint((x / s - shift) / 2), 0, self.cols - 1)
                cx = (2 * j + shift) * s
            best = np.minimum(best, np.hypot(x - cx, y - i * s))
        with np.errstate(divide="ignore", invalid="ignore"):
            ramp = np.clip((r - best) / w + 0.5, 0.0, 1.0)
        return np.where(w > 0, ramp, (best <= r).astype(np.float64))

    def _raster_ink(self, x, y, w):
        import cv2

        raster, ppm = _charuco_raster(self)
        base = 1.0 - raster.astype(np.float32) / 255.0
        kernel = 2 * np.rint(w * ppm / 2).astype(np.intp) + 1  # odd: centred
        out = np.empty(x.shape)
        for k in np.unique(kernel):
            ink = base if k < 3 else cv2.blur(base, (int(k), int(k)),
                                              borderType=cv2.BORDER_CONSTANT)
            pick = kernel == k
            out[pick] = _bilinear_ink(ink, x[pick] * ppm - 0.5, y[pick] * ppm - 0.5)
        return out

    # -- OpenCV objects ------------------------------------------------------------------------
    def opencv_charuco(self):
        """The ``cv2.aruco.CharucoBoard`` of a ChArUco board (lengths in mm)."""
        import cv2

        if self.kind != "charuco":
            raise ValueError(f"board: a {self.kind} board has no ChArUco board")
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.cols, self.rows), float(self.spacing),
                                      float(self.marker_mm), dictionary)


def _bilinear_ink(ink, col, row):
    """Bilinear samples of a raster at pixel coordinates (centres at integers), 0 beyond it."""
    h, wd = ink.shape
    padded = np.pad(ink, 1)
    c0 = np.floor(col)
    r0 = np.floor(row)
    fc = col - c0
    fr = row - r0
    c0 = np.clip(c0.astype(np.intp) + 1, 0, wd)
    r0 = np.clip(r0.astype(np.intp) + 1, 0, h)
    fc = np.where((col < -1) | (col > wd), 0.0, fc)
    fr = np.where((row < -1) | (row > h), 0.0, fr)
    value = ((1 - fc) * (1 - fr) * padded[r0, c0] + fc * (1 - fr) * padded[r0, c0 + 1]
             + (1 - fc) * fr * padded[r0 + 1, c0] + fc * fr * padded[r0 + 1, c0 + 1])
    outside = (col < -1) | (col > wd) | (row < -1) | (row > h)
    return np.where(outside, 0.0, value).astype(np.float64)


def default_board(kind: str = "checkerboard") -> Board:
    """A board of `kind` sized for the default rig's 32 × 40 mm view (2.5 mm pitch).

    Checkerboard and ChArUco: 11 × 8 squares of 2.5 mm; circles: 11 × 8 circles 2.5 mm apart;
    asymmetric circles: 11 rows of 4 circles, rows 2.5 mm apart. The pattern spans about
    20 × 27.5 mm, so that tilted by 30° it stays inside every camera's view.

    Examples
    --------
    >>> default_board("charuco").size_mm
    (25.0, 32.5)
    """
    if kind not in BOARD_KINDS:
        raise ValueError(f"board: expected a kind in {', '.join(BOARD_KINDS)}, got {kind!r}")
    cols = 4 if kind == "asymmetric-circles" else 8
    return Board(kind, rows=11, cols=cols, spacing=2.5)


def _dictionary_size(name: str) -> int:
    import cv2

    if not (isinstance(name, str) and name.startswith(_DICTIONARY_PREFIX)
            and hasattr(cv2.aruco, name)):
        raise ValueError(f"dictionary: expected an OpenCV ArUco dictionary such as "
                         f"DICT_5X5_100, got {name!r}")
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
    return int(dictionary.bytesList.shape[0])


def _box_average_checker(x, s, n, w):
    """1-D box averages over ``[x − w/2, x + w/2]`` of ``in(x)`` and ``q(x)``.

    ``in`` is 1 on ``[0, n s]`` and 0 outside, ``q`` is ``+1`` on even squares, ``−1`` on odd
    ones, 0 outside; both through their antiderivatives (exact box filter).
    """
    def f_in(t):
        return np.clip(t, 0.0, n * s)

    def f_q(t):
        t = np.clip(t, 0.0, n * s)
        k = np.floor(t / s)
        r = t - k * s
        return np.where(np.mod(k, 2) == 0, r, s - r)

    inside = ((x >= 0) & (x < n * s)).astype(np.float64)
    q = np.where(np.mod(np.floor(x / s), 2) == 0, 1.0, -1.0) * inside
    a, b = x - w / 2, x + w / 2
    with np.errstate(divide="ignore", invalid="ignore"):
        box_in = (f_in(b) - f_in(a)) / w
        box_q = (f_q(b) - f_q(a)) / w
    point = w == 0
    return np.where(point, inside, box_in), np.where(point, q, box_q)


_RASTERS: dict = {}


def _charuco_raster(board: Board) -> tuple[np.ndarray, float]:
    """``(image, px_per_mm)``: the ChArUco pattern area (no margin), cached per board."""
    key = (board.rows, board.cols, float(board.spacing), board.marker_mm, board.dictionary)
    if key not in _RASTERS:
        # whole pixels per square, at least 40 px/mm and 200 px per square
        per_square = max(200, math.ceil(40 * board.spacing))
        cv_board = board.opencv_charuco()
        image = cv_board.generateImage((board.cols * per_square, board.rows * per_square),
                                       marginSize=0, borderBits=1)
        _RASTERS.clear()
        _RASTERS[key] = (np.ascontiguousarray(image), per_square / float(board.spacing))
    return _RASTERS[key]


# -- detection ------------------------------------------------------------------------------------
def to_uint8(image) -> np.ndarray:
    """An image of any dtype as 8-bit for OpenCV, stretched between its 0.5 and 99.5 percentiles.

    Parameters
    ----------
    image : (H, W) array_like of float or int
        Any bit depth or scale (float ``[0, 1]``, 16-bit left-aligned, …); NaN counts as dark.

    Returns
    -------
    (H, W) uint8
    """
    return np.rint(np.clip(_stretched(image), 0, 1) * 255).astype(np.uint8)


def _stretched(image) -> np.ndarray:
    """``(H, W)`` float64: `image` mapped linearly so that its 0.5 and 99.5 percentiles are 0
    and 1 (not clipped; NaN to 0; all zeros for a flat image)."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        img = img[..., :3].mean(axis=2)
    if img.ndim != 2 or min(img.shape) < 8:
        raise ValueError(f"image: expected a 2-D image of at least 8 x 8 px, got shape "
                         f"{img.shape}")
    if not (np.issubdtype(img.dtype, np.number) and not np.iscomplexobj(img)):
        raise TypeError(f"image: expected real numbers, got {img.dtype}")
    img = img.astype(np.float64)
    finite = np.isfinite(img)
    if not finite.any():
        raise ValueError("image: no finite value")
    lo, hi = np.percentile(img[finite], [0.5, 99.5])
    if not hi > lo:
        return np.zeros(img.shape)
    return np.where(finite, (img - lo) / (hi - lo), 0.0)


def detect_board(image, board: Board) -> tuple[np.ndarray, np.ndarray] | None:
    """Find a board in an image and label its points.

    Parameters
    ----------
    image : (H, W) array_like
        Grey image of any dtype and bit depth (:func:`to_uint8`), e.g. a capture's decoded
        albedo (the mean of the phase frames) or a white frame.
    board : Board

    Returns
    -------
    (indices, xy) or None
        ``indices (n,)`` int64 into :meth:`Board.object_points`, ascending; ``xy (n, 2)``
        float64 image coordinates, px, pixel centres at integers (``docs/conventions.md``).
        All points for the checkerboard and circle grids, those found for ChArUco (at least 4).
        None when the board is not found.

    Notes
    -----
    Finding: checkerboard ``cv2.findChessboardCornersSB`` (accuracy mode), falling back on
    ``cv2.findChessboardCorners`` and ``cv2.cornerSubPix``; circles ``cv2.findCirclesGrid``
    with a blob detector for dark discs of any size; ChArUco ``cv2.aruco.CharucoDetector``.
    Labelling: module docstring. Then every point is measured again on the image (in floating
    point, not the 8-bit copy OpenCV gets): a corner as the crossing of the two edges through
    it, each a line fitted to edge points measured on short profiles across its two halves
    (:func:`_refine_checker_corners`); a circle as the ink centroid against a fitted local
    paper level, corrected for perspective (the centroid of a disc's image is not the image of
    its centre, :func:`_refine_circles`). On the virtual scanner this takes the RMS error
    against the true projections from 0.02–0.08 px (OpenCV's) to 0.002–0.013 px at scale 0.5
    up to 58° of obliquity (``docs/real-scanner.md``, "Measured").
    """
    if not isinstance(board, Board):
        raise TypeError(f"board: expected a Board, got {type(board).__name__}")
    img = _stretched(image)
    img8 = np.rint(np.clip(img, 0, 1) * 255).astype(np.uint8)
    if board.kind == "charuco":
        return _detect_charuco(img8, img, board)
    if board.kind == "checkerboard":
        xy = _find_checkerboard(img8, board)
    else:
        xy = _find_circles(img8, board)
    if xy is None:
        return None
    indices = _label_grid(img8, board, xy)
    if indices is None:
        return None
    if board.kind == "checkerboard":
        xy = _refine_checker_corners(img, board, indices, xy)
    else:
        xy = _refine_circles(img, board, indices, xy)
        if xy is None:
            return None
    order = np.argsort(indices)
    return indices[order].astype(np.int64), xy[order]


def _find_checkerboard(img8, board):
    import cv2

    size = board.pattern_size
    flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    found, corners = cv2.findChessboardCornersSB(img8, size, flags=flags)
    if not found:
        found, corners = cv2.findChessboardCorners(
            img8, size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not found:
            return None
        xy = corners.reshape(-1, 2).astype(np.float64)
        spacing = np.median(np.linalg.norm(np.diff(xy.reshape(size[1], size[0], 2), axis=1),
                                           axis=-1))
        half = int(np.clip(spacing / 4, 2, 15))
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
        corners = cv2.cornerSubPix(img8, corners.astype(np.float32), (half, half), (-1, -1),
                                   criteria)
    return corners.reshape(-1, 2).astype(np.float64)


def _blob_detector(img8, board):
    import cv2

    params = cv2.SimpleBlobDetector_Params()
    params.filterByColor = True
    params.blobColor = 0  # dark circles on white paper
    params.minArea = 9.0
    params.maxArea = float(img8.shape[0] * img8.shape[1]) / 4
    params.filterByCircularity = False
    params.filterByInertia = True
    params.minInertiaRatio = 0.05
    params.filterByConvexity = True
    params.minConvexity = 0.8
    params.minDistBetweenBlobs = 2.0
    params.minThreshold = 20
    params.maxThreshold = 235
    params.thresholdStep = 10
    return cv2.SimpleBlobDetector_create(params)


def _find_circles(img8, board):
    import cv2

    flags = (cv2.CALIB_CB_SYMMETRIC_GRID if board.kind == "circles"
             else cv2.CALIB_CB_ASYMMETRIC_GRID)
    detector = _blob_detector(img8, board)
    blobs = len(detector.detect(img8))
    if blobs < board.n_points:
        return None
    # OpenCV's plain grid search is combinatorial in the blobs: 10-15 s for the ~900 blobs of
    # a board-less noisy image, where the clustering search takes 0.1 s
    modes = (0, cv2.CALIB_CB_CLUSTERING) if blobs <= 4 * board.n_points else (
        cv2.CALIB_CB_CLUSTERING,)
    for extra in modes:
        found, centers = cv2.findCirclesGrid(img8, board.pattern_size, flags=flags | extra,
                                             blobDetector=detector)
        if found:
            return centers.reshape(-1, 2).astype(np.float64)
    return None


def _detect_charuco(img8, img, board):
    import cv2

    detector = cv2.aruco.CharucoDetector(board.opencv_charuco())
    corners, ids, _, _ = detector.detectBoard(img8)
    if corners is None or ids is None or len(ids) < 4:
        return None
    indices = ids.reshape(-1).astype(np.int64)
    xy = corners.reshape(-1, 2).astype(np.float64)
    order = np.argsort(indices)
    indices, xy = indices[order], xy[order]
    # refine with a window of a quarter of the local square's image (OpenCV's default is
    # smaller and leaves about 0.06 px of noise); the markers stay outside it
    obj = board.object_points()[indices, :2]
    hom = _homography(obj, xy)
    here = _apply(hom, obj)
    step = np.minimum(
        np.linalg.norm(_apply(hom, obj + np.array([board.spacing, 0.0])) - here, axis=1),
        np.linalg.norm(_apply(hom, obj + np.array([0.0, board.spacing])) - here, axis=1))
    gap = (board.spacing - board.marker_mm) / 2 / board.spacing
    half = int(np.clip(np.median(step) * min(0.25, 0.8 * gap), 2, 20))
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
    refined = cv2.cornerSubPix(img8, xy.astype(np.float32).reshape(-1, 1, 2), (half, half),
                               (-1, -1), criteria).reshape(-1, 2).astype(np.float64)
    moved = np.linalg.norm(refined - xy, axis=1)
    xy = np.where((moved < 0.5 * half)[:, None], refined, xy)
    # then as checkerboard corners, with profiles short of the markers
    return indices, _refine_checker_corners(img, board, indices, xy,
                                            max_half_profile=0.6 * gap)


def _homography(src, dst):
    """Least-squares homography ``(3, 3)`` mapping ``src (n, 2)`` to ``dst (n, 2)`` (DLT)."""
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    # normalise both point sets (Hartley)
    def norm(p):
        c = p.mean(axis=0)
        s = math.sqrt(2) / max(np.sqrt(((p - c) ** 2).sum(axis=1)).mean(), 1e-12)
        return np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1.0]])

    ts, td = norm(src), norm(dst)
    ps = (np.column_stack([src, np.ones(len(src))]) @ ts.T)
    pd = (np.column_stack([dst, np.ones(len(dst))]) @ td.T)
    n = len(src)
    a = np.zeros((2 * n, 9))
    a[0::2, 0:3] = ps
    a[0::2, 6:9] = -pd[:, 0:1] * ps
    a[1::2, 3:6] = ps
    a[1::2, 6:9] = -pd[:, 1:2] * ps
    _, _, vt = np.linalg.svd(a)
    h = vt[-1].reshape(3, 3)
    h = np.linalg.solve(td, h @ ts)
    return h / h[2, 2]


def _apply(h, xy):
    p = np.column_stack([xy, np.ones(len(xy))]) @ h.T
    return p[:, :2] / p[:, 2:3]


def _label_grid(img8, board, xy):
    """Board indices ``(n,)`` of OpenCV's grid points `xy` (module docstring), or None."""
    w, h = board.pattern_size
    grid = np.arange(w * h).reshape(h, w)
    obj = board.object_points()[:, :2]
    candidates = []
    for axes in ((), (0,), (1,), (0, 1)):
        labels = np.flip(grid, axes).ravel() if axes else grid.ravel()
        hom = _homography(obj[labels], xy)
        residual = np.sqrt(np.mean(np.sum((_apply(hom, obj[labels]) - xy) ** 2, axis=1)))
        # orientation: the Jacobian of the board -> image map at the board centre
        c = obj.mean(axis=0)
        p = hom @ np.array([c[0], c[1], 1.0])
        jac = (hom[:2, :2] * p[2] - np.outer(p[:2], hom[2, :2])) / p[2] ** 2
        if np.linalg.det(jac) > 0:
            candidates.append((residual, labels, hom))
    if not candidates:
        return None
    best = min(r for r, _, _ in candidates)
    pitch = np.median(np.linalg.norm(np.diff(xy.reshape(h, w, 2), axis=1), axis=-1))
    tied = [(r, lab, hom) for r, lab, hom in candidates if r <= best + 0.05 * pitch + 0.5]
    if len(tied) == 1:
        return tied[0][1]
    if board.kind == "checkerboard" and not board.half_turn_symmetric:
        scores = [_checker_contrast(img8, board, hom) for _, _, hom in tied]
        return tied[int(np.argmax(scores))][1]
    # half-turn symmetric: the board's +x towards the image's right (board_views then makes
    # the cameras of a pose agree through the projector's coordinates)
    scores = []
    for _, _, hom in tied:
        a, b = _apply(hom, np.array([[0.0, 0.0], [1.0, 0.0]]) * board.spacing)
        scores.append(b[0] - a[0])
    return tied[int(np.argmax(scores))][1]


def _checker_contrast(img8, board, hom):
    """Mean grey of the squares the labelling makes white minus that of the black ones."""
    s = float(board.spacing)
    i, j = np.divmod(np.arange(board.rows * board.cols), board.cols)
    centres = np.column_stack([(j + 0.5) * s, (i + 0.5) * s])
    px = _apply(hom, centres)
    height, width = img8.shape
    inside = (px[:, 0] >= 0) & (px[:, 0] <= width - 1) & (px[:, 1] >= 0) & (px[:, 1] <= height - 1)
    if not inside.any():
        return 0.0
    grey = img8[np.rint(px[inside, 1]).astype(int), np.rint(px[inside, 0]).astype(int)]
    black = ((i + j) % 2 == 0)[inside]
    if black.all() or not black.any():
        return 0.0
    return float(grey[~black].mean() - grey[black].mean())


def _refine_checker_corners(img, board, indices, xy, *, max_half_profile: float = 0.3,
                            iterations: int = 2):
    """:func:`_refine_corners_once` `iterations` times (each anchored on the last).

    Left as they are when the corners do not span the board in both directions (fewer than 6,
    or all in one row or column of a partial ChArUco view): their homography is not defined.
    """
    obj = board.object_points()[indices, :2]
    if (len(obj) < 6 or len(np.unique(np.round(obj[:, 0], 6))) < 2
            or len(np.unique(np.round(obj[:, 1], 6))) < 2):
        return xy
    for _ in range(iterations):
        xy = _refine_corners_once(img, board, indices, xy, max_half_profile=max_half_profile)
    return xy


def _refine_corners_once(img, board, indices, xy, *, t_range=(0.2, 0.45),
                         max_half_profile: float = 0.3, profile_px: float = 5.0,
                         n_t: int = 8, n_v: int = 41):
    """Checkerboard corners refined as the crossing of the two edges through them.

    For each corner, the edge along the board's ``x`` through it is measured on ``2 n_t``
    profiles across it (along ``y``, ``±profile_px`` camera px long, between 0.08 and
    `max_half_profile` squares: short profiles stay clear of lighting gradients and of a
    ChArUco board's markers), placed at ``t_range``
    squares on either side of the corner (away from the corner itself, where the other edge
    blurs in), each profile sampled bilinearly at positions mapped by the board→image
    homography ``H`` (fitted to all corners, anchored at the corner's current position); the
    edge point is where the profile crosses the mean of its two ends' levels. A line fitted to
    these points (total least squares) and the one of the edge along ``y`` meet at the refined
    corner. The two halves of an edge have opposite polarities, so a non-linear response that
    moves the mid-level crossing moves them oppositely and the line stays; straight edges are
    assumed over one square (lens distortion bends them far less there). A corner whose
    profiles do not show the edge keeps its position, as one the refinement moves by more
    than a fifth of a square.

    Measured on the virtual scanner (scale 0.5): 0.002–0.009 px RMS against the true corners
    up to 58° of obliquity (0.04 px at 64°), against 0.02–0.08 px for
    ``findChessboardCornersSB`` and OpenCV's ChArUco corners.
    """
    s = float(board.spacing)
    obj = board.object_points()[indices, :2]
    hom = _homography(obj, xy)
    offsets = xy - _apply(hom, obj)
    t_lo, t_hi = t_range
    ts = np.concatenate([-np.linspace(t_lo, t_hi, n_t), np.linspace(t_lo, t_hi, n_t)]) * s
    here = _apply(hom, obj)
    step = np.minimum(np.linalg.norm(_apply(hom, obj + np.array([s, 0.0])) - here, axis=1),
                      np.linalg.norm(_apply(hom, obj + np.array([0.0, s])) - here, axis=1))
    half = np.clip(profile_px / np.maximum(step, 1e-9), 0.08, max_half_profile)
    end = max(2, n_v // 6)
    out = xy.copy()
    height, width = img.shape
    for k, (x0, y0) in enumerate(obj):
        vs = np.linspace(-half[k], half[k], n_v) * s
        lines = []
        for along_x in (True, False):
            if along_x:  # the edge y = y0, profiles along y
                px, py = np.broadcast_arrays(x0 + ts[:, None], y0 + vs[None, :])
            else:
                px, py = np.broadcast_arrays(x0 + vs[None, :], y0 + ts[:, None])
            pix = _apply(hom, np.column_stack([px.ravel(), py.ravel()])) + offsets[k]
            if (pix.min() < 0 or pix[:, 0].max() > width - 1
                    or pix[:, 1].max() > height - 1):
                break
            prof = ndi.map_coordinates(img, [pix[:, 1], pix[:, 0]], order=1).reshape(
                len(ts), n_v)
            lo = prof[:, :end].mean(axis=1)
            hi = prof[:, -end:].mean(axis=1)
            d = prof - 0.5 * (lo + hi)[:, None]
            crossing = np.sign(d[:, :-1]) * np.sign(d[:, 1:]) < 0
            # the crossing nearest the profile's middle
            distance = np.where(crossing, np.abs(np.arange(n_v - 1) - (n_v - 1) / 2), np.inf)
            c = np.argmin(distance, axis=1)
            good = np.isfinite(distance[np.arange(len(ts)), c]) & (np.abs(hi - lo) > 0.1)
            if np.count_nonzero(good) < 4:
                break
            rows = np.arange(len(ts))[good]
            c = c[good]
            frac = d[rows, c] / (d[rows, c] - d[rows, c + 1])
            v = vs[c] + frac * (vs[1] - vs[0])
            board_pts = (np.column_stack([x0 + ts[rows], y0 + v]) if along_x
                         else np.column_stack([x0 + v, y0 + ts[rows]]))
            edge = _apply(hom, board_pts) + offsets[k]
            centre = edge.mean(axis=0)
            normal = np.linalg.svd(edge - centre)[2][1]
            lines.append((normal, normal @ centre))
        if len(lines) != 2:
            continue
        a = np.array([lines[0][0], lines[1][0]])
        if abs(np.linalg.det(a)) < 0.1:
            continue
        corner = np.linalg.solve(a, np.array([lines[0][1], lines[1][1]]))
        if np.linalg.norm(corner - xy[k]) < 0.2 * step[k]:
            out[k] = corner
    return out


def _refine_circles(img, board, indices, xy, *, iterations: int = 2):
    """Circle centres refined to the projection of the true circle centres.

    The blob detector's centroid of a disc seen in perspective is not the image of the disc's
    centre, and it drifts with the lighting. With the board→image homography ``H`` (fitted to
    the current centres) each disc is measured again: the paper's brightness is fitted as a
    plane in ``x, y`` to a ring of pixels around the disc's mapped outline (between 1.25 and
    1.6 radii), the ink fraction ``1 − I / paper`` (clipped to ``[0, 1]``) is summed within
    1.2 radii, and its centroid (the area centroid of the projected disc, edges weighted by
    their coverage) is moved by the offset between the mapped outline's area centroid and
    ``H(centre)``.
    """
    obj = board.object_points()[indices, :2]
    img = np.asarray(img, dtype=np.float64)
    height, width = img.shape
    r = board.marker_mm / 2
    angles = np.linspace(0.0, 2 * np.pi, 64, endpoint=False)
    unit = np.column_stack([np.cos(angles), np.sin(angles)])
    current = xy.copy()
    for _ in range(iterations):
        hom = _homography(obj, current)
        out = current.copy()
        for k, centre in enumerate(obj):
            outer = _apply(hom, centre + 1.6 * r * unit)
            x0, y0 = np.floor(outer.min(axis=0)).astype(int)
            x1, y1 = np.ceil(outer.max(axis=0)).astype(int)
            if x0 < 0 or y0 < 0 or x1 >= width or y1 >= height:
                continue
            patch = img[y0:y1 + 1, x0:x1 + 1]
            gy, gx = np.mgrid[y0:y1 + 1, x0:x1 + 1]
            pts = np.column_stack([gx.ravel(), gy.ravel()])
            in_outer = _in_polygon(pts, outer)
            in_gap = _in_polygon(pts, _apply(hom, centre + 1.25 * r * unit))
            in_disc = _in_polygon(pts, _apply(hom, centre + 1.2 * r * unit)).reshape(patch.shape)
            ring = in_outer & ~in_gap
            if np.count_nonzero(ring) < 6:
                continue
            design = np.column_stack([np.ones(np.count_nonzero(ring)), pts[ring]])
            coef, *_ = np.linalg.lstsq(design, patch.ravel()[ring], rcond=None)
            paper = coef[0] + coef[1] * gx + coef[2] * gy
            if not np.all(paper[in_disc] > 0):
                continue
            ink = np.clip(1.0 - patch / paper, 0.0, 1.0) * in_disc
            total = ink.sum()
            if not total > 0:
                continue
            centroid = np.array([(ink * gx).sum(), (ink * gy).sum()]) / total
            outline = _apply(hom, centre + r * unit)
            bias = _polygon_centroid(outline) - _apply(hom, centre[None])[0]
            out[k] = centroid - bias
        if not np.all(np.isfinite(out)):
            return None
        current = out
    return current


def _polygon_centroid(poly):
    x, y = poly[:, 0], poly[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = cross.sum() / 2
    return np.array([((x + xn) * cross).sum(), ((y + yn) * cross).sum()]) / (6 * area)


def _in_polygon(points, poly):
    """Whether points ``(n, 2)`` lie inside a convex polygon ``(m, 2)`` (either winding)."""
    edges = np.roll(poly, -1, axis=0) - poly
    rel = points[:, None, :] - poly[None, :, :]
    cross = edges[None, :, 0] * rel[..., 1] - edges[None, :, 1] * rel[..., 0]
    return np.all(cross >= 0, axis=1) | np.all(cross <= 0, axis=1)


# -- printable sheets -----------------------------------------------------------------------------
_INK = "#000000"
_PAPER = "#ffffff"


@dataclass
class Sheet:
    """A printable page at true size: primitives in mm, ``x`` right, ``y`` down from top-left.

    Built by :func:`board_sheet` and :func:`target_wrap_sheet`; written by :meth:`save` as SVG
    (``width="…mm"``, ``viewBox`` in mm) or PDF (matplotlib's PDF backend, page size in inches
    = mm / 25.4), both at 1:1 scale.

    Attributes
    ----------
    width, height : float
        Page size, mm.
    items : list of tuple
        ``("rect", x, y, w, h, colour)``, ``("circle", cx, cy, r, colour)``,
        ``("line", x0, y0, x1, y1, width, colour)``, ``("text", x, y, size, text, anchor)``
        (``anchor`` ``start``/``middle``/``end``, ``size`` the font height in mm, ``y`` the
        baseline), ``("image", x, y, w, h, array (H, W) uint8)``, in drawing order.
    title : str
    """

    width: float
    height: float
    items: list
    title: str = ""

    def to_svg(self) -> str:
        """The page as an SVG document (mm units)."""
        import base64
        import io
        from xml.sax.saxutils import escape

        from PIL import Image

        def f(v):
            return f"{v:.4f}".rstrip("0").rstrip(".")

        out = ['<?xml version="1.0" encoding="UTF-8"?>',
               f'<svg xmlns="http://www.w3.org/2000/svg" '
               f'xmlns:xlink="http://www.w3.org/1999/xlink" width="{f(self.width)}mm" '
               f'height="{f(self.height)}mm" viewBox="0 0 {f(self.width)} {f(self.height)}">',
               f"<title>{escape(self.title)}</title>",
               f'<rect x="0" y="0" width="{f(self.width)}" height="{f(self.height)}" '
               f'fill="{_PAPER}"/>']
        for item in self.items:
            kind = item[0]
            if kind == "rect":
                _, x, y, w, h, colour = item
                out.append(f'<rect x="{f(x)}" y="{f(y)}" width="{f(w)}" height="{f(h)}" '
                           f'fill="{colour}"/>')
            elif kind == "circle":
                _, cx, cy, r, colour = item
                out.append(f'<circle cx="{f(cx)}" cy="{f(cy)}" r="{f(r)}" fill="{colour}"/>')
            elif kind == "line":
                _, x0, y0, x1, y1, width, colour = item
                out.append(f'<line x1="{f(x0)}" y1="{f(y0)}" x2="{f(x1)}" y2="{f(y1)}" '
                           f'stroke="{colour}" stroke-width="{f(width)}"/>')
            elif kind == "text":
                _, x, y, size, text, anchor = item
                out.append(f'<text x="{f(x)}" y="{f(y)}" font-family="sans-serif" '
                           f'font-size="{f(size)}" text-anchor="{anchor}">{escape(text)}</text>')
            elif kind == "image":
                _, x, y, w, h, array = item
                buffer = io.BytesIO()
                Image.fromarray(np.asarray(array, dtype=np.uint8)).save(buffer, format="PNG")
                data = base64.b64encode(buffer.getvalue()).decode("ascii")
                out.append(f'<image x="{f(x)}" y="{f(y)}" width="{f(w)}" height="{f(h)}" '
                           'preserveAspectRatio="none" style="image-rendering:pixelated" '
                           f'xlink:href="data:image/png;base64,{data}"/>')
            else:  # pragma: no cover - built here only
                raise ValueError(f"sheet: unknown item {kind!r}")
        out.append("</svg>")
        return "\n".join(out) + "\n"

    def _pdf(self, path) -> None:
        import matplotlib

        matplotlib.use("Agg", force=False)
        from matplotlib.figure import Figure
        from matplotlib.patches import Circle, Rectangle

        fig = Figure(figsize=(self.width / 25.4, self.height / 25.4))
        ax = fig.add_axes((0, 0, 1, 1))
        ax.set_xlim(0, self.width)
        ax.set_ylim(self.height, 0)
        ax.set_axis_off()
        points_per_mm = 72 / 25.4
        for item in self.items:
            kind = item[0]
            if kind == "rect":
                _, x, y, w, h, colour = item
                ax.add_patch(Rectangle((x, y), w, h, facecolor=colour, edgecolor="none",
                                       linewidth=0))
            elif kind == "circle":
                _, cx, cy, r, colour = item
                ax.add_patch(Circle((cx, cy), r, facecolor=colour, edgecolor="none",
                                    linewidth=0))
            elif kind == "line":
                _, x0, y0, x1, y1, width, colour = item
                ax.plot([x0, x1], [y0, y1], color=colour, linewidth=width * points_per_mm,
                        solid_capstyle="butt")
            elif kind == "text":
                _, x, y, size, text, anchor = item
                ha = {"start": "left", "middle": "center", "end": "right"}[anchor]
                ax.text(x, y, text, fontsize=size * points_per_mm, ha=ha,
                        va="baseline", family="sans-serif")
            elif kind == "image":
                _, x, y, w, h, array = item
                ax.imshow(array, cmap="gray", vmin=0, vmax=255, extent=(x, x + w, y + h, y),
                          interpolation="nearest", resample=False)
        ax.set_xlim(0, self.width)
        ax.set_ylim(self.height, 0)
        fig.savefig(path, format="pdf")

    def save(self, path) -> None:
        """Write the page as ``.svg`` or ``.pdf`` (by the suffix), atomically, at 1:1 scale."""
        from pathlib import Path

        path = Path(path)
        suffix = path.suffix.lower()
        if suffix not in (".svg", ".pdf"):
            raise ValueError(f"{path}: expected a .svg or .pdf file name")
        with atomic_path(path) as tmp:
            if suffix == ".svg":
                tmp.write_text(self.to_svg(), encoding="utf-8")
            else:
                self._pdf(tmp)


def _scale_bar(items, x, y, length=50.0):
    """A `length` mm bar with 10 mm ticks, its label above, its top-left at ``(x, y)``."""
    items.append(("rect", x, y + 2.5, length, 0.6, _INK))
    for k in range(int(length // 10) + 1):
        items.append(("line", x + 10 * k, y + 1.0, x + 10 * k, y + 3.1, 0.3, _INK))
    items.append(("text", x, y + 6.4, 2.4,
                  f"scale check: this bar is {length:g} mm long; print at 100 % (no fit to page)",
                  "start"))


def board_sheet(board: Board, *, page_margin: float = 10.0) -> Sheet:
    """The printable page of a board: the board at true size, its dimensions, a 50 mm bar.

    The board's sheet (pattern plus its white margin, :meth:`Board.extent`) is drawn with a
    thin grey cut line around it; below it the kind, rows and columns (and what they count),
    spacing, marker, overall size and OpenCV pattern size, and a 50 mm scale bar to check the
    printer's scaling. Checkerboards and circle grids are vector drawings; a ChArUco board is
    the raster of ``cv2.aruco.CharucoBoard.generateImage`` (whole pixels per marker bit not
    guaranteed: at least 40 px/mm, drawn without smoothing).
    """
    x0, x1, y0, y1 = board.extent()
    width, height = board.size_mm
    text_block = 40.0
    page_w = max(width, 170.0) + 2 * page_margin
    page_h = height + 2 * page_margin + text_block
    ox = page_margin + (page_w - 2 * page_margin - width) / 2 - x0  # board x -> page x
    oy = page_margin - y0
    items: list = []
    grey = "#b0b0b0"
    for a, b, c, d in ((x0, y0, x1, y0), (x1, y0, x1, y1), (x1, y1, x0, y1), (x0, y1, x0, y0)):
        items.append(("line", ox + a, oy + b, ox + c, oy + d, 0.1, grey))
    s = float(board.spacing)
    if board.kind == "checkerboard":
        for i in range(board.rows):
            for j in range(board.cols):
                if (i + j) % 2 == 0:
                    items.append(("rect", ox + j * s, oy + i * s, s, s, _INK))
    elif board.kind == "charuco":
        raster, _ = _charuco_raster(board)
        items.append(("image", ox, oy, board.cols * s, board.rows * s, raster))
    else:
        for x, y, _ in board.object_points():
            items.append(("circle", ox + x, oy + y, board.marker_mm / 2, _INK))
    counts = {"checkerboard": "squares", "charuco": "squares", "circles": "circles",
              "asymmetric-circles": "circles (cols per row)"}[board.kind]
    spacing_is = {"checkerboard": "square side", "charuco": "square side",
                  "circles": "centre spacing",
                  "asymmetric-circles": "row spacing; circles in a row 2 x apart"}[board.kind]
    lines = [f"nail2nail {board.kind} board: --rows {board.rows} --cols {board.cols} "
             f"({counts}) --spacing {s:g} mm ({spacing_is})"]
    if board.kind == "charuco":
        lines.append(f"marker side {board.marker_mm:g} mm, dictionary {board.dictionary}")
    elif board.kind != "checkerboard":
        lines.append(f"circle diameter {board.marker_mm:g} mm, dark circles on white")
    lines.append(f"overall {width:g} x {height:g} mm (margin {board.margin_mm:g} mm); "
                 f"OpenCV pattern size {board.pattern_size[0]} x {board.pattern_size[1]}")
    lines.append("board frame: origin at the top-left of the pattern, x right, y down; "
                 "keep the sheet flat")
    ty = page_margin + height + 7.0
    for k, line in enumerate(lines):
        items.append(("text", page_margin, ty + 4.2 * k, 2.6, line, "start"))
    _scale_bar(items, page_margin, ty + 4.2 * len(lines) + 1.0)
    return Sheet(page_w, page_h, items, title=lines[0])


def target_wrap_sheet(geometry=None, *, page_margin: float = 10.0) -> Sheet:
    """The printable wrap of the cylindrical calibration target (:class:`TargetGeometry`).

    The cylinder's surface unrolled: ``2π · radius`` wide (the seam at the back, ``θ = ±180°``;
    the middle of the sheet faces ``+Z``, the centre camera, and ``θ`` grows to the right as
    seen from the front, towards ``+X``) and as tall as the cylinder's extent ``y_range`` (world
    ``Y`` up the sheet). Marks are **bright on dark**: the wrap is black, the marks white discs
    of `mark_diameter` (arc length on the surface = diameter on the sheet) at arc length
    ``radius · θ`` of their column and at their row's ``Y``; the key mark a ring (outer and
    inner diameters). Ticks and labels outside the wrap give the column angles and row
    heights; text below gives every dimension and a 50 mm scale bar.
    """

    g = geometry or TargetGeometry()
    r = float(g.radius)
    width = 2 * np.pi * r
    y_lo, y_hi = (float(v) for v in g.y_range)
    height = y_hi - y_lo
    top = page_margin + 8.0  # room for the column labels
    left = page_margin + 12.0  # and the row labels
    page_w = max(width + left + page_margin, 190.0)
    text_block = 70.0
    page_h = top + height + 8.0 + text_block

    def sheet_x(theta_deg):
        return left + width / 2 + r * np.radians(theta_deg)

    def sheet_y(y):
        return top + (y_hi - y)

    items: list = [("rect", left, top, width, height, _INK)]
    for i, y in enumerate(g.row_y):
        for j, theta in enumerate(g.column_angles_deg):
            cx, cy = sheet_x(theta), sheet_y(y)
            if (i, j) == tuple(g.key):
                items.append(("circle", cx, cy, g.key_outer_diameter / 2, _PAPER))
                items.append(("circle", cx, cy, g.key_inner_diameter / 2, _INK))
            else:
                items.append(("circle", cx, cy, g.mark_diameter / 2, _PAPER))
    for j, theta in enumerate(g.column_angles_deg):
        x = sheet_x(theta)
        items.append(("line", x, top - 2.5, x, top - 0.5, 0.2, _INK))
        items.append(("line", x, top + height + 0.5, x, top + height + 2.5, 0.2, _INK))
        items.append(("text", x, top - 3.2, 1.8, f"{j}", "middle"))
        items.append(("text", x, top + height + 4.6, 1.8, f"{j}", "middle"))
    for i, y in enumerate(g.row_y):
        yy = sheet_y(y)
        items.append(("line", left - 2.5, yy, left - 0.5, yy, 0.2, _INK))
        items.append(("text", left - 3.0, yy + 0.7, 1.8, f"Y {y:+.2f}", "end"))
        items.append(("text", left + width + 1.0, yy + 0.7, 1.8, f"row {i}", "start"))
    items.append(("text", left - 1.0, top - 3.2, 1.8, "column", "end"))
    for theta, label in ((-180.0, "seam"), (0.0, "+Z (centre camera)"), (180.0, "seam")):
        x = sheet_x(theta)
        items.append(("line", x, top + height + 0.5, x, top + height + 6.5, 0.2, "#808080"))
        items.append(("text", x, top + height + 9.0, 1.8, label, "middle"))
    key_row, key_col = g.key
    pitch = r * np.radians(g.column_angles_deg[1] - g.column_angles_deg[0])
    lines = [
        f"nail2nail cylinder calibration target wrap: radius {r:g} mm, circumference "
        f"{width:.3f} mm (= the wrap's width),",
        f"height {height:g} mm (the cylinder's extent: Y {y_lo:g} to {y_hi:g} mm)",
        f"marks: bright (white) discs of {g.mark_diameter:g} mm diameter (arc length on the "
        "cylinder) on a dark (black) cylinder;",
        "dark marks on a light cylinder are not found",
        f"rows 0-{g.n_rows - 1}: Y = {', '.join(f'{y:g}' for y in g.row_y)} mm",
        f"columns 0-{g.n_cols - 1}: {', '.join(f'{t:.2f}' for t in g.column_angles_deg)} deg "
        f"from +Z towards +X (arc {pitch:.3f} mm apart)",
        f"key mark: a ring at row {key_row}, column {key_col} (Y {g.row_y[key_row]:g} mm, "
        f"{g.column_angles_deg[key_col]:+.2f} deg): outer diameter {g.key_outer_diameter:g} mm, "
        f"hole {g.key_inner_diameter:g} mm",
        "wrap printed side out on a cylinder of exactly this radius, seam at the back, Y up;",
        "the middle of the wrap faces the centre camera (world +Z), its axis is world Y",
        "matte paper or print; marks must stay sharp and bright under the projector",
    ]
    ty = top + height + 16.0
    for k, line in enumerate(lines):
        items.append(("text", page_margin, ty + 4.0 * k, 2.4, line, "start"))
    _scale_bar(items, page_margin, ty + 4.0 * len(lines) + 1.0)
    return Sheet(page_w, page_h, items, title=lines[0])


def half_turn_ids(board: Board, ids) -> np.ndarray:
    """The labels of features `ids` on `board` turned by half a turn in its plane.

    For a :attr:`Board.half_turn_symmetric` board the turn maps the feature grid onto itself,
    feature ``k`` onto ``N − 1 − k`` (``N`` = :attr:`Board.n_points`; row ``i``, column ``j``
    onto ``R' − 1 − i``, ``C' − 1 − j`` of the ``R' × C'`` feature grid). ``ValueError`` for a
    board without that symmetry.

    Examples
    --------
    >>> board = Board("checkerboard", rows=4, cols=6, spacing=10.0)
    >>> board.half_turn_symmetric, half_turn_ids(board, [0, 1, 14]).tolist()
    (True, [14, 13, 0])
    """
    if not board.half_turn_symmetric:
        raise ValueError(f"board: a {board.kind} board of {board.rows} x {board.cols} has no "
                         "half-turn symmetry")
    return board.n_points - 1 - np.asarray(ids, dtype=np.int64)
