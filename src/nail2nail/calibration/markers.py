"""The cylindrical calibration target: its mark grid, and finding and identifying the marks.

The target (thesis chapter four, Tables 2 and 3) is a cylinder of radius 10.744 mm about the
world ``Y`` axis with bright reference marks on a grid: columns every 17.067° around the axis
(``±8.533°, ±25.60°, ±42.67°`` from ``+Z`` as in the tables, continued to ``±59.73°, ±76.80°``),
rows every 6.35 mm (``Y = −12.7 … 19.05`` mm). Grid index ``(row, col)``: ``row`` 0…5 from
``Y = −12.7`` upwards, ``col`` 0…9 from −76.8° towards ``+X``.

Mark design (chosen so that software identifies every mark from the image alone):

- every mark is a bright disc of diameter 1.2 mm (drawn on the cylinder by arc length) on a
  grey surface, small enough that its image centroid sits within a fraction of a pixel of the
  projection of its centre;
- one **key mark** at ``(row 2, col 5)`` (``Y = 0``, +8.53°), visible to all three cameras, is a
  ring (outer diameter 1.6 mm, hole 0.8 mm);
- the marks are **bright on a dark cylinder** (dark marks are not found); the cylinder is 95 mm
  long (``y_range``, ``Y = −45 … 50`` mm). ``nail2nail print-target cylinder`` prints its wrap
  (:func:`nail2nail.calibration.boards.target_wrap_sheet`, ``docs/real-scanner.md``).

:func:`find_target_marks` thresholds the image against a local background (grey opening),
measures sub-pixel centroids, recognises the key by its hole, groups the marks into rows (by
image ``y``) and columns (by image ``x``; the cameras look perpendicular to the axis, which runs
up the image), and counts rows and columns from the key. The only prior is the nominal rig
layout: the target axis runs along the image columns with ``+Y`` up and ``+X`` to the right, and
the approximate mark size in pixels. No projection of known geometry is used.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.ndimage as ndi

from nail2nail._validation import as_float_array

__all__ = ["TargetGeometry", "TargetMarks", "find_target_marks", "mark_diameter_px"]


@dataclass(frozen=True)
class TargetGeometry:
    """Geometry of the cylindrical mark target (world mm, angles in degrees from ``+Z``).

    Attributes
    ----------
    radius : float
        Cylinder radius, mm (thesis: 10.744).
    column_angles_deg : tuple of float
        Azimuths of the mark columns about ``Y`` from ``+Z`` towards ``+X``, ascending.
    row_y : tuple of float
        ``Y`` of the mark rows, ascending, mm.
    mark_diameter : float
        Diameter of a plain mark, mm (arc length on the surface).
    key : (int, int)
        ``(row, col)`` of the key mark.
    key_outer_diameter, key_inner_diameter : float
        Ring of the key mark, mm.
    y_range : (float, float)
        Extent of the cylinder along ``Y``, mm.
    """

    radius: float = 10.7442
    column_angles_deg: tuple[float, ...] = tuple(17.0668 * (k + 0.5) for k in range(-5, 5))
    row_y: tuple[float, ...] = tuple(-12.7 + 6.35 * k for k in range(6))
    mark_diameter: float = 1.2
    key: tuple[int, int] = (2, 5)
    key_outer_diameter: float = 1.6
    key_inner_diameter: float = 0.8
    y_range: tuple[float, float] = (-45.0, 50.0)

    @property
    def n_rows(self) -> int:
        """Number of mark rows."""
        return len(self.row_y)

    @property
    def n_cols(self) -> int:
        """Number of mark columns."""
        return len(self.column_angles_deg)

    def mark_world(self, grid) -> np.ndarray:
        """World XYZ ``(N, 3)`` of mark centres for grid indices ``(N, 2)`` ``(row, col)``.

        Examples
        --------
        >>> TargetGeometry().mark_world([[5, 2]]).round(3).tolist()
        [[-7.282, 19.05, 7.9]]
        """
        grid = np.asarray(grid, dtype=int).reshape(-1, 2)
        if np.any(grid < 0) or np.any(grid[:, 0] >= self.n_rows) or np.any(
            grid[:, 1] >= self.n_cols
        ):
            raise ValueError(
                f"grid: indices must lie in rows 0..{self.n_rows - 1}, cols 0..{self.n_cols - 1}"
            )
        theta = np.radians(np.asarray(self.column_angles_deg))[grid[:, 1]]
        y = np.asarray(self.row_y)[grid[:, 0]]
        return np.column_stack([self.radius * np.sin(theta), y, self.radius * np.cos(theta)])

    def signed_distance(self, xyz) -> np.ndarray:
        """Signed distance ``(...)`` in mm of world points ``(..., 3)`` from the cylinder's
        surface (``hypot(X, Z) − radius``; positive outside): the dense constraint of
        :func:`nail2nail.calibration.target.calibrate_rig_joint`.

        Examples
        --------
        >>> TargetGeometry().signed_distance([[0.0, 5.0, 11.0]]).round(4).tolist()
        [0.2558]
        """
        xyz = np.asarray(xyz, dtype=float)
        return np.hypot(xyz[..., 0], xyz[..., 2]) - self.radius

    def all_marks(self) -> tuple[np.ndarray, np.ndarray]:
        """Every mark: ``grid (N, 2) int`` and ``xyz_world (N, 3)``, row-major."""
        rows, cols = np.meshgrid(np.arange(self.n_rows), np.arange(self.n_cols), indexing="ij")
        grid = np.column_stack([rows.ravel(), cols.ravel()])
        return grid, self.mark_world(grid)


@dataclass
class TargetMarks:
    """Marks found in one camera image.

    Attributes
    ----------
    xy : (N, 2) float64
        Sub-pixel centroids ``(x, y)``, camera px (pixel-centre convention).
    grid : (N, 2) int
        ``(row, col)`` identity of each mark.
    xyz_world : (N, 3) float64
        World coordinates of the identified marks, mm.
    is_key : (N,) bool
        The key mark.
    size_px : (N, 2) float64
        Width and height of each mark's region, px.
    """

    xy: np.ndarray
    grid: np.ndarray
    xyz_world: np.ndarray
    is_key: np.ndarray
    size_px: np.ndarray

    def __len__(self) -> int:
        return len(self.xy)


def mark_diameter_px(camera, target: TargetGeometry | None = None) -> float:
    """Approximate diameter of a mark in a camera's image, px (nominal-geometry prior).

    Uses the focal length and the distance from the camera centre to the target axis.
    """
    target = target or TargetGeometry()
    center = camera.center
    distance = float(np.hypot(center[0], center[2])) - target.radius
    return float(camera.K[1, 1] * target.mark_diameter / distance)


def _cluster_1d(values: np.ndarray, gap: float) -> np.ndarray:
    """Cluster labels (0, 1, … in ascending order) splitting sorted values at gaps > `gap`."""
    order = np.argsort(values)
    breaks = np.concatenate([[0], np.cumsum(np.diff(values[order]) > gap)])
    labels = np.empty(len(values), dtype=int)
    labels[order] = breaks
    return labels


def _refine_centroids(img, labels, region, xy, slices, d: float) -> np.ndarray:
    """Centroids ``(K, 2)`` of marks measured against a local background (see `refine`).

    For each mark (label ``region[k]``): the background is a plane in ``x, y`` fitted to the
    surface pixels between ``grow`` and ``grow + band`` px outside the mark's filled region
    (other marks excluded); the covered fraction of a pixel is its excess over that background
    relative to the mark's own plateau (the median over the region eroded by 2 px), clipped to
    ``[0, 1]``, over the region grown by ``grow`` px. A mark whose band is too small keeps its
    centroid.
    """
    grow = 3
    band = max(4, round(0.3 * d))
    margin = grow + band + 1
    H, W = img.shape
    out = xy.copy()
    for k, label in enumerate(region):
        sl = slices[label - 1]
        r0, r1 = max(sl[0].start - margin, 0), min(sl[0].stop + margin, H)
        c0, c1 = max(sl[1].start - margin, 0), min(sl[1].stop + margin, W)
        lab = labels[r0:r1, c0:c1]
        win = img[r0:r1, c0:c1]
        own = lab == label
        filled = ndi.binary_fill_holes(own)
        inner = ndi.binary_dilation(filled, iterations=grow)
        outer = ndi.binary_dilation(filled, iterations=grow + band)
        others = ndi.binary_dilation((lab > 0) & ~own, iterations=grow)
        ring = outer & ~inner & ~others
        if np.count_nonzero(ring) < 12:
            continue
        rows, cols = np.nonzero(ring)
        A = np.column_stack([np.ones(rows.size), cols, rows]).astype(float)
        coef, *_ = np.linalg.lstsq(A, win[ring], rcond=None)
        rr, cc = np.mgrid[r0:r1, c0:c1]
        background = coef[0] + coef[1] * (cc - c0) + coef[2] * (rr - r0)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = (win - background) / background
        core = ndi.binary_erosion(own, iterations=2)
        plateau = float(np.median(ratio[core if np.any(core) else own]))
        if not (np.all(np.isfinite(ratio[inner])) and plateau > 0):
            continue
        weight = np.where(inner, np.clip(ratio / plateau, 0.0, 1.0), 0.0)
        total = weight.sum()
        out[k] = np.sum(weight * cc) / total, np.sum(weight * rr) / total
    return out


def find_target_marks(
    image,
    *,
    mark_diameter_px: float,
    target: TargetGeometry | None = None,
    contrast: float = 0.6,
    min_aspect: float = 0.45,
    refine: bool = False,
) -> TargetMarks:
    """Find, measure and identify the target's marks in a uniformly lit camera image.

    Parameters
    ----------
    image : (H, W) array
        Camera image of the target under uniform (e.g. full-white) projector light, the mean of
        one frequency's N phase-shifted frames, or the albedo image of a phase decode; any
        numeric dtype.
    mark_diameter_px : float
        Approximate image diameter of a plain mark (:func:`mark_diameter_px` gives it from a
        nominal camera model).
    target : TargetGeometry, optional
    contrast : float
        A pixel belongs to a mark where ``image − background > contrast · background`` (the
        marks are about three times as bright as the target surface).
    min_aspect : float
        Marks whose width/height ratio is smaller (seen more obliquely than about 63° near the
        silhouette, where the image centroid drifts from the projected centre) are dropped.
    refine : bool
        Measure each mark's centroid again against a background fitted (a plane in ``x, y``)
        to a band of surface pixels around that mark, and with its own plateau: the image-wide
        background (a grey opening) is biased near the edge of the lit area and where the
        shading changes fast, which moved centroids by up to 0.3 px at full scale (issue 9);
        refined, they lie within ~0.01 px (RMS) of the centroid of the mark's projected area.
        Use it with a calibration that models that centroid
        (:func:`nail2nail.calibration.target.calibrate_rig_joint`'s ``target``); a calibration that
        compares centroids with projected mark centres is left with the larger geometric bias
        of oblique marks, which the image-wide measurement happens to offset in part.

    Returns
    -------
    TargetMarks
        Identified marks sorted by ``(row, col)``.

    Raises
    ------
    ValueError
        If the image is not 2-D, the mark size is not positive, or no key mark is found.
    """
    target = target or TargetGeometry()
    img = as_float_array(image, "image", dtype=np.float64)
    if img.ndim != 2:
        raise ValueError(f"image: expected a 2-D (H, W) array, got shape {img.shape}")
    if not mark_diameter_px > 2:
        raise ValueError(
            f"mark_diameter_px: expected a diameter > 2 px, got {mark_diameter_px!r}"
        )
    d = float(mark_diameter_px)
    size = int(2 * round(1.2 * d * target.key_outer_diameter / target.mark_diameter) + 1)
    background = ndi.grey_opening(img, size=(size, size))
    background = ndi.uniform_filter(background, size=size // 2 * 2 + 1)
    floor = 0.02 * float(np.percentile(img, 99.5))
    if not floor > 0:
        raise ValueError("image: no bright marks found (the image is dark)")
    excess = img - background
    ratio = excess / np.maximum(background, floor)
    mask = ratio > contrast
    mask = ndi.binary_opening(mask, iterations=1)
    labels, n = ndi.label(mask)
    if n == 0:
        raise ValueError("image: no bright marks found (the marks must be bright discs on a "
                         "darker cylinder)")
    index = np.arange(1, n + 1)
    filled = ndi.binary_fill_holes(mask)
    filled_labels, _ = ndi.label(filled)
    # per region: weights ~ covered fraction of the pixel (ratio saturates inside the mark)
    inside = np.median(ratio[mask])
    weight = np.clip(ratio / inside, 0.0, 1.0)
    # grow each region by a pixel so that partially covered edge pixels count
    grown = ndi.grey_dilation(labels, size=(3, 3))
    grown = np.where(labels > 0, labels, grown)
    rows, cols = np.indices(img.shape)
    w_sum = ndi.sum(weight, grown, index)
    cx = ndi.sum(weight * cols, grown, index) / w_sum
    cy = ndi.sum(weight * rows, grown, index) / w_sum
    slices = ndi.find_objects(labels)
    width = np.array([s[1].stop - s[1].start for s in slices], dtype=float)
    height = np.array([s[0].stop - s[0].start for s in slices], dtype=float)
    touches = np.array([s[0].start == 0 or s[1].start == 0 or s[0].stop == img.shape[0]
                        or s[1].stop == img.shape[1] for s in slices])
    area = ndi.sum(mask, labels, index)
    # filled area of each region: the filled label under the region's centre pixel
    pick = np.array([filled_labels[s][labels[s] == i + 1][0] for i, s in enumerate(slices)])
    filled_area = ndi.sum(filled, filled_labels, pick)
    hole_fraction = 1.0 - area / np.maximum(filled_area, 1)
    key_d = d * target.key_outer_diameter / target.mark_diameter
    keep = (
        (height > 0.75 * d) & (height < 1.3 * key_d)
        & (width >= min_aspect * height) & (width <= 1.3 * height) & ~touches
    )
    if not np.any(keep):
        raise ValueError(
            f"image: no mark of the expected size ({d:.1f} px across) found; the marks must be "
            "bright (white) discs on a darker cylinder (dark marks are not found), and "
            "mark_diameter_px (nail2nail calibrate --mark-diameter-px) their approximate image "
            "diameter")
    cx, cy, width, height, hole_fraction, region = (
        a[keep] for a in (cx, cy, width, height, hole_fraction, index)
    )
    is_key = hole_fraction > 0.05
    if not np.any(is_key):
        raise ValueError("image: the key mark (ring) was not found; cannot identify the marks")
    if np.count_nonzero(is_key) > 1:
        # keep the ring with the largest hole
        best = np.argmax(np.where(is_key, hole_fraction, -1.0))
        is_key = np.zeros_like(is_key)
        is_key[best] = True
    row_label = _cluster_1d(-cy, 1.5 * d)  # rows ascend with world Y, i.e. up the image
    col_label = _cluster_1d(cx, 0.4 * d)
    # a column (row) is a line of several marks: a lone blob is not a mark of the grid
    lone = (np.bincount(col_label)[col_label] < 2) | (np.bincount(row_label)[row_label] < 2)
    lone &= ~is_key
    if np.any(lone):
        cx, cy, width, height, is_key, region = (
            a[~lone] for a in (cx, cy, width, height, is_key, region)
        )
        row_label = _cluster_1d(-cy, 1.5 * d)
        col_label = _cluster_1d(cx, 0.4 * d)
    k = int(np.flatnonzero(is_key)[0])
    grid = np.column_stack([
        target.key[0] + row_label - row_label[k],
        target.key[1] + col_label - col_label[k],
    ])
    valid = (
        (grid[:, 0] >= 0) & (grid[:, 0] < target.n_rows)
        & (grid[:, 1] >= 0) & (grid[:, 1] < target.n_cols)
    )
    codes = grid[:, 0] * target.n_cols + grid[:, 1]
    unique, counts = np.unique(codes[valid], return_counts=True)
    valid &= ~np.isin(codes, unique[counts > 1])
    order = np.flatnonzero(valid)[np.argsort(codes[valid], kind="stable")]
    grid = grid[order]
    xy = np.column_stack([cx, cy])[order]
    if refine:
        xy = _refine_centroids(img, labels, region[order], xy, slices, d)
    return TargetMarks(
        xy=xy,
        grid=grid,
        xyz_world=target.mark_world(grid),
        is_key=is_key[order],
        size_px=np.column_stack([width, height])[order],
    )
