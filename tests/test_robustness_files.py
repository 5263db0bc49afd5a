"""Issue 10: manifests, calibrations and scan manifests checked, not assumed (real files)."""

from __future__ import annotations

import numpy as np
import pytest
from _robustness import _calibration, _capture, _one_error_line, _scan_dir

from nail2nail.calibration.files import load_calibration
from nail2nail.cli import main
from nail2nail.io._json import read_json, write_json
from nail2nail.io.capture import read_capture, read_frame, write_frame
from nail2nail.io.scans import load_scans, save_scans


def _edit(path, change):
    data = read_json(path)
    change(data)
    write_json(path, data)


# ------------------------------------------------------------------------- versions, formats


@pytest.mark.parametrize("version", [2, "abc", "1", True, None])
def test_capture_unknown_version(tmp_path, capsys, version):
    cap = _capture(tmp_path / "cap")
    _edit(cap / "capture.json", lambda d: d.update(version=version))
    with pytest.raises(ValueError, match=r"capture.json: unknown version"):
        read_capture(cap)
    calib = _calibration(tmp_path / "calib.json")
    assert main(["scan", str(cap), "--calib", str(calib), "--out", str(tmp_path / "o")]) == 2
    _one_error_line(capsys, "capture.json", "version")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("bit_depth", [99, 0, 7, "8", True])
def test_capture_unknown_bit_depth(tmp_path, bit_depth):
    cap = _capture(tmp_path / "cap")
    _edit(cap / "capture.json", lambda d: d.update(bit_depth=bit_depth))
    with pytest.raises(ValueError, match=r"capture.json: bit_depth"):
        read_capture(cap)


@pytest.mark.parametrize("version", [2, "abc"])
def test_calibration_unknown_version(tmp_path, capsys, version):
    calib = _calibration(tmp_path / "calib.json")
    _edit(calib, lambda d: d.update(version=version))
    with pytest.raises(ValueError, match=r"calib.json: unknown version"):
        load_calibration(calib)
    cap = _capture(tmp_path / "cap")
    assert main(["scan", str(cap), "--calib", str(calib), "--out", str(tmp_path / "o")]) == 2
    _one_error_line(capsys, "calib.json", "unknown version")
    _edit(calib, lambda d: d.pop("version"))
    with pytest.raises(ValueError, match=r"calib.json: no 'version'"):
        load_calibration(calib)


def test_scan_json_unknown_version(tmp_path):
    scans = _scan_dir(tmp_path / "s")
    _edit(scans / "scan.json", lambda d: d.update(version=2))
    with pytest.raises(ValueError, match=r"scan.json: unknown version 2"):
        load_scans(scans)


# ------------------------------------------------------------------------- names and paths


def test_duplicate_camera_names(tmp_path, capsys):
    cap = _capture(tmp_path / "cap", names=("cam0", "cam1"))
    _edit(cap / "capture.json", lambda d: d["cameras"][1].update(name="cam0"))
    with pytest.raises(ValueError, match=r"capture.json: two cameras are named 'cam0'"):
        read_capture(cap)
    calib = _calibration(tmp_path / "calib.json", names=("cam0", "cam0"))
    with pytest.raises(ValueError, match=r"calib.json: two cameras are named 'cam0'"):
        load_calibration(calib)
    assert main(["scan", str(cap), "--calib", str(calib), "--out", str(tmp_path / "o")]) == 2
    _one_error_line(capsys, "calib.json", "'cam0'")
    scans = _scan_dir(tmp_path / "s")
    _edit(scans / "scan.json", lambda d: d["cameras"][1].update(name="cam0"))
    with pytest.raises(ValueError, match=r"scan.json: two cameras"):
        load_scans(scans)


@pytest.mark.parametrize("name", ["../escape", "a/b", "a\\b", "", "..", "/abs", "C:x", 3])
def test_camera_names_are_plain(tmp_path, capsys, name):
    cap = _capture(tmp_path / "cap")
    _edit(cap / "capture.json", lambda d: d["cameras"][0].update(name=name))
    with pytest.raises(ValueError, match=r"capture.json: cameras\[0\].name"):
        read_capture(cap)
    calib = _calibration(tmp_path / "calib.json")
    _edit(calib, lambda d: d["cameras"][0].update(name=name))
    assert main(["scan", str(cap), "--calib", str(calib), "--out", str(tmp_path / "o")]) == 2
    _one_error_line(capsys, "calib.json", "cameras[0].name")
    assert not (tmp_path / "o").exists() and not (tmp_path / "escape.npz").exists()


def test_save_scans_refuses_path_names(tmp_path):
    from nail2nail.scan.results import Scan

    nan = np.full((2, 2), np.nan)
    scan = Scan(name="../escape", xyz=np.full((2, 2, 3), np.nan), xp=nan, yp=nan,
                albedo=np.zeros((2, 2)), intensity=np.zeros((2, 2)),
                modulation=np.zeros((2, 2)), mask=np.zeros((2, 2), bool))
    with pytest.raises(ValueError, match=r"not a plain name"):
        save_scans(tmp_path / "out", [scan])
    assert not (tmp_path / "out").exists() and not (tmp_path / "escape.npz").exists()


@pytest.mark.parametrize("frame", ["../outside.png", "/etc/hostname", "cam0/../../outside.png",
                                   "link/000.png"])
def test_frame_paths_stay_inside_capture(tmp_path, capsys, frame):
    cap = _capture(tmp_path / "cap")
    write_frame(tmp_path / "outside.png", np.zeros((6, 8), np.uint8))
    (cap / "link").symlink_to(tmp_path)  # a directory link leading out of the capture
    (tmp_path / "000.png").write_bytes((tmp_path / "outside.png").read_bytes())
    _edit(cap / "capture.json", lambda d: d["cameras"][0]["frames"].__setitem__(0, frame))
    with pytest.raises(ValueError, match=r"capture.json: cameras\[0\].frames"):
        read_capture(cap)
    calib = _calibration(tmp_path / "calib.json")
    assert main(["scan", str(cap), "--calib", str(calib), "--out", str(tmp_path / "o")]) == 2
    _one_error_line(capsys, "capture.json", repr(frame))


@pytest.mark.parametrize("npz", ["../outside.npz", "/tmp/outside.npz", ""])
def test_scan_npz_path_stays_inside(tmp_path, capsys, npz):
    scans = _scan_dir(tmp_path / "s", npz_path=npz)
    with pytest.raises(ValueError, match=r"scan.json: cameras\[0\].npz"):
        load_scans(scans)
    assert main(["merge", str(scans), "--out", str(tmp_path / "m")]) == 2
    _one_error_line(capsys, "scan.json", "cameras[0].npz")


# ------------------------------------------------------------------------- frame sizes, depth


def test_frame_size_differs_from_manifest(tmp_path, capsys):
    cap = _capture(tmp_path / "cap", size=(8, 6))
    _edit(cap / "capture.json", lambda d: d["cameras"][0].update(size=[16, 12]))
    with pytest.raises(ValueError, match=r"000.png: frame is 8 x 6 px.*16 x 12"):
        read_capture(cap)
    calib = _calibration(tmp_path / "calib.json")
    assert main(["scan", str(cap), "--calib", str(calib), "--out", str(tmp_path / "o")]) == 2
    _one_error_line(capsys, "000.png", "16 x 12")


def test_capture_without_pattern_set_names_its_manifest(tmp_path, capsys):
    """A capture whose manifest has no pattern set: scan says which file and what is missing
    (issue 24: it said "expected a PatternSet, got NoneType")."""
    cap = _capture(tmp_path / "cap", size=(8, 6))
    calib = _calibration(tmp_path / "calib.json")
    assert main(["scan", str(cap), "--calib", str(calib), "--out", str(tmp_path / "o")]) == 2
    _one_error_line(capsys, "capture.json", '"pattern_set" is null or missing')
    assert not (tmp_path / "o").exists()


def test_frames_of_different_sizes(tmp_path):
    cap = _capture(tmp_path / "cap")
    _edit(cap / "capture.json", lambda d: d["cameras"][0].pop("size"))
    write_frame(cap / "cam0" / "001.png", np.zeros((7, 8), np.uint8))
    with pytest.raises(ValueError, match=r"001.png: frame is 8 x 7 px.*first frame is 8 x 6"):
        read_capture(cap)


@pytest.mark.parametrize("size", [[8], [0, 6], [8.5, 6], "8x6"])
def test_bad_size_entry(tmp_path, size):
    cap = _capture(tmp_path / "cap")
    _edit(cap / "capture.json", lambda d: d["cameras"][0].update(size=size))
    with pytest.raises(ValueError, match=r"capture.json: cameras\[0\].size"):
        read_capture(cap)


def test_sixteen_bit_png_under_bit_depth_8(tmp_path, capsys):
    frames = [np.arange(48, dtype=np.uint16).reshape(6, 8) * 5] * 2  # 0-255 in a 16-bit PNG
    cap = _capture(tmp_path / "cap", frames=frames, bit_depth=8)
    with pytest.raises(ValueError, match=r"000.png: a 16-bit image, but the capture's bit_depth"):
        read_capture(cap)
    calib = _calibration(tmp_path / "calib.json")
    assert main(["scan", str(cap), "--calib", str(calib), "--out", str(tmp_path / "o")]) == 2
    _one_error_line(capsys, "000.png", "bit_depth is 8")


@pytest.mark.parametrize("bit_depth", [10, 12])
def test_right_aligned_values_refused(tmp_path, bit_depth):
    top = 2**bit_depth - 1
    right = (np.linspace(0, top, 48).astype(np.uint16)).reshape(6, 8)
    write_frame(tmp_path / "r.png", right)
    with pytest.raises(ValueError, match=r"r.png: .*left-aligned"):
        read_frame(tmp_path / "r.png", bit_depth=bit_depth)
    write_frame(tmp_path / "l.png", right << np.uint16(16 - bit_depth))
    np.testing.assert_allclose(read_frame(tmp_path / "l.png", bit_depth=bit_depth),
                               right / top, atol=1e-7)
    write_frame(tmp_path / "e.png", right.astype(np.uint8))
    with pytest.raises(ValueError, match=r"e.png: an 8-bit image"):
        read_frame(tmp_path / "e.png", bit_depth=bit_depth)


@pytest.mark.parametrize("mode", ["P", "1", "RGB", "LA"])
def test_non_grey_frames_refused(tmp_path, mode):
    from PIL import Image

    Image.new(mode, (8, 6)).save(tmp_path / "f.png")
    with pytest.raises(ValueError, match=r"f.png: expected a single-channel grey image"):
        read_frame(tmp_path / "f.png")
    with pytest.raises(ValueError, match=r"bit_depth"):
        read_frame(tmp_path / "f.png", bit_depth=99)


def test_pattern_set_errors_name_manifest(tmp_path):
    cap = _capture(tmp_path / "cap")
    _edit(cap / "capture.json", lambda d: d.update(pattern_set={"format": "nope"}))
    with pytest.raises(ValueError, match=r"capture.json: pattern_set"):
        read_capture(cap)
