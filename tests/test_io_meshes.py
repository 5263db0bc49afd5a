"""Mesh exports for 3D tools (issue 27): ``nail2nail.io.meshes`` and ``export-mesh``."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from nail2nail.cli import main
from nail2nail.io.meshes import MESH_FORMATS, write_mesh
from nail2nail.io.ply import read_ply, write_ply
from nail2nail.merge.mesh import mesh_topology


def _patch(n: int = 12):
    """A finger-like patch (a cylinder of radius 5 mm, ±1 rad, 15 mm long): points (mm),
    triangles, grey colours, normals."""
    t, y = np.meshgrid(np.linspace(-1, 1, n), np.linspace(0, 15, n))
    points = np.stack([5 * np.sin(t), y, 5 * np.cos(t)], -1).reshape(-1, 3)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[:-1, 1:], idx[1:, 1:]
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                            np.stack([c, b, d], -1).reshape(-1, 3)])
    grey = (np.linspace(30, 220, len(points))).astype(np.uint8)
    normals = np.stack([np.sin(t), 0 * t, np.cos(t)], -1).reshape(-1, 3)
    return points, faces, np.stack([grey] * 3, -1), normals


@pytest.mark.parametrize("suffix", sorted(MESH_FORMATS))
def test_write_mesh_round_trip(suffix, tmp_path):
    """trimesh reads back every format: the same triangles (as coordinates: STL keeps no
    shared vertices), colours where the format holds them, one consistent winding."""
    points, faces, colors, normals = _patch()
    path = write_mesh(tmp_path / f"patch{suffix}", points, faces, colors=colors,
                      normals=normals)
    back = trimesh.load(path, process=False, force="mesh")
    np.testing.assert_allclose(back.vertices[back.faces], points[faces], atol=1e-5)
    assert back.is_winding_consistent
    if suffix in (".ply", ".obj", ".glb"):
        assert len(back.vertices) == len(points)
        np.testing.assert_array_equal(back.visual.vertex_colors[:, :3], colors)
    assert not list(tmp_path.glob(".*tmp"))  # the temporary file renamed


@pytest.mark.parametrize(("name", "faces", "match"), [
    ("m.xyz", [[0, 1, 2]], "unknown mesh format"),
    ("m.stl", np.zeros((0, 3), int), "needs triangles"),
    ("m.glb", [[0, 1, 5]], "indices"),
])
def test_write_mesh_bad_input(name, faces, match, tmp_path):
    with pytest.raises(ValueError, match=match):
        write_mesh(tmp_path / name, np.eye(3), faces)
    assert list(tmp_path.iterdir()) == []


def test_cli_export_mesh(tmp_path, capsys):
    """From a merge directory (super.ply), as GLB; --seamless re-meshes a point cloud;
    bad suffix, missing input, a point cloud without --seamless: exit 2, nothing written."""
    points, faces, colors, normals = _patch(20)
    merge = tmp_path / "merge"
    write_ply(merge / "super.ply", points, colors=colors, normals=normals, faces=faces)
    assert main(["-q", "export-mesh", str(merge), "-o", str(tmp_path / "f.glb")]) == 0
    glb = trimesh.load(tmp_path / "f.glb", process=False, force="mesh")
    assert len(glb.faces) == len(faces)
    write_ply(tmp_path / "cloud.ply", points, colors=colors, normals=normals)
    assert main(["-q", "export-mesh", str(tmp_path / "cloud.ply"), "-o",
                 str(tmp_path / "s.obj"), "--seamless"]) == 0
    obj = trimesh.load(tmp_path / "s.obj", process=False, force="mesh")
    topo = mesh_topology(obj.faces, len(obj.vertices))
    assert topo["non_manifold_edges"] == topo["inconsistent_edges"] == 0
    assert topo["boundary_edges"] == 4 * 19  # the patch's outline
    capsys.readouterr()
    for args, needle in (
            ([str(merge), "-o", str(tmp_path / "x.xyz")], "--out"),
            ([str(tmp_path / "absent.ply"), "-o", str(tmp_path / "x.obj")], "absent.ply"),
            ([str(tmp_path / "cloud.ply"), "-o", str(tmp_path / "x.stl")], "point cloud")):
        assert main(["export-mesh", *args]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and needle in err[0], err
    assert not any(tmp_path.glob("x.*"))
    assert read_ply(merge / "super.ply").faces is not None  # the source untouched


def test_a_fifo_given_as_the_mesh_is_refused_unopened(tmp_path, capsys):
    """Found by ``bench/fuzz_cli.py``: ``export-mesh FIFO`` waited for a writer forever
    (read_ply opened it); a PLY reader now refuses anything but a regular file first."""
    import os

    fifo = tmp_path / "pipe.ply"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match=r"not a regular file \(a FIFO"):
        read_ply(fifo)
    assert main(["export-mesh", str(fifo), "-o", str(tmp_path / "m.glb")]) == 2
    assert "FIFO" in capsys.readouterr().err
    assert not (tmp_path / "m.glb").exists()
