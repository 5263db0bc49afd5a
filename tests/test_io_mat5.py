"""Tests for nail2nail.io.mat5: the thesis's legacy scan format."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from nail2nail.io.mat5 import MAT5_SUFFIXES, mat5_paths, read_mat5, write_mat5
from nail2nail.scan.results import Scan


def make_scan(shape=(7, 9), seed=0, name="cam0") -> Scan:
    rng = np.random.default_rng(seed)
    h, w = shape
    mask = rng.random(shape) > 0.3
    xyz = rng.normal(0, 10, (h, w, 3)).astype(np.float32)
    xp = rng.uniform(0, 1280, shape).astype(np.float32)
    yp = rng.uniform(0, 1040, shape).astype(np.float32)
    for a in (xp, yp):
        a[~mask] = np.nan
    xyz[~mask] = np.nan
    albedo = rng.random(shape).astype(np.float32)
    modulation = rng.uniform(0.0, 0.5, shape).astype(np.float32)
    intensity = np.where(mask, 2 * modulation, 0).astype(np.float32)
    intensity[0, 0] = 1e-4  # tiny but valid (if mask[0, 0]) must stay valid
    return Scan(name=name, xyz=xyz, xp=xp, yp=yp, albedo=albedo, intensity=intensity,
                modulation=modulation, mask=mask)


def matlab_appendix_reader(fname1):
    """The appendix MATLAB code, line by line (1-based indexing aside)."""
    with Image.open(fname1 + "C.bmp") as im:
        c1 = np.asarray(im)  # c1=imread(fnamec1);
    My, Nx, a = c1.shape  # [My,Nx,a]=size(c1);
    with Image.open(fname1 + "I.bmp") as im:
        i1 = np.asarray(im)  # i1=imread(fnamei1);
    out = {}
    for key in ("X", "Y", "Z", "XP", "YP"):
        with open(fname1 + f"{key}.by", "rb") as fd:  # fd=fopen(fnamex1);
            v = np.fromfile(fd, dtype="<f4")  # xw1=fread(fd,'float'); (column vector)
        # xw1=reshape(xw1,Nx,My)';  MATLAB reshape fills column-major, then transpose
        out[key] = v.reshape((Nx, My), order="F").T
    return c1, i1, out, (My, Nx, a)


def test_round_trip_exact(tmp_path):
    scan = make_scan()
    paths = write_mat5(tmp_path / "sub" / "cam0", scan)
    assert [p.name for p in paths] == [f"cam0{s}" for s in MAT5_SUFFIXES]
    back = read_mat5(tmp_path / "sub" / "cam0")
    assert back.name == "cam0"
    np.testing.assert_array_equal(back.mask, scan.mask)
    np.testing.assert_array_equal(back.xyz, scan.xyz)  # NaN == NaN for assert_array_equal
    np.testing.assert_array_equal(back.xp, scan.xp)
    np.testing.assert_array_equal(back.yp, scan.yp)
    np.testing.assert_array_equal(back.albedo, np.rint(scan.albedo * 255) / np.float32(255))
    assert back.xyz.dtype == np.float32 and back.albedo.dtype == np.float32
    assert np.all(back.intensity[back.mask] >= 1 / 255) and np.all(back.intensity[~back.mask] == 0)
    # writing what was read reproduces every file byte for byte
    write_mat5(tmp_path / "again", back)
    for suffix in MAT5_SUFFIXES:
        assert (tmp_path / f"again{suffix}").read_bytes() == (tmp_path / "sub" / f"cam0{suffix}"
                                                               ).read_bytes()
    assert not list((tmp_path / "sub").glob("*.tmp"))


def test_file_layout_read_by_appendix_matlab_code(tmp_path):
    scan = make_scan((5, 8), seed=3)
    write_mat5(tmp_path / "scan", scan)
    c1, i1, planes, (My, Nx, a) = matlab_appendix_reader(str(tmp_path / "scan"))
    assert (My, Nx, a) == (5, 8, 3)
    assert c1.dtype == np.uint8 and i1.shape == (5, 8)
    valid = i1 > 0  # "if i1(m,n) > 0"
    np.testing.assert_array_equal(valid, scan.mask)
    for key, ref in (("X", scan.xyz[..., 0]), ("Y", scan.xyz[..., 1]), ("Z", scan.xyz[..., 2]),
                     ("XP", scan.xp), ("YP", scan.yp)):
        np.testing.assert_array_equal(planes[key][valid], ref[valid])
        assert np.all(planes[key][~valid] == 0)
    # the element at row m, column n is the (m * Nx + n)-th float on disk
    raw = np.fromfile(tmp_path / "scanXP.by", dtype="<f4")
    m, n = np.argwhere(valid)[0]
    assert raw[m * Nx + n] == scan.xp[m, n]
    assert (tmp_path / "scanX.by").stat().st_size == 4 * 5 * 8
    with Image.open(tmp_path / "scanC.bmp") as im:
        assert im.mode == "RGB" and im.format == "BMP"


def test_invalid_xyz_written_invalid(tmp_path):
    scan = make_scan((4, 4), seed=1)
    scan.mask[:] = True
    scan.xyz = np.ones((4, 4, 3), np.float32)
    scan.xyz[1, 1, 2] = np.nan
    write_mat5(tmp_path / "a", scan)
    back = read_mat5(tmp_path / "a", name="other")
    assert back.name == "other" and not back.mask[1, 1] and back.mask.sum() == 15


def test_bad_inputs(tmp_path):
    with pytest.raises(TypeError, match="expected a Scan"):
        write_mat5(tmp_path / "a", {"xyz": 0})
    scan = make_scan((4, 4))
    scan.xp = scan.xp[:2]
    with pytest.raises(ValueError, match=r"scan.xp: expected shape \(4, 4\)"):
        write_mat5(tmp_path / "a", scan)
    write_mat5(tmp_path / "b", make_scan((4, 4)))
    paths = mat5_paths(tmp_path / "b")
    paths["Z.by"].write_bytes(b"\0" * 12)
    with pytest.raises(ValueError, match=r"bZ.by: expected 4 x 4 float32 \(64 bytes\), got 12"):
        read_mat5(tmp_path / "b")
    paths["YP.by"].unlink()
    paths["Z.by"].write_bytes(b"\0" * 64)
    with pytest.raises(FileNotFoundError):
        read_mat5(tmp_path / "b")
