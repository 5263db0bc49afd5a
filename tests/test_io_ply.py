"""Tests for nail2nail.io.ply: binary PLY point clouds and meshes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nail2nail.io.ply import read_ply, write_ply, write_scan_ply
from nail2nail.scan.results import Scan


@settings(max_examples=20, deadline=None)
@given(n=st.integers(0, 40), with_colors=st.booleans(), with_normals=st.booleans(),
       n_faces=st.integers(0, 10), seed=st.integers(0, 2**16))
def test_round_trip(tmp_path_factory, n, with_colors, with_normals, n_faces, seed):
    rng = np.random.default_rng(seed)
    path = tmp_path_factory.mktemp("ply") / "a.ply"
    points = rng.normal(0, 20, (n, 3)).astype(np.float32)
    colors = rng.integers(0, 256, (n, 3)).astype(np.uint8) if with_colors else None
    normals = rng.normal(size=(n, 3)).astype(np.float32) if with_normals else None
    faces = rng.integers(0, n, (n_faces, 3)) if n and n_faces else None
    write_ply(path, points, colors=colors, normals=normals, faces=faces, comments=["hello"])
    back = read_ply(path)
    np.testing.assert_array_equal(back.points, points)
    assert back.points.shape == (n, 3) and back.points.dtype == np.float32
    if with_colors:
        np.testing.assert_array_equal(back.colors, colors)
    else:
        assert back.colors is None
    if with_normals:
        np.testing.assert_array_equal(back.normals, normals)
    else:
        assert back.normals is None
    if faces is not None:
        np.testing.assert_array_equal(back.faces, faces)
        assert back.faces.dtype == np.int32
    else:
        assert back.faces is None
    assert back.comments == ["hello"]


def test_header_is_binary_little_endian(tmp_path):
    path = write_ply(tmp_path / "a.ply", [[1, 2, 3]], colors=[[1, 2, 3]], faces=[[0, 0, 0]])
    raw = path.read_bytes()
    header = raw[: raw.index(b"end_header\n") + 11].decode()
    assert header.splitlines() == [
        "ply", "format binary_little_endian 1.0", "element vertex 1",
        "property float x", "property float y", "property float z",
        "property uchar red", "property uchar green", "property uchar blue",
        "element face 1", "property list uchar int vertex_indices", "end_header",
    ]
    assert len(raw) == len(header) + 12 + 3 + 1 + 12
    assert np.frombuffer(raw[len(header):len(header) + 12], "<f4").tolist() == [1, 2, 3]


def test_reads_ascii_and_big_endian(tmp_path):
    ascii_ply = (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                 b"property float z\nproperty float quality\nelement face 1\n"
                 b"property list uchar int vertex_index\nend_header\n"
                 b"0 0 0 1\n1 0 0 2\n0 1 0 3\n3 0 1 2\n")
    (tmp_path / "a.ply").write_bytes(ascii_ply)
    data = read_ply(tmp_path / "a.ply")
    assert data.points.tolist() == [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    assert data.faces.tolist() == [[0, 1, 2]] and data.extra["quality"].tolist() == [1, 2, 3]
    body = np.array([[1.5, -2, 3]], ">f4").tobytes()
    (tmp_path / "b.ply").write_bytes(b"ply\nformat binary_big_endian 1.0\nelement vertex 1\n"
                                     b"property float x\nproperty float y\nproperty float z\n"
                                     b"end_header\n" + body)
    assert read_ply(tmp_path / "b.ply").points.tolist() == [[1.5, -2, 3]]


def test_write_scan_ply(tmp_path):
    mask = np.array([[True, False], [True, True]])
    xyz = np.arange(12, dtype=np.float32).reshape(2, 2, 3)
    xyz[1, 1] = np.nan
    nan = np.full((2, 2), np.nan, np.float32)
    scan = Scan(name="cam1", xyz=xyz, xp=nan, yp=nan, albedo=np.full((2, 2), 0.5, np.float32),
                intensity=nan, modulation=nan, mask=mask)
    write_scan_ply(tmp_path / "s.ply", scan)
    data = read_ply(tmp_path / "s.ply")
    np.testing.assert_array_equal(data.points, xyz[[0, 1], [0, 0]])
    assert data.colors.tolist() == [[128, 128, 128]] * 2
    assert data.comments == ["nail2nail scan cam1"]


def test_bad_inputs(tmp_path):
    with pytest.raises(ValueError, match=r"points: expected shape \(N, 3\)"):
        write_ply(tmp_path / "a.ply", np.zeros((3, 2)))
    with pytest.raises(ValueError, match="NaN"):
        write_ply(tmp_path / "a.ply", [[0, 0, np.nan]])
    with pytest.raises(ValueError, match="colors: expected integers"):
        write_ply(tmp_path / "a.ply", np.zeros((1, 3)), colors=[[0, 0, 300]])
    with pytest.raises(ValueError, match=r"faces: vertex indices must lie in \[0, 1\)"):
        write_ply(tmp_path / "a.ply", np.zeros((1, 3)), faces=[[0, 1, 0]])
    assert not (tmp_path / "a.ply").exists()
    (tmp_path / "x.ply").write_bytes(b"solid stl\n")
    with pytest.raises(ValueError, match="not a PLY file"):
        read_ply(tmp_path / "x.ply")
    write_ply(tmp_path / "t.ply", np.zeros((4, 3)))
    (tmp_path / "t.ply").write_bytes((tmp_path / "t.ply").read_bytes()[:-5])
    with pytest.raises(ValueError, match="truncated element vertex"):
        read_ply(tmp_path / "t.ply")
