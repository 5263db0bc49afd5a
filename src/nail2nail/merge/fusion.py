"""The super scan: one nail-to-nail point cloud and mesh fused from all cameras.

Every camera's scan is a grid of world points. Where two cameras see the same surface, the
projector-space correspondence of :mod:`nail2nail.merge` pairs their pixels; :func:`fuse_scans`
keeps each surface point once, on the grid of the camera with the highest priority that sees it,
and moves it to the weighted mean of every camera's point for it. The weight of a camera's point
is its fringe modulation × the cosine of its viewing angle × a feather that falls to zero at the
edge of the camera's valid region, so the fused surface joins the single-camera surfaces beside
it without a step. Only reliable pairs are averaged (:data:`nail2nail.merge.REJECT_REASONS`:
a rejected pair keeps the better-viewed camera's point), and points that stand off their
neighbours (spikes) or, left unfused, off the other cameras' surface are dropped. Holes stay
holes; the mesh joins neighbouring pixels of one grid (two triangles per 2 × 2 block, no
triangle with a long edge), so the fused region is meshed from one camera.

The **super mat5** (the thesis's merged file set, chapter five) is defined here as one mat5 grid
holding the cameras side by side, left to right in scan order, separated by `gap_px` invalid
columns: each column block is a camera's own pixel grid with the fused world points on the pixels
it owns and NaN (intensity 0) elsewhere, so every valid pixel of the super mat5 is exactly one
vertex of the super scan and legacy tools that mesh a mat5 grid mesh each camera separately.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import scipy.ndimage
import scipy.spatial

from .._interpolate import bilinear
from .._validation import as_int
from ..reconstruction import Scan
from .correspondence import (
    REJECT_REASONS,
    Correspondence,
    _check_scan,
    _correspond,
    grid_normals,
    valid_mask,
    view_cosine,
)

__all__ = [
    "SuperScan",
    "fuse_scans",
    "grid_mesh",
    "grid_normals",
    "spikes",
    "super_mat5_scan",
    "view_weights",
    "write_super_mat5",
    "write_super_ply",
]


def view_weights(
    scan: Scan,
    *,
    normals=None,
    feather_px: float = 8.0,
    use_modulation: bool = True,
    smooth_px: float = 0.0,
) -> np.ndarray:
    """Fusion weight of each pixel: modulation × cos(viewing angle) × edge feather.

    Parameters
    ----------
    scan : Scan
    normals : (H, W, 3) float, optional
        Surface normals (:func:`grid_normals` if omitted).
    feather_px : float
        Distance from the edge of the valid region (or of the image) over which the weight ramps
        from 0 to 1, px; 0 for no feather.
    use_modulation : bool
        Include the fringe modulation (``False``: a purely geometric score).
    smooth_px : float
        Gaussian smoothing (σ, px) of the cosine over the valid pixels; 0 for none.

    Returns
    -------
    (H, W) float64
        Non-negative weights; 0 on invalid pixels. Without ``scan.camera_center`` the cosine
        factor is 1.
    """
    _check_scan(scan, "scan")
    valid = valid_mask(scan)
    weight = valid.astype(np.float64)
    if use_modulation:
        weight *= np.clip(np.nan_to_num(np.asarray(scan.modulation, np.float64)), 0, None)
    if scan.camera_center is not None:
        weight *= view_cosine(scan, normals=normals, smooth_px=smooth_px)
    weight *= _feather(valid, feather_px)
    weight[~valid] = 0.0
    return weight


def _feather(valid: np.ndarray, feather_px: float) -> np.ndarray | float:
    """Ramp from 0 at the edge of `valid` (or of the image) to 1 at `feather_px` inside."""
    if feather_px <= 0:
        return 1.0
    distance = scipy.ndimage.distance_transform_edt(np.pad(valid, 1))[1:-1, 1:-1]
    return np.clip((distance - 0.5) / feather_px, 0, 1)


def spikes(xyz, valid, *, spike_mm: float = 0.05) -> np.ndarray:
    """Points that stand off the surface of their neighbours: lone decoding errors.

    For each valid pixel, the lines through it (row, column, two diagonals) whose two
    neighbours are valid; with at least two such lines, the local normal ``n`` is the
    normalised sum of the cross products of their chords (the pixel itself is not used), and
    the offset on a line is ``|n · (X − (X₋ + X₊) / 2)|``. A pixel is a spike when the offset
    exceeds `spike_mm` on every line (the smallest: a ridge, a step or a grazing view bends the
    surface along one direction, not across all). On a smooth surface the offset is the
    curvature term ``κ h² / 2`` (h the pixel spacing: about 4 µm on the finger's ridges at full
    resolution) plus the noise. Pixels with fewer than two lines (the outermost row of a valid
    region) are not tested: with one line, a spike and its neighbour look alike.

    Parameters
    ----------
    xyz : (H, W, 3) float
        World points, mm.
    valid : (H, W) bool
    spike_mm : float
        Largest accepted offset, mm.

    Returns
    -------
    (H, W) bool

    Examples
    --------
    >>> rr, cc = np.mgrid[0:5, 0:5].astype(float)
    >>> xyz = np.stack([cc, -rr, 0 * cc], -1)
    >>> xyz[2, 2, 2] = 0.2
    >>> np.argwhere(spikes(xyz, np.ones((5, 5), bool))).tolist()
    [[2, 2]]
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    valid = np.asarray(valid, dtype=bool) & np.isfinite(xyz).all(axis=-1)
    h, w = valid.shape
    pad = np.pad(np.where(valid[..., None], xyz, np.nan), ((1, 1), (1, 1), (0, 0)),
                 constant_values=np.nan).reshape(-1, 3)
    rr, cc = np.nonzero(valid)
    centre = (rr + 1) * (w + 2) + cc + 1  # flat indices into the padded grid
    x = xyz[rr, cc]
    steps = ((1, 0), (0, 1), (1, 1), (1, -1))
    chords, mids = [], []
    for dr, dc in steps:
        before, after = pad[centre - dr * (w + 2) - dc], pad[centre + dr * (w + 2) + dc]
        chords.append(after - before)
        mids.append(0.5 * (before + after))
    normal = np.zeros_like(x)
    for k in range(len(steps)):
        for m in range(k + 1, len(steps)):
            # orient every pair's cross product alike: by the sign of the pixel steps' own
            sign = np.sign(steps[k][0] * steps[m][1] - steps[k][1] * steps[m][0])
            normal += np.nan_to_num(sign * np.cross(chords[k], chords[m]))
    with np.errstate(invalid="ignore", divide="ignore"):
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    smallest = np.full(rr.size, np.inf)
    lines = np.zeros(rr.size, dtype=np.int8)
    for mid in mids:
        offset = np.abs(np.einsum("nk,nk->n", x - mid, normal))
        lines += np.isfinite(mid[:, 0])
        smallest = np.fmin(smallest, offset)  # NaN (a missing neighbour) leaves it
    out = np.zeros((h, w), dtype=bool)
    out[rr, cc] = (lines >= 2) & np.isfinite(smallest) & (smallest > spike_mm)
    return out


def grid_mesh(xyz, keep, *, max_edge_mm: float, normals=None) -> tuple[np.ndarray, np.ndarray]:
    """Triangles joining neighbouring kept pixels of one grid.

    Each 2 × 2 block gives the triangles (top-left, bottom-left, top-right) and (top-right,
    bottom-left, bottom-right) when their three pixels are kept and no edge is longer than
    `max_edge_mm`; each triangle is wound counter-clockwise seen from the side `normals` point to.

    Parameters
    ----------
    xyz : (H, W, 3) float
        World points, mm.
    keep : (H, W) bool
        Pixels that are vertices.
    max_edge_mm : float
        Longest edge of a kept triangle, mm (depth discontinuities are not bridged).
    normals : (H, W, 3) float, optional
        Vertex normals used for the winding (:func:`grid_normals` if omitted).

    Returns
    -------
    vertex_index : (H, W) int64
        Index of each kept pixel among the vertices (row-major order), −1 elsewhere.
    faces : (F, 3) int64
        Vertex indices of each triangle.

    Examples
    --------
    >>> rr, cc = np.mgrid[0:2, 0:3].astype(float)
    >>> _, faces = grid_mesh(np.stack([cc, -rr, 0 * cc], -1), np.ones((2, 3), bool), max_edge_mm=2)
    >>> faces.shape
    (4, 3)
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    keep = np.asarray(keep, dtype=bool) & np.isfinite(xyz).all(axis=-1)
    index = np.full(keep.shape, -1, dtype=np.int64)
    index[keep] = np.arange(np.count_nonzero(keep))
    if normals is None:
        normals = grid_normals(xyz)
    tl, tr, bl, br = index[:-1, :-1], index[:-1, 1:], index[1:, :-1], index[1:, 1:]
    tris = np.concatenate([
        np.stack([tl, bl, tr], axis=-1).reshape(-1, 3),
        np.stack([tr, bl, br], axis=-1).reshape(-1, 3),
    ])
    tris = tris[(tris >= 0).all(axis=1)]
    pts = xyz[keep]
    a, b, c = pts[tris[:, 0]], pts[tris[:, 1]], pts[tris[:, 2]]
    longest = np.maximum.reduce([
        np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1), np.linalg.norm(a - c, axis=1)
    ])
    tris = tris[longest <= max_edge_mm]
    a, b, c = pts[tris[:, 0]], pts[tris[:, 1]], pts[tris[:, 2]]
    vn = np.asarray(normals, dtype=np.float64)[keep][tris].sum(axis=1)
    flip = np.einsum("ij,ij->i", np.cross(b - a, c - a), np.nan_to_num(vn)) < 0
    tris[flip] = tris[flip][:, [0, 2, 1]]
    return index, tris


@dataclass
class SuperScan:
    """A nail-to-nail scan fused from several cameras.

    Attributes
    ----------
    scans : list of Scan
        Per camera, its grid with fused world points on the pixels it owns; ``mask`` marks them
        and ``xyz`` is NaN elsewhere.
    normals : list of (H, W, 3) float32
        Per camera, unit normals of the fused grid (NaN off the owned pixels).
    n_views : list of (H, W) uint8
        Per camera, the number of cameras fused into each owned pixel (1: seen by its owner only).
    vertices : (N, 3) float32
        Every owned pixel of every camera, world mm (camera order, then row-major).
    vertex_normals : (N, 3) float32
    colors : (N, 3) uint8
        Albedo as grey.
    faces : (F, 3) int32
        Triangles, indices into `vertices`.
    camera : (N,) int16
        Index of the camera each vertex comes from.
    pixel : (N, 2) int32
        ``(row, col)`` of each vertex in its camera.
    correspondences : dict
        The :class:`~nail2nail.merge.Correspondence` of each ordered pair ``(i, j)`` used.
    priority : list of int
        Camera indices, highest priority first.
    duplicates_removed : dict[str, int]
        Per camera, owned points dropped as 3D duplicates of a higher-priority camera's points.
    points_rejected : dict[str, dict[str, int]]
        Per camera, points dropped as ``"spike"`` (before fusion, :func:`spikes`) and as
        ``"off_surface"`` (unfused points off the other cameras' fused surface).
    """

    scans: list[Scan]
    normals: list[np.ndarray]
    n_views: list[np.ndarray]
    vertices: np.ndarray
    vertex_normals: np.ndarray
    colors: np.ndarray
    faces: np.ndarray
    camera: np.ndarray
    pixel: np.ndarray
    correspondences: dict = field(default_factory=dict)
    priority: list[int] = field(default_factory=list)
    duplicates_removed: dict = field(default_factory=dict)
    points_rejected: dict = field(default_factory=dict)

    @property
    def n_vertices(self) -> int:
        """Number of vertices."""
        return int(self.vertices.shape[0])

    def summary(self) -> dict:
        """JSON-ready counts: vertices, faces, per camera owned and fused pixels."""
        return {
            "vertices": self.n_vertices,
            "faces": int(self.faces.shape[0]),
            "priority": [self.scans[i].name for i in self.priority],
            "duplicates_removed": dict(self.duplicates_removed),
            "points_rejected": {k: dict(v) for k, v in self.points_rejected.items()},
            "rejected_pairs": {
                f"{i}-{j}": {k: int(m.dropped.get(k, 0)) for k in REJECT_REASONS}
                for (i, j), m in self.correspondences.items()
            },
            "cameras": {
                s.name: {"owned": int(s.mask.sum()), "fused": int(np.count_nonzero(v > 1))}
                for s, v in zip(self.scans, self.n_views, strict=True)
            },
        }


def _off_surface(points, score, ref, ref_trust, *, radius, surface_mm, k=8) -> np.ndarray:
    """Points farther than `surface_mm` from the plane of their `k` nearest reference points
    (within `radius`, at least 3), where those are more trusted than the point (mean trust)."""
    tree = scipy.spatial.cKDTree(ref)
    out = np.zeros(points.shape[0], dtype=bool)
    near = np.flatnonzero(np.isfinite(tree.query(points, distance_upper_bound=radius)[0]))
    dist, idx = tree.query(points[near], k=k, distance_upper_bound=radius)
    found = np.isfinite(dist)
    enough = found.sum(axis=1) >= 3
    test = near[enough]
    if not test.size:
        return out
    idx, found, p = idx[enough], found[enough], points[test]
    nb = ref[np.where(found, idx, 0)]
    w = found[..., None].astype(np.float64)
    centroid = (nb * w).sum(axis=1) / w.sum(axis=1)
    d = (nb - centroid[:, None]) * w
    values, vectors = np.linalg.eigh(np.einsum("nki,nkj->nij", d, d))
    normal = vectors[:, :, 0]  # the smallest eigenvalue's vector: the plane's normal
    # points along a line (a grazing view's single row) define no plane
    planar = values[:, 1] > 0.05 * values[:, 2]
    offset = np.abs(np.einsum("ni,ni->n", p - centroid, normal))
    trust = np.where(found, ref_trust[np.where(found, idx, 0)], 0.0)
    mean_trust = trust.sum(axis=1) / found.sum(axis=1)
    out[test] = planar & (offset > surface_mm) & (mean_trust > score[test])
    return out


def fuse_scans(
    scans,
    *,
    priority=None,
    ownership: str = "angle",
    max_residual_px: float = 0.5,
    border_px: int = 1,
    feather_px: float = 8.0,
    max_edge_mm: float | None = None,
    dedupe_mm: float | None = None,
    spike_mm: float | None = 0.05,
    surface_mm: float | None = 0.05,
    max_view_angle_deg: float | None = 70.0,
    min_relative_modulation: float | None = 1 / 3,
    outlier_mm: float | None = 0.025,
    outlier_mad: float = 4.0,
) -> SuperScan:
    """Fuse the scans of several cameras into one nail-to-nail point cloud and mesh.

    0. Spikes (:func:`spikes`: points off their neighbours' surface by more than `spike_mm`)
       are dropped from each camera's scan.
    1. Correspondence of every ordered pair of cameras in projector space
       (:func:`nail2nail.merge.correspond`, every pixel), with the unreliable pairs rejected
       (a view beyond `max_view_angle_deg`, modulation below `min_relative_modulation` of the
       camera's median, a distance that is a local outlier: `outlier_mm`, `outlier_mad`).
    2. Ownership (duplicates removed): a pixel is dropped as a duplicate when another camera has
       a correspondence for it (kept or rejected: a rejected pair is still the same surface
       point, only too inaccurate to average) and views it better (``ownership="angle"``: a
       larger smoothed cos(viewing angle) × edge feather, `priority` breaking ties) or has a
       higher `priority` (``ownership="priority"``; for rejected pairs the better view decides
       in both modes); then points within `dedupe_mm` of a point kept by a camera of higher
       priority go too. The rest are the super scan's vertices, so an overlap is meshed from
       one camera.
    3. Fusion: each owned pixel moves to the weighted mean of its own point and its
       corresponding points in every other camera, over the kept pairs only (weights:
       :func:`view_weights`, interpolated at the sub-pixel correspondence). A point whose pair
       was rejected keeps the better-viewed camera's point: it is not averaged.
    4. A point left unfused (no kept pair) that lies farther than `surface_mm` from the plane
       of the other cameras' points around it (8 nearest within 3 pixel spacings) is dropped
       when those are confirmed (a kept pair closer than `surface_mm`) or view the surface
       better (the ownership score): a corrupted point at a mask edge or a shadow border,
       where no pair could be tested. Of two disagreeing lone points the better view stays.
    5. Normals of the fused grids (:func:`grid_normals`) and a mesh per camera grid
       (:func:`grid_mesh`).

    Parameters
    ----------
    scans : sequence of Scan
        At least one; names should differ.
    priority : sequence of int, optional
        Camera indices, highest priority first. Default: by decreasing number of valid pixels
        (the camera that sees most of the finger first).
    ownership : {"angle", "priority"}
        Which camera keeps a point seen by several.
    max_residual_px, border_px :
        Passed to :func:`~nail2nail.merge.correspond` (the overlap test).
    feather_px : float
        Width of the weight ramp at the edge of each camera's valid region, px.
    max_edge_mm : float, optional
        Longest mesh edge; default 4 × the median distance of horizontally adjacent pixels.
    dedupe_mm : float, optional
        After ownership, a point closer than this to a point owned by a camera of higher
        `priority` is dropped too (edges of valid regions, where correspondences are refused);
        default half the pixel spacing, 0 to skip.
    spike_mm : float or None
        Spike threshold of step 0, mm; None skips it.
    surface_mm : float or None
        Off-surface threshold of step 4, mm; None skips it.
    max_view_angle_deg, min_relative_modulation, outlier_mm, outlier_mad :
        The rejection tests, passed to :func:`~nail2nail.merge.correspond`; None skips one.

    Returns
    -------
    SuperScan

    Raises
    ------
    ValueError
        For no scans, a bad priority, or a scan without valid pixels.
    """
    scans = list(scans)
    if not scans:
        raise ValueError("scans: expected at least one Scan")
    for i, s in enumerate(scans):
        _check_scan(s, f"scans[{i}]")
    n = len(scans)
    valid = [valid_mask(s) for s in scans]
    for s, v in zip(scans, valid, strict=True):
        if not v.any():
            raise ValueError(f"scans: {s.name!r} has no valid pixels")
    if priority is None:
        priority = sorted(range(n), key=lambda i: (-int(valid[i].sum()), i))
    priority = [int(p) for p in priority]
    if sorted(priority) != list(range(n)):
        raise ValueError(f"priority: expected a permutation of 0..{n - 1}, got {priority}")
    border_px = as_int(border_px, "border_px", minimum=1)
    if ownership not in ("angle", "priority"):
        raise ValueError(f"ownership: expected 'angle' or 'priority', got {ownership!r}")
    for name, value in (("spike_mm", spike_mm), ("surface_mm", surface_mm)):
        if value is not None and not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name}: expected a positive number or None, got {value}")
    rank = {cam: k for k, cam in enumerate(priority)}

    normals0 = [grid_normals(s.xyz, camera_center=s.camera_center) for s in scans]
    spikes_removed = dict.fromkeys((s.name for s in scans), 0)
    if spike_mm is not None:
        for i, s in enumerate(scans):
            bad = spikes(s.xyz, valid[i], spike_mm=spike_mm)
            spikes_removed[s.name] = int(bad.sum())
            if bad.any():
                valid[i] = valid[i] & ~bad
                scans[i] = replace(s, mask=valid[i], xyz=np.where(valid[i][..., None], s.xyz,
                                                                   np.float32(np.nan)))
                normals0[i] = grid_normals(scans[i].xyz, camera_center=s.camera_center)
    weights = [view_weights(s, normals=nm, feather_px=feather_px)
               for s, nm in zip(scans, normals0, strict=True)]
    # the smoothed view cosine serves the rejection test and the ownership score
    quality = {id(s): [view_cosine(s, normals=nm, smooth_px=2.0), None]
               for s, nm in zip(scans, normals0, strict=True) if s.camera_center is not None}
    corr: dict[tuple[int, int], Correspondence] = {}
    for i in range(n):
        for j in range(n):
            if i != j:
                corr[i, j] = _correspond(
                    scans[i], scans[j], stride=1, max_residual_px=max_residual_px,
                    border_px=border_px, max_jump_px=2.0, refine=True, method="kdtree",
                    workers=-1, max_view_angle_deg=max_view_angle_deg,
                    min_relative_modulation=min_relative_modulation, outlier_mm=outlier_mm,
                    outlier_mad=outlier_mad, outlier_block_px=32, quality=quality)

    scores = []  # view_weights(use_modulation=False, smooth_px=2) from the cached cosine
    for s, v in zip(scans, valid, strict=True):
        cos = quality[id(s)][0] if id(s) in quality else v.astype(np.float64)
        scores.append(np.where(v, cos * _feather(v, feather_px), 0.0))
    keeps = []
    for i in range(n):
        keep = valid[i].copy()
        for j in range(n):
            if j == i:
                continue
            kept = corr[i, j]
            n_kept = kept.n_pairs
            pairs = kept.all_pairs()
            rc = pairs.parent_rc
            other, _, _ = bilinear(scores[j], *pairs.child_rc.T)
            mine = scores[i][rc[:, 0], rc[:, 1]]
            lose = (other > mine) | ((other == mine) & (rank[j] < rank[i]))
            if ownership == "priority":  # kept pairs by priority, rejected by the better view
                lose[:n_kept] = rank[j] < rank[i]
            keep[rc[lose, 0], rc[lose, 1]] = False
        keeps.append(keep)

    spacing = np.concatenate([
        np.linalg.norm(np.diff(s.xyz, axis=1), axis=-1).ravel() for s in scans
    ])
    spacing = float(np.median(spacing[np.isfinite(spacing)])) if np.isfinite(spacing).any() \
        else np.inf
    if max_edge_mm is None:
        max_edge_mm = 4.0 * spacing
    if dedupe_mm is None:
        dedupe_mm = 0.5 * spacing
    # duplicates the correspondence cannot see (edges of valid regions): points closer than
    # dedupe_mm to a point of a camera ranked higher are dropped
    removed = dict.fromkeys((s.name for s in scans), 0)
    if dedupe_mm > 0 and np.isfinite(dedupe_mm):
        for k in range(1, n):
            i = priority[k]
            above = np.concatenate([scans[j].xyz[keeps[j]] for j in priority[:k]])
            if not above.size:
                continue
            tree = scipy.spatial.cKDTree(above)
            rr, cc = np.nonzero(keeps[i])
            dist, _ = tree.query(scans[i].xyz[rr, cc], distance_upper_bound=dedupe_mm)
            near = np.isfinite(dist)
            keeps[i][rr[near], cc[near]] = False
            removed[scans[i].name] = int(near.sum())

    fused_xyz, counts = [], []
    for i, s in enumerate(scans):
        keep = keeps[i]
        xyz = np.asarray(s.xyz, dtype=np.float64)
        w_sum = np.where(keep, weights[i], 0.0)
        acc = xyz * w_sum[..., None]
        count = keep.astype(np.uint8)
        for j in range(n):
            if j == i:
                continue
            m = corr[i, j]
            own = keep[m.parent_rc[:, 0], m.parent_rc[:, 1]]
            rc, sub = m.parent_rc[own], m.child_rc[own]
            w_j, _, _ = bilinear(weights[j], sub[:, 0], sub[:, 1])
            np.add.at(w_sum, (rc[:, 0], rc[:, 1]), w_j)
            np.add.at(acc, (rc[:, 0], rc[:, 1]), w_j[:, None] * m.xyz_child[own])
            np.add.at(count, (rc[:, 0], rc[:, 1]), 1)
        with np.errstate(invalid="ignore", divide="ignore"):
            fused_xyz.append(np.where((w_sum > 0)[..., None], acc / w_sum[..., None], xyz))
        counts.append(count)

    # a lone point (no kept pair) off the surface of the other cameras nearby is dropped when
    # they are confirmed there (a kept pair within surface_mm) or view it better
    off_surface = dict.fromkeys((s.name for s in scans), 0)
    if surface_mm is not None and n > 1 and np.isfinite(spacing):
        points, trust = [], []  # per camera: valid points; confirmed (inf) or view score
        for j in range(n):
            t = np.array(scores[j], dtype=np.float64)
            for k in range(n):
                if k != j:
                    m = corr[j, k]
                    t[tuple(m.parent_rc[m.distance_mm <= surface_mm].T)] = np.inf
            points.append(np.asarray(scans[j].xyz, np.float64)[valid[j]])
            trust.append(t[valid[j]])
        for i in range(n):
            lone = keeps[i] & (counts[i] == 1)
            others = [j for j in range(n) if j != i]
            ref = np.concatenate([points[j] for j in others])
            if not lone.any() or not ref.size:
                continue
            ref_trust = np.concatenate([trust[j] for j in others])
            rr, cc = np.nonzero(lone)
            off = _off_surface(fused_xyz[i][rr, cc], scores[i][rr, cc], ref, ref_trust,
                               radius=3 * spacing, surface_mm=surface_mm)
            keeps[i][rr[off], cc[off]] = False
            off_surface[scans[i].name] = int(off.sum())

    fused_scans, fused_normals, n_views = [], [], []
    for i, s in enumerate(scans):
        keep, count, fused, xyz = keeps[i], counts[i], fused_xyz[i], np.asarray(s.xyz, np.float64)
        # normals from every valid pixel (fused where owned), so ownership edges keep them
        normals = grid_normals(np.where(keep[..., None], fused, xyz), camera_center=s.camera_center)
        normals[~keep] = np.nan
        fused[~keep] = np.nan
        fused_scan = Scan(
            name=s.name, xyz=fused.astype(np.float32), xp=np.where(keep, s.xp, np.nan),
            yp=np.where(keep, s.yp, np.nan), albedo=s.albedo,
            intensity=np.where(keep, s.intensity, 0).astype(np.float32),
            modulation=s.modulation, mask=keep, camera_center=s.camera_center,
        )
        fused_scans.append(fused_scan)
        fused_normals.append(normals)
        n_views.append(np.where(keep, count, 0).astype(np.uint8))

    verts, vnorm, cols, cams, pix, faces = [], [], [], [], [], []
    offset = 0
    for i, (f, nm) in enumerate(zip(fused_scans, fused_normals, strict=True)):
        index, tri = grid_mesh(f.xyz, f.mask, max_edge_mm=max_edge_mm, normals=nm)
        sel = index >= 0
        rr, cc = np.nonzero(sel)
        verts.append(f.xyz[sel])
        vnorm.append(nm[sel])
        grey = np.clip(np.nan_to_num(np.asarray(f.albedo, np.float64)[sel]) * 255 + 0.5, 0, 255)
        cols.append(np.repeat(grey.astype(np.uint8)[:, None], 3, axis=1))
        cams.append(np.full(rr.size, i, dtype=np.int16))
        pix.append(np.stack([rr, cc], axis=-1).astype(np.int32))
        faces.append((tri + offset).astype(np.int32))
        offset += rr.size
    return SuperScan(
        scans=fused_scans, normals=fused_normals, n_views=n_views,
        vertices=np.concatenate(verts).astype(np.float32),
        vertex_normals=np.concatenate(vnorm).astype(np.float32),
        colors=np.concatenate(cols), faces=np.concatenate(faces),
        camera=np.concatenate(cams), pixel=np.concatenate(pix),
        correspondences=corr, priority=priority, duplicates_removed=removed,
        points_rejected={s.name: {"spike": spikes_removed[s.name],
                                  "off_surface": off_surface[s.name]} for s in scans},
    )


def super_mat5_scan(superscan: SuperScan, *, gap_px: int = 1, name: str = "super") -> Scan:
    """The super mat5 grid: every camera's fused grid side by side (see the module docstring).

    Parameters
    ----------
    superscan : SuperScan
    gap_px : int
        Invalid columns between two cameras' blocks.
    name : str

    Returns
    -------
    Scan
        Shape ``(max H, ΣW + gap_px × (n − 1))``; ``camera_center`` is None.
    """
    gap_px = as_int(gap_px, "gap_px", minimum=0)
    scans = superscan.scans
    height = max(s.shape[0] for s in scans)
    width = sum(s.shape[1] for s in scans) + gap_px * (len(scans) - 1)
    xyz = np.full((height, width, 3), np.nan, dtype=np.float32)
    planes = {k: np.full((height, width), np.nan, np.float32) for k in ("xp", "yp")}
    planes |= {k: np.zeros((height, width), np.float32)
               for k in ("albedo", "intensity", "modulation")}
    mask = np.zeros((height, width), dtype=bool)
    col = 0
    for s in scans:
        h, w = s.shape
        block = (slice(0, h), slice(col, col + w))
        xyz[block] = s.xyz
        mask[block] = s.mask
        for k in planes:
            planes[k][block] = getattr(s, k)
        col += w + gap_px
    return Scan(name=name, xyz=xyz, mask=mask, camera_center=None, **planes)


def write_super_mat5(
    prefix: str | os.PathLike, superscan: SuperScan, *, gap_px: int = 1
) -> list[Path]:
    """Write the super mat5 (:func:`super_mat5_scan`) with :func:`nail2nail.io.mat5.write_mat5`.

    Returns
    -------
    list of Path
        The seven files of the set.
    """
    from ..io.mat5 import write_mat5

    return write_mat5(prefix, super_mat5_scan(superscan, gap_px=gap_px))


def write_super_ply(path: str | os.PathLike, superscan: SuperScan) -> Path:
    """Write the super scan as binary PLY: vertices, normals, grey colours, triangles.

    Returns
    -------
    Path
        `path`.
    """
    from ..io.ply import write_ply

    names = ", ".join(s.name for s in superscan.scans)
    return write_ply(path, superscan.vertices, colors=superscan.colors,
                     normals=superscan.vertex_normals, faces=superscan.faces,
                     comments=[f"nail2nail super scan fused from {names}"])
