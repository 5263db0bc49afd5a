"""Issue 11: the compiled fusion kernels agree with plain NumPy references.

Each kernel of :mod:`nail2nail.merge.fusion` is compared with the NumPy formulation it replaced
(kept here as the reference), on small synthetic scans; :func:`fuse_scans` as a whole with a
NumPy reference fusion that takes the same correspondences. The kernels repeat NumPy's float64
arithmetic, so the results agree to rounding (exactly, on the machines measured); the tests
allow for a different order of summation in NumPy's own loops.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import scipy.ndimage
import scipy.spatial

sys.path.insert(0, str(Path(__file__).parent))
from _synthetic import synthetic_scans

from nail2nail._feather import feather
from nail2nail._interpolate import bilinear
from nail2nail.merge import valid_mask
from nail2nail.merge.correspondence import grid_normals, view_cosine
from nail2nail.merge.fusion import (
    _dedupe_kernel,
    _fused_normals,
    _grid,
    _off_surface_kernel,
    fuse_scans,
    grid_mesh,
    spikes,
    super_mat5_scan,
    view_weights,
)

SIZE = (96, 120)
RADIUS = 8.0  # the synthetic cylinder


# -- the NumPy references ----------------------------------------------------------------------
def _spikes_reference(xyz, valid, spike_mm):
    xyz = np.asarray(xyz, dtype=np.float64)
    valid = np.asarray(valid, dtype=bool) & np.isfinite(xyz).all(axis=-1)
    h, w = valid.shape
    pad = np.pad(np.where(valid[..., None], xyz, np.nan), ((1, 1), (1, 1), (0, 0)),
                 constant_values=np.nan).reshape(-1, 3)
    rr, cc = np.nonzero(valid)
    centre = (rr + 1) * (w + 2) + cc + 1
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
            sign = np.sign(steps[k][0] * steps[m][1] - steps[k][1] * steps[m][0])
            normal += np.nan_to_num(sign * np.cross(chords[k], chords[m]))
    with np.errstate(invalid="ignore", divide="ignore"):
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    smallest = np.full(rr.size, np.inf)
    lines = np.zeros(rr.size, dtype=np.int8)
    for mid in mids:
        offset = np.abs(np.einsum("nk,nk->n", x - mid, normal))
        lines += np.isfinite(mid[:, 0])
        smallest = np.fmin(smallest, offset)
    out = np.zeros((h, w), dtype=bool)
    out[rr, cc] = (lines >= 2) & np.isfinite(smallest) & (smallest > spike_mm)
    return out


def _feather_reference(valid, feather_px):
    if feather_px <= 0:
        return np.ones(valid.shape)
    distance = scipy.ndimage.distance_transform_edt(np.pad(valid, 1))[1:-1, 1:-1]
    return np.clip((distance - 0.5) / feather_px, 0, 1)


def _view_weights_reference(scan, normals, feather_px):
    valid = valid_mask(scan)
    weight = valid.astype(np.float64)
    weight *= np.clip(np.nan_to_num(np.asarray(scan.modulation, np.float64)), 0, None)
    if scan.camera_center is not None:
        weight *= view_cosine(scan, normals=normals)
    weight *= _feather_reference(valid, feather_px)
    weight[~valid] = 0.0
    return weight


def _grid_mesh_reference(xyz, keep, max_edge_mm, normals):
    xyz = np.asarray(xyz, dtype=np.float64)
    keep = np.asarray(keep, dtype=bool) & np.isfinite(xyz).all(axis=-1)
    index = np.full(keep.shape, -1, dtype=np.int64)
    index[keep] = np.arange(np.count_nonzero(keep))
    tl, tr, bl, br = index[:-1, :-1], index[:-1, 1:], index[1:, :-1], index[1:, 1:]
    tris = np.concatenate([np.stack([tl, bl, tr], axis=-1).reshape(-1, 3),
                           np.stack([tr, bl, br], axis=-1).reshape(-1, 3)])
    tris = tris[(tris >= 0).all(axis=1)]
    pts = xyz[keep]
    a, b, c = pts[tris[:, 0]], pts[tris[:, 1]], pts[tris[:, 2]]
    longest = np.maximum.reduce([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1),
                                 np.linalg.norm(a - c, axis=1)])
    tris = tris[longest <= max_edge_mm]
    a, b, c = pts[tris[:, 0]], pts[tris[:, 1]], pts[tris[:, 2]]
    vn = np.asarray(normals, dtype=np.float64)[keep][tris].sum(axis=1)
    flip = np.einsum("ij,ij->i", np.cross(b - a, c - a), np.nan_to_num(vn)) < 0
    tris[flip] = tris[flip][:, [0, 2, 1]]
    return index, tris


def _off_surface_reference(points, score, ref, ref_trust, *, radius, surface_mm, k=8):
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
    normal = vectors[:, :, 0]
    planar = values[:, 1] > 0.05 * values[:, 2]
    offset = np.abs(np.einsum("ni,ni->n", p - centroid, normal))
    trust = np.where(found, ref_trust[np.where(found, idx, 0)], 0.0)
    mean_trust = trust.sum(axis=1) / found.sum(axis=1)
    out[test] = planar & (offset > surface_mm) & (mean_trust > score[test])
    return out


def _fuse_reference(scans, corr, *, feather_px=8.0, spike_mm=0.05, surface_mm=0.05):
    """fuse_scans as NumPy (the code before issue 11), on the given correspondences."""
    scans = list(scans)
    n = len(scans)
    valid = [valid_mask(s) for s in scans]
    priority = sorted(range(n), key=lambda i: (-int(valid[i].sum()), i))
    rank = {cam: k for k, cam in enumerate(priority)}
    normals0 = [grid_normals(s.xyz, camera_center=s.camera_center) for s in scans]
    spiked = {}
    for i, s in enumerate(scans):
        bad = _spikes_reference(s.xyz, valid[i], spike_mm)
        spiked[s.name] = int(bad.sum())
        if bad.any():
            valid[i] = valid[i] & ~bad
            scans[i] = replace(s, mask=valid[i], xyz=np.where(valid[i][..., None], s.xyz,
                                                               np.float32(np.nan)))
            normals0[i] = grid_normals(scans[i].xyz, camera_center=s.camera_center)
    weights = [_view_weights_reference(s, nm, feather_px)
               for s, nm in zip(scans, normals0, strict=True)]
    scores = [np.where(v, view_cosine(s, normals=nm, smooth_px=2.0)
                       * _feather_reference(v, feather_px), 0.0)
              for s, v, nm in zip(scans, valid, normals0, strict=True)]
    keeps = []
    for i in range(n):
        keep = valid[i].copy()
        for j in range(n):
            if j != i:
                pairs = corr[i, j].all_pairs()
                rc = pairs.parent_rc
                other = bilinear(scores[j], *pairs.child_rc.T)[0]
                mine = scores[i][rc[:, 0], rc[:, 1]]
                lose = (other > mine) | ((other == mine) & (rank[j] < rank[i]))
                keep[rc[lose, 0], rc[lose, 1]] = False
        keeps.append(keep)
    spacing = np.concatenate([np.linalg.norm(np.diff(s.xyz, axis=1), axis=-1).ravel()
                              for s in scans])
    spacing = float(np.median(spacing[np.isfinite(spacing)]))
    max_edge_mm, dedupe_mm = 4.0 * spacing, 0.5 * spacing
    removed = dict.fromkeys((s.name for s in scans), 0)
    for k in range(1, n):
        i = priority[k]
        above = np.concatenate([scans[j].xyz[keeps[j]] for j in priority[:k]])
        rr, cc = np.nonzero(keeps[i])
        dist, _ = scipy.spatial.cKDTree(above).query(scans[i].xyz[rr, cc],
                                                     distance_upper_bound=dedupe_mm)
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
            if j != i:
                m = corr[i, j]
                own = keep[m.parent_rc[:, 0], m.parent_rc[:, 1]]
                rc, sub = m.parent_rc[own], m.child_rc[own]
                w_j = bilinear(weights[j], sub[:, 0], sub[:, 1])[0]
                np.add.at(w_sum, (rc[:, 0], rc[:, 1]), w_j)
                np.add.at(acc, (rc[:, 0], rc[:, 1]), w_j[:, None] * m.xyz_child[own])
                np.add.at(count, (rc[:, 0], rc[:, 1]), 1)
        with np.errstate(invalid="ignore", divide="ignore"):
            fused_xyz.append(np.where((w_sum > 0)[..., None], acc / w_sum[..., None], xyz))
        counts.append(count)
    off_surface = dict.fromkeys((s.name for s in scans), 0)
    points, trust = [], []
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
        rr, cc = np.nonzero(lone)
        off = _off_surface_reference(fused_xyz[i][rr, cc], scores[i][rr, cc], ref,
                                     np.concatenate([trust[j] for j in others]),
                                     radius=3 * spacing, surface_mm=surface_mm)
        keeps[i][rr[off], cc[off]] = False
        off_surface[scans[i].name] = int(off.sum())
    out = {"vertices": [], "normals": [], "faces": [], "masks": keeps, "n_views": []}
    offset = 0
    for i, s in enumerate(scans):
        keep, fused = keeps[i], fused_xyz[i]
        normals = grid_normals(np.where(keep[..., None], fused, np.asarray(s.xyz, np.float64)),
                               camera_center=s.camera_center)
        normals[~keep] = np.nan
        fused[~keep] = np.nan
        f32 = fused.astype(np.float32)
        index, tri = _grid_mesh_reference(f32, keep, max_edge_mm, normals)
        out["vertices"].append(f32[index >= 0])
        out["normals"].append(normals[index >= 0])
        out["faces"].append((tri + offset).astype(np.int32))
        out["n_views"].append(np.where(keep, counts[i], 0).astype(np.uint8))
        offset += int((index >= 0).sum())
    for key in ("vertices", "normals", "faces"):
        out[key] = np.concatenate(out[key])
    out.update(removed=removed, off_surface=off_surface, spikes=spiked)
    return out


def _super_mat5_reference(scans, gap_px):
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
    return {"xyz": xyz, "mask": mask, **planes}


# -- fixtures ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def scans():
    return synthetic_scans(size=SIZE, noise_px=0.05, seed=5)


def _corrupted(scans, seed=0):
    """Camera 1 with points of its mask-edge band and of its inside pushed off the surface."""
    s = scans[1]
    rng = np.random.default_rng(seed)
    inner = scipy.ndimage.binary_erosion(s.mask, iterations=3)
    xyz = s.xyz.copy()
    for region, count, offset_mm in ((s.mask & ~inner, 40, 0.2), (inner, 12, 0.3)):
        rows, cols = np.nonzero(region)
        pick = rng.choice(rows.size, count, replace=False)
        xyz[rows[pick], cols[pick]] *= np.float32(1 + offset_mm / RADIUS)
    return [scans[0], replace(s, xyz=xyz), scans[2]]


# -- kernels against their references ----------------------------------------------------------
@pytest.mark.parametrize("spike_mm", [0.05, 0.01, 0.002])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_spikes_match_numpy(scans, spike_mm, dtype):
    found = 0
    for s in _corrupted(scans):
        xyz = s.xyz.astype(dtype)
        valid = valid_mask(s)
        expected = _spikes_reference(xyz, valid, spike_mm)
        np.testing.assert_array_equal(spikes(xyz, valid, spike_mm=spike_mm), expected)
        found += expected.sum()
    assert found > 0


def test_spikes_bad_shape():
    with pytest.raises(ValueError, match="xyz: expected shape"):
        spikes(np.zeros((4, 5, 3)), np.ones((5, 4), bool))


@pytest.mark.parametrize("feather_px", [0.0, 0.7, 3.3, 8.0, 20.0, 100.0])
def test_feather_matches_distance_transform(scans, feather_px):
    rng = np.random.default_rng(3)
    masks = [valid_mask(s) for s in scans]
    masks += [rng.random((int(rng.integers(1, 30)), int(rng.integers(1, 30))))
              > rng.uniform(0.05, 0.9) for _ in range(40)]
    masks += [np.ones((5, 7), bool), np.zeros((3, 3), bool)]
    for valid in masks:
        got = feather(valid, feather_px)
        np.testing.assert_array_equal(got, _feather_reference(valid, feather_px))
        if feather_px > 0:  # positive on every valid pixel, 0 off them
            assert (got[valid] >= 0.5 / feather_px).all() and (got[~valid] == 0).all()


def test_view_weights_match_numpy(scans):
    for s in scans:
        normals = grid_normals(s.xyz, camera_center=s.camera_center)
        for feather_px in (0.0, 8.0):
            np.testing.assert_allclose(view_weights(s, feather_px=feather_px),
                                       _view_weights_reference(s, normals, feather_px),
                                       rtol=1e-12, atol=1e-15)
    plain = replace(scans[1], camera_center=None)
    np.testing.assert_allclose(view_weights(plain), _view_weights_reference(plain, None, 8.0),
                               rtol=1e-12, atol=1e-15)


def test_grid_mesh_matches_numpy(scans):
    rng = np.random.default_rng(4)
    for s in scans:
        xyz = s.xyz.astype(np.float64)
        xyz[rng.random(xyz.shape[:2]) < 0.01] += [0, 0, 1.0]  # depth steps: long edges
        keep = valid_mask(s) & (rng.random(xyz.shape[:2]) > 0.05)  # holes
        normals = grid_normals(xyz, camera_center=s.camera_center)
        normals[rng.random(xyz.shape[:2]) < 0.2] *= -1  # windings to flip
        index, faces = grid_mesh(xyz, keep, max_edge_mm=0.6, normals=normals)
        ref_index, ref_faces = _grid_mesh_reference(xyz, keep, 0.6, normals)
        np.testing.assert_array_equal(index, ref_index)
        np.testing.assert_array_equal(faces, ref_faces)
        assert faces.dtype == np.int64 and faces.shape[0] > 0


def test_fused_normals_match_grid_normals(scans):
    rng = np.random.default_rng(5)
    s = scans[1]
    valid = valid_mask(s)
    pixels = np.flatnonzero(valid)
    index = np.full(valid.shape, -1, np.int32)
    index.ravel()[pixels] = np.arange(pixels.size, dtype=np.int32)
    keep = rng.random(pixels.size) > 0.3
    fused = s.xyz.reshape(-1, 3)[pixels].astype(np.float64) + 0.01 * rng.standard_normal(
        (pixels.size, 3))
    rows, cols = np.divmod(pixels, valid.shape[1])
    composite = s.xyz.astype(np.float64)
    composite.reshape(-1, 3)[pixels[keep]] = fused[keep]
    for center in (s.camera_center, None):
        expected = grid_normals(composite, camera_center=center)[rows[keep], cols[keep]]
        got = _fused_normals(s.xyz, index, keep, fused, rows[keep], cols[keep],
                             np.zeros(3) if center is None else np.asarray(center, float),
                             center is not None)
        np.testing.assert_allclose(got, expected, atol=1e-6)
        assert got.dtype == np.float32


def _cloud(rng, n, *, z0=0.0):
    """Points on a wavy sheet, spacing about 0.03 mm, as a camera's grid would give."""
    rr, cc = np.mgrid[0:n, 0:n] * 0.03
    z = z0 + 0.1 * np.sin(rr * 3) * np.cos(cc * 2) + 0.003 * rng.standard_normal(rr.shape)
    return np.stack([cc, rr, z], -1).reshape(-1, 3)


def test_grid_searches_match_kdtree():
    rng = np.random.default_rng(6)
    groups = [_cloud(rng, 60).astype(np.float32), _cloud(rng, 50, z0=0.004).astype(np.float32),
              (_cloud(rng, 40, z0=0.02) + np.array([0.3, 0.2, 0])).astype(np.float32)]
    points = np.concatenate(groups)
    start = np.concatenate([[0], np.cumsum([g.shape[0] for g in groups])])
    grid = _grid(points, start, 0.09)
    # dedupe: group 2's points near a kept point of groups 0 and 1
    keep = rng.random(points.shape[0]) > 0.4
    radius = 0.012
    above = np.concatenate([groups[j][keep[start[j]:start[j + 1]]] for j in (0, 1)])
    dist, _ = scipy.spatial.cKDTree(above).query(groups[2], distance_upper_bound=radius)
    expected = keep[start[2]:] & np.isfinite(dist)
    got = keep.copy()
    removed = _dedupe_kernel(*grid, np.array([True, True, False]), np.take(keep, grid[2]), got,
                             groups[2], int(start[2]), radius)
    assert removed == expected.sum() > 0
    np.testing.assert_array_equal(got[start[2]:], keep[start[2]:] & ~expected)
    np.testing.assert_array_equal(got[:start[2]], keep[:start[2]])
    # off surface: group 0's points, some pushed off, against groups 1 and 2
    query = groups[0].astype(np.float64)
    query[::7, 2] += rng.uniform(-0.1, 0.1, query[::7].shape[0])
    trust = rng.uniform(0, 1, points.shape[0])
    trust[rng.random(points.shape[0]) < 0.2] = np.inf
    score = rng.uniform(0, 1, query.shape[0])
    ref = points[start[1]:].astype(np.float64)
    expected = _off_surface_reference(query, score, ref, trust[start[1]:], radius=0.09,
                                      surface_mm=0.02)
    got = _off_surface_kernel(*grid, trust, 0, query, score, 0.09, 0.02)
    assert expected.sum() > 10
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("gap_px", [0, 1, 3])
def test_super_mat5_matches_numpy(gap_px):
    # cameras of different sizes: the shorter ones padded below
    scans = [synthetic_scans(size=size, seed=k)[k] for k, size in
             enumerate([(40, 50), (48, 60), (32, 36)])]
    sup = fuse_scans(scans)
    grid = super_mat5_scan(sup, gap_px=gap_px)
    for key, expected in _super_mat5_reference(sup.scans, gap_px).items():
        got = getattr(grid, key)
        assert got.dtype == expected.dtype, key
        np.testing.assert_array_equal(got, expected, err_msg=key)


# -- the whole fusion --------------------------------------------------------------------------
@pytest.mark.parametrize("corrupt", [False, True])
def test_fuse_scans_matches_numpy_reference(scans, corrupt):
    data = _corrupted(scans) if corrupt else scans
    sup = fuse_scans(data)
    ref = _fuse_reference(data, sup.correspondences)
    np.testing.assert_array_equal(sup.faces, ref["faces"])
    np.testing.assert_allclose(sup.vertices, ref["vertices"], rtol=0, atol=1e-5)
    np.testing.assert_allclose(sup.vertex_normals, ref["normals"], rtol=0, atol=1e-5)
    for k, f in enumerate(sup.scans):
        np.testing.assert_array_equal(f.mask, ref["masks"][k])
        np.testing.assert_array_equal(sup.n_views[k], ref["n_views"][k])
    assert sup.duplicates_removed == ref["removed"]
    assert {k: v["off_surface"] for k, v in sup.points_rejected.items()} == ref["off_surface"]
    assert {k: v["spike"] for k, v in sup.points_rejected.items()} == ref["spikes"]
    if corrupt:  # every step had work to do
        assert sum(ref["spikes"].values()) > 0 and sum(ref["off_surface"].values()) > 0
    assert sum(ref["removed"].values()) > 0


def test_timings_name_every_step(scans):
    sup = fuse_scans(scans)
    assert list(sup.timings) == ["scan_normals", "spikes", "weights", "correspond", "ownership",
                                 "spacing", "grid", "dedupe", "fusion", "off_surface", "normals",
                                 "mesh", "output"]
    assert all(v >= 0 for v in sup.timings.values())
