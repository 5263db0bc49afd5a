"""The seamless mesh (issue 27): ``nail2nail.merge.mesh``."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nail2nail.merge.fusion import grid_mesh
from nail2nail.merge.mesh import boundary_figures, mesh_topology, param_mesh


def _cylinder_grids(seed: int, gap_px: int = 1):
    """Two grids of a cylinder's front (radius 8 mm), meeting along a seam `gap_px` pixels
    apart (1: neighbours, as two cameras' owned pixels are on the surface), the normals, and a
    one-to-one plane (arc length × height)."""
    rng = np.random.default_rng(seed)
    theta = np.linspace(-1.2, 1.2, 80)
    height = np.linspace(-6.0, 6.0, 60)
    t, h = np.meshgrid(theta, height)
    xyz = np.stack([8 * np.sin(t), h, 8 * np.cos(t)], -1)
    xyz += rng.normal(0, 0.002, xyz.shape)  # µm-level noise, as a scan's
    left = np.zeros(t.shape, bool)
    right = np.zeros(t.shape, bool)
    left[:, :40] = True
    right[:, 40 + gap_px - 1:] = True  # gap_px − 1 columns owned by neither
    normals = xyz * np.array([1.0, 0.0, 1.0])
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    return xyz, left, right, normals, np.stack([8 * t, h], -1)


def test_topology_of_a_square():
    topo = mesh_topology([[0, 1, 2], [0, 2, 3]], 5)
    assert topo == {"faces": 2, "edges": 5, "boundary_edges": 4, "non_manifold_edges": 0,
                    "non_manifold_vertices": 0, "isolated_vertices": 1,
                    "inconsistent_edges": 0}
    # the same square with one triangle flipped: its diagonal runs twice the same way
    assert mesh_topology([[0, 1, 2], [0, 3, 2]], 4)["inconsistent_edges"] == 1
    # a fan of three triangles on one edge; a bow-tie at vertex 0
    assert mesh_topology([[0, 1, 2], [1, 0, 3], [0, 1, 4]], 5)["non_manifold_edges"] == 1
    assert mesh_topology([[0, 1, 2], [0, 3, 4]], 5)["non_manifold_vertices"] == 1


def test_two_grids_meet_in_one_surface():
    """The seam between two grids a pixel apart is closed; the boundary is the outline."""
    xyz, left, right, normals, uv = _cylinder_grids(0, gap_px=2)
    keep = left | right
    _, faces = grid_mesh(xyz, keep, max_edge_mm=1.0, normals=normals)
    grids = mesh_topology(faces, int(keep.sum()))
    points, n = xyz[keep], normals[keep]
    seamless = param_mesh(points, uv[keep], normals=n)
    topo = mesh_topology(seamless, len(points))
    assert grids["boundary_edges"] > topo["boundary_edges"]
    # the outline of the 60 x 79 kept block: 2 (59 + 78) edges (the gap column is dropped)
    assert topo["boundary_edges"] == 2 * (59 + 78)
    assert topo["non_manifold_edges"] == topo["non_manifold_vertices"] == 0
    assert topo["inconsistent_edges"] == 0 and topo["isolated_vertices"] == 0
    # wound counter-clockwise seen from outside (the normals' side)
    a, b, c = (points[seamless[:, k]] for k in range(3))
    facing = (np.cross(b - a, c - a) * (n[seamless[:, 0]])).sum(1)
    assert np.all(facing > 0)


def test_holes_and_concave_outline_stay_open():
    xyz, left, right, _, uv = _cylinder_grids(1, gap_px=1)
    keep = left | right
    keep[20:30, 20:30] = False  # a hole of 10 x 10 px (2.4 mm across)
    keep[:25, 60:] = False  # a notch in the outline
    faces = param_mesh(xyz[keep], uv[keep])
    topo = mesh_topology(faces, int(keep.sum()))
    assert topo["non_manifold_edges"] == topo["non_manifold_vertices"] == 0
    # where each triangle lies, in (row, col) of the grid
    rows, cols = np.nonzero(keep)
    r, c = rows[faces].mean(axis=1), cols[faces].mean(axis=1)
    # concave corners (the hole's, the notch's) are bevelled by triangles of at most 3 local
    # spacings; farther in, nothing is bridged
    assert not np.any((r > 22) & (r < 27) & (c > 22) & (c < 27))
    assert not np.any((r < 21) & (c > 63))
    # so the boundary runs round the hole too: more than the block's outline, 2 (59 + 79)
    # grid edges (the notch's L keeps the outline's length; bevels shorten both)
    assert 2 * (59 + 79) < topo["boundary_edges"] < 2 * (59 + 79) + 44


def test_small_holes_inside_are_closed_notches_stay_open():
    """fill_holes_mm closes a hole inside the surface (whose triangles' edges fit), never the
    outline's notch (outside the scanned area: its dropped triangles reach the hull)."""
    xyz, left, right, _, uv = _cylinder_grids(1, gap_px=1)
    keep = left | right
    keep[20:30, 20:30] = False  # a hole of 10 x 10 px (2.4 mm across)
    keep[:25, 60:] = False  # a notch in the outline
    points = xyz[keep]
    rows, cols = np.nonzero(keep)
    open_ = param_mesh(points, uv[keep])
    too_small = param_mesh(points, uv[keep], fill_holes_mm=1.0)
    closed = param_mesh(points, uv[keep], fill_holes_mm=5.0)
    np.testing.assert_array_equal(too_small, open_)  # the hole's spans are over 1 mm
    assert boundary_figures(open_, points)["holes"] == 1
    figures = boundary_figures(closed, points)
    assert figures["holes"] == figures["hole_edges"] == 0
    topo = mesh_topology(closed, len(points))
    assert topo["non_manifold_edges"] == topo["non_manifold_vertices"] == 0
    assert topo["inconsistent_edges"] == 0
    r, c = rows[closed].mean(axis=1), cols[closed].mean(axis=1)
    assert np.any((r > 22) & (r < 27) & (c > 22) & (c < 27))  # across the hole
    assert not np.any((r < 21) & (c > 63))  # the notch stays open
    # the outline is as before: only the hole's boundary went
    assert topo["boundary_edges"] == boundary_figures(open_, points)["outline_edges"]


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.5, 3.0))
def test_param_mesh_is_edge_manifold_and_consistently_wound(seed, spread):
    """Any cloud and any plane: a subset of a planar triangulation."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform(0, 10, (300, 2))
    points = np.column_stack([uv, spread * np.sin(uv[:, 0])])
    faces = param_mesh(points, uv)
    topo = mesh_topology(faces, len(points))
    assert topo["non_manifold_edges"] == 0 and topo["inconsistent_edges"] == 0
    assert faces.min() >= 0 and faces.max() < len(points)


@pytest.mark.parametrize(("points", "uv", "kwargs", "match"), [
    (np.zeros((10, 3)), np.zeros((9, 2)), {}, "uv"),
    (np.full((10, 3), np.nan), np.zeros((10, 2)), {}, "finite"),
    (np.zeros((5, 3)), np.zeros((5, 2)), {}, "more than neighbours"),
    (np.random.default_rng(0).random((20, 3)), np.random.default_rng(1).random((20, 2)),
     {"edge_factor": 0.0}, "edge_factor"),
])
def test_param_mesh_bad_input(points, uv, kwargs, match):
    with pytest.raises(ValueError, match=match):
        param_mesh(points, uv, **kwargs)


# -- the super scan's PLY, on request -----------------------------------------------------------

@pytest.fixture(scope="module")
def ring_scans():
    from _synthetic import synthetic_scans

    return synthetic_scans(size=(64, 80), noise_px=0.05, seed=5)


def test_write_merge_seamless_mesh(ring_scans, tmp_path):
    """merge's super.ply: the cameras' grids side by side by default (seams open), one
    seamless surface with seamless_mesh=True on the very same vertices (the faces alone
    change); merge.json gives its topology."""
    from nail2nail.io.ply import read_ply
    from nail2nail.merge.report import write_merge

    grids = write_merge(ring_scans, tmp_path / "grids", figures=False, mat5=False)
    one = write_merge(ring_scans, tmp_path / "one", figures=False, mat5=False,
                      seamless_mesh=True)
    assert grids["super_scan"]["mesh"] is None
    mesh = one["super_scan"]["mesh"]
    a, b = read_ply(tmp_path / "grids" / "super.ply"), read_ply(tmp_path / "one" / "super.ply")
    np.testing.assert_array_equal(a.points, b.points)
    before, after = mesh_topology(a.faces, len(a.points)), mesh_topology(b.faces, len(b.points))
    print("\ngrids:", before, "\nseamless:", after)
    assert after == {k: mesh[k] for k in after}
    assert one["super_scan"]["faces"] == after["faces"] == len(b.faces)
    assert after["non_manifold_edges"] == after["inconsistent_edges"] == 0
    assert after["boundary_edges"] < 0.5 * before["boundary_edges"]
    assert after["non_manifold_vertices"] <= before["non_manifold_vertices"]
    # wound as the vertex normals (towards the cameras)
    p, n = b.points.astype(float), b.normals.astype(float)
    f = b.faces
    facing = (np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]]) * n[f[:, 0]]).sum(1)
    assert np.mean(facing > 0) > 0.99
    json_text = (tmp_path / "one" / "merge.json").read_text()
    assert '"seamless": true' in json_text


def test_cli_merge_seamless_mesh(ring_scans, tmp_path, capsys):
    from nail2nail.cli import main
    from nail2nail.io.ply import read_ply
    from nail2nail.io.scans import save_scans

    save_scans(tmp_path / "scans", ring_scans, mat5=False, ply=False)
    assert main(["-q", "merge", str(tmp_path / "scans"), "--out", str(tmp_path / "m"),
                 "--no-figures", "--seamless-mesh"]) == 0
    ply = read_ply(tmp_path / "m" / "super.ply")
    assert mesh_topology(ply.faces, len(ply.points))["non_manifold_edges"] == 0
    assert any("seamless" in c for c in ply.comments)
