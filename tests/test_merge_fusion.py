"""Tests of nail2nail.merge.fusion: the super scan (fused cloud, normals, mesh, super mat5)."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import scipy.spatial

sys.path.insert(0, str(Path(__file__).parent))
from _synthetic import synthetic_scans

from nail2nail.merge import valid_mask
from nail2nail.merge.fusion import (
    fuse_scans,
    grid_mesh,
    grid_normals,
    super_mat5_scan,
    view_weights,
    write_super_mat5,
    write_super_ply,
)

SIZE = (96, 120)
RADIUS = 8.0  # the synthetic cylinder


@pytest.fixture(scope="module")
def scans():
    return synthetic_scans(size=SIZE, noise_px=0.05, seed=5)


@pytest.fixture(scope="module")
def superscan(scans):
    return fuse_scans(scans)


def _radial_error(points):
    p = np.asarray(points, dtype=np.float64)
    return np.hypot(p[..., 0], p[..., 2]) - RADIUS


def _spacing(scans):
    d = np.concatenate([np.linalg.norm(np.diff(s.xyz, axis=1), axis=-1).ravel() for s in scans])
    return float(np.median(d[np.isfinite(d)]))


def test_super_scan_lies_on_the_surface(superscan):
    assert np.abs(_radial_error(superscan.vertices)).max() < 0.01
    assert superscan.vertices.dtype == np.float32 and superscan.faces.dtype == np.int32


def test_overlaps_are_fused_not_stacked(scans, superscan):
    n_valid = sum(int(valid_mask(s).sum()) for s in scans)
    assert superscan.n_vertices < 0.75 * n_valid  # the overlaps appear once
    fused = sum(int((v > 1).sum()) for v in superscan.n_views)
    assert fused > 0.5 * superscan.n_vertices
    # no two cameras left points on top of each other
    spacing = _spacing(scans)
    v = superscan.vertices
    for a in range(3):
        for b in range(a + 1, 3):
            d, _ = scipy.spatial.cKDTree(v[superscan.camera == b]).query(
                v[superscan.camera == a])
            assert d.min() > 0.3 * spacing
    # and the surface has no gap wider than a few pixels between cameras around the finger
    ring = np.abs(v[:, 1]) < 0.5 * spacing
    angle = np.sort(np.arctan2(v[ring, 0], v[ring, 2]))
    assert np.diff(angle).max() * RADIUS < 4 * spacing


def test_fusion_averages_noise_down():
    scans = synthetic_scans(size=SIZE, seed=7)
    rng = np.random.default_rng(1)
    noisy = []
    for s in scans:
        xyz = s.xyz + (0.01 * rng.standard_normal(s.xyz.shape)).astype(np.float32)
        noisy.append(replace(s, xyz=xyz))
    sup = fuse_scans(noisy)
    multi = np.concatenate([(v > 1)[f.mask] for v, f in zip(sup.n_views, sup.scans, strict=True)])
    before = np.concatenate([_radial_error(s.xyz[valid_mask(s)]) for s in noisy])
    after = _radial_error(sup.vertices[multi])
    assert np.sqrt(np.mean(after**2)) < 0.85 * np.sqrt(np.mean(before**2))


def test_shifted_camera_is_pulled_halfway(scans):
    shifted = [scans[0], replace(scans[1], xyz=scans[1].xyz + np.float32([0, 0, 0.05])),
               scans[2]]
    sup = fuse_scans(shifted, ownership="priority", priority=[1, 0, 2])
    own = sup.scans[1]
    fused = sup.n_views[1] > 1
    dz = own.xyz[fused][:, 2] - shifted[1].xyz[fused][:, 2]
    assert np.all(dz < 0.0) and np.all(dz > -0.06)  # between the cameras (± decoding noise)
    assert -0.04 < np.median(dz) < -0.01  # comparable weights away from the edges


def test_normals_point_out_and_faces_agree(superscan):
    v = superscan.vertices.astype(np.float64)
    radial = np.stack([v[:, 0], 0 * v[:, 0], v[:, 2]], -1) / RADIUS
    n = superscan.vertex_normals
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1, atol=1e-5)
    assert np.einsum("ij,ij->i", n, radial).min() > 0.95
    f = superscan.faces
    face_n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all(np.einsum("ij,ij->i", face_n, radial[f[:, 0]]) > 0)
    assert f.min() >= 0 and f.max() < superscan.n_vertices


def test_holes_stay_holes(scans):
    centre = np.array([0.0, 2.0, RADIUS])  # a 1.5 mm hole on the front of the finger
    holed = []
    for s in scans:
        mask = s.mask & ~(np.linalg.norm(s.xyz - centre, axis=-1) < 1.5)
        holed.append(replace(s, mask=mask))
    sup = fuse_scans(holed)
    v = sup.vertices.astype(np.float64)
    assert np.linalg.norm(v - centre, axis=1).min() >= 1.5 - 1e-6
    centroids = v[sup.faces].mean(axis=1)
    assert np.linalg.norm(centroids - centre, axis=1).min() > 1.0


def test_mesh_skips_long_edges():
    rr, cc = np.mgrid[0:4, 0:5].astype(float)
    xyz = np.stack([cc, -rr, 0 * cc], -1)
    xyz[:, 3:, 2] = 10.0  # a depth step between columns 2 and 3
    index, faces = grid_mesh(xyz, np.ones((4, 5), bool), max_edge_mm=2.0)
    assert faces.shape == (2 * 3 * 3, 3)  # columns 0-2 and 3-4: (3 + 1) blocks per row pair
    assert index.max() == 19


def test_grid_normals_of_a_tilted_plane_and_view_weights(scans):
    rr, cc = np.mgrid[0:5, 0:6].astype(float)
    xyz = np.stack([cc, -rr, 0.5 * cc], -1)
    n = grid_normals(xyz, camera_center=[0, 0, 100])
    np.testing.assert_allclose(n[2, 2], np.array([-0.5, 0, 1]) / np.sqrt(1.25), atol=1e-6)
    assert np.isfinite(n).all()  # one-sided differences at the edges
    w = view_weights(scans[1])
    assert w.shape == scans[1].shape and w.min() >= 0
    assert np.all(w[~scans[1].mask] == 0)
    assert w.max() <= 1.0


def test_super_mat5_holds_every_vertex_once(superscan, tmp_path):
    grid = super_mat5_scan(superscan, gap_px=1)
    h = max(s.shape[0] for s in superscan.scans)
    assert grid.xyz.shape == (h, 3 * SIZE[0] + 2, 3)
    assert int(grid.mask.sum()) == superscan.n_vertices
    np.testing.assert_array_equal(np.sort(grid.xyz[grid.mask][:, 1]),
                                  np.sort(superscan.vertices[:, 1]))
    assert not grid.mask[:, SIZE[0]].any()  # the gap column
    from nail2nail.io.mat5 import read_mat5

    files = write_super_mat5(tmp_path / "super", superscan)
    assert len(files) == 7
    back = read_mat5(tmp_path / "super")
    np.testing.assert_array_equal(back.mask, grid.mask)
    np.testing.assert_array_equal(back.xyz[back.mask], grid.xyz[grid.mask])


def test_super_ply_round_trip(superscan, tmp_path):
    from nail2nail.io.ply import read_ply

    path = write_super_ply(tmp_path / "super.ply", superscan)
    data = read_ply(path)
    np.testing.assert_array_equal(data.points, superscan.vertices)
    np.testing.assert_array_equal(data.faces, superscan.faces)
    np.testing.assert_array_equal(data.colors, superscan.colors)
    assert data.normals is not None


def test_summary_counts(superscan):
    s = superscan.summary()
    assert s["vertices"] == superscan.n_vertices
    assert sum(c["owned"] for c in s["cameras"].values()) == superscan.n_vertices
    assert set(s["duplicates_removed"]) == {"cam0", "cam1", "cam2"}


def test_bad_inputs(scans):
    with pytest.raises(ValueError, match="scans: expected at least one"):
        fuse_scans([])
    with pytest.raises(ValueError, match="priority: expected a permutation"):
        fuse_scans(scans, priority=[0, 0, 1])
    with pytest.raises(ValueError, match="ownership"):
        fuse_scans(scans, ownership="vote")
    with pytest.raises(ValueError, match="has no valid pixels"):
        fuse_scans([scans[0], replace(scans[1], mask=np.zeros_like(scans[1].mask))])
    with pytest.raises(TypeError, match=r"scans\[1\]"):
        fuse_scans([scans[0], "cam1"])
    with pytest.raises(ValueError, match="xyz: expected shape"):
        grid_normals(np.zeros((4, 4)))


# -- issue 9: a clean fused surface ----------------------------------------------------------
def _corrupted(scans):
    """Camera 1 with 40 points of its mask-edge band (3 px) and 12 inner points pushed 0.2 and
    0.3 mm off the surface."""
    import scipy.ndimage

    s = scans[1]
    rng = np.random.default_rng(0)
    inner = scipy.ndimage.binary_erosion(s.mask, iterations=3)
    xyz = s.xyz.copy()
    picked = []
    for region, count, offset_mm in ((s.mask & ~inner, 40, 0.2),
                                     (scipy.ndimage.binary_erosion(s.mask, iterations=10), 12,
                                      0.3)):
        rows, cols = np.nonzero(region)
        pick = rng.choice(rows.size, count, replace=False)
        xyz[rows[pick], cols[pick]] *= np.float32(1 + offset_mm / RADIUS)  # radially out
        picked.append((rows[pick], cols[pick]))
    return [scans[0], replace(s, xyz=xyz), scans[2]], picked


def test_issue9_corrupted_points_do_not_reach_the_fused_surface(scans):
    bad, (_, (sr, sc)) = _corrupted(scans)
    off = {"spike_mm": None, "surface_mm": None, "max_view_angle_deg": None,
           "max_incidence_deg": None, "min_relative_modulation": None, "outlier_mm": None}
    dirty = fuse_scans(bad, **off)
    assert np.abs(_radial_error(dirty.vertices)).max() > 0.1  # what fusing them blindly does
    sup = fuse_scans(bad)
    assert np.abs(_radial_error(sup.vertices)).max() < 0.05
    assert sup.points_rejected["cam1"]["spike"] >= 12
    assert not sup.scans[1].mask[sr, sc].any()
    summary = sup.summary()
    assert summary["points_rejected"] == sup.points_rejected
    assert set(summary["points_rejected"]["cam0"]) == {"spike", "off_surface"}
    rejected = summary["rejected_pairs"]
    assert set(rejected) == {f"{i}-{j}" for i in range(3) for j in range(3) if i != j}
    assert sum(rejected["0-1"].values()) > 0
    # the surface still covers the finger: corrupted points were replaced, not cut out
    assert sup.n_vertices > 0.95 * dirty.n_vertices


def test_issue9_spikes():
    from nail2nail.merge.fusion import spikes

    rr, cc = np.mgrid[0:12, 0:12].astype(float)
    xyz = np.stack([cc * 0.05, -rr * 0.05, 0.02 * np.sin(cc)], -1)  # ridges along columns
    valid = np.ones((12, 12), bool)
    assert not spikes(xyz, valid).any()
    xyz[5, 5, 2] += 0.2
    xyz[0, 7, 2] -= 0.2  # the outermost row has one line: not tested
    xyz[11, 0, 2] -= 0.2  # a corner: neither
    xyz[5, 11, 2] += 0.2  # the last column: the column line and no other, not tested either
    xyz[1, 3, 2] += 0.2  # inside the first row: three lines
    found = spikes(xyz, valid)
    assert np.argwhere(found).tolist() == [[1, 3], [5, 5]]
    valid[4:7, 4:7] = False
    assert not spikes(xyz, valid)[5, 5]
    with pytest.raises(ValueError, match="spike_mm"):
        fuse_scans(synthetic_scans(size=(32, 40)), spike_mm=0)
