"""Issue 29: calibration files read and written by import-/export-calibration, calibrate and
calibrate-board: hostile inputs give exit 2, one line naming the file or option and the value,
nothing written, no signal (a segmentation fault, a hang, gigabytes of memory)."""

from __future__ import annotations

import contextlib
import json
import os
import re
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from _robustness import _capture, _one_error_line

from nail2nail.calibration.files import (
    CameraCalibration,
    RigCalibration,
    load_calibration,
    save_calibration,
)
from nail2nail.calibration.opencv_files import (
    MAX_FILE_BYTES,
    MAX_NESTING,
    read_opencv_calibration,
    write_opencv_calibration,
)
from nail2nail.cli import main
from nail2nail.scan.patterns import PatternSet
from nail2nail.simulation.rig import default_rig, ideal_calibration


@pytest.fixture(scope="module")
def slstudio_text(tmp_path_factory) -> str:
    """A valid SLStudio calibration.yml (float64), as OpenCV writes it."""
    rig = default_rig(0.25, projector_distortion="none")
    camera, projector = rig.cameras[1], rig.projector
    Rp = projector.R @ camera.R.T
    entries = {"Kc": camera.K, "kc": camera.dist.reshape(1, 5), "Kp": projector.K,
               "kp": projector.dist.reshape(1, 5), "Rp": Rp,
               "Tp": (projector.t - Rp @ camera.t).reshape(3, 1),
               "frameWidth": camera.size[0], "frameHeight": camera.size[1],
               "screenResX": projector.size[0], "screenResY": projector.size[1]}
    path = tmp_path_factory.mktemp("slstudio") / "calibration.yml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in entries.items():
        fs.write(key, value)
    fs.release()
    text = path.read_text()
    assert _matrix(3, 3) in text and "frameWidth: 256\n" in text
    assert "Tp: !!opencv-matrix\n   rows: 3\n   cols: 1\n   dt: d\n   data: [ " in text
    read_opencv_calibration(path)  # valid as written
    return text


def _listing(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir())


# -- 1. parsers behind guards -------------------------------------------------------------------

_CHILD = """
import contextlib, io, json, resource, sys
resource.setrlimit(resource.RLIMIT_AS, (3 * 2**30, 3 * 2**30))  # a regression fails, small
from nail2nail.cli import main
results = []
for path in sys.argv[2:]:
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main(["import-calibration", path, "-o", sys.argv[1]])
    results.append([path, code, err.getvalue()])
print(json.dumps(results))
"""


@pytest.mark.skipif(os.name != "posix", reason="FIFOs, /dev/zero and setrlimit are POSIX")
def test_deep_files_devices_and_fifos_are_refused_before_opencv(tmp_path):
    """A file nested 100 000 levels deep killed the process inside OpenCV (signal 11),
    /dev/zero took gigabytes, a FIFO nobody writes to hung: run in a child process, which a
    regression kills or stops (3 GiB, 120 s) without taking pytest with it."""
    d = 100_000
    deep = {"deep.yml": "%YAML:1.0\n---\na: " + "[" * d + "]" * d + "\n",
            "deep.xml": '<?xml version="1.0"?>\n<opencv_storage>\n' + "<a>" * d + "</a>" * d
                        + "\n</opencv_storage>\n",
            "deep.json": '{"a": ' + "[" * d + "]" * d + "}\n"}
    for name, text in deep.items():
        (tmp_path / name).write_text(text)
    os.mkfifo(tmp_path / "fifo.yml")
    paths = [*(str(tmp_path / n) for n in deep), "/dev/zero", str(tmp_path / "fifo.yml")]
    out = tmp_path / "rig.json"
    child = subprocess.run([sys.executable, "-c", _CHILD, str(out), *paths],
                           capture_output=True, text=True, timeout=120, check=False)
    assert child.returncode == 0, (child.returncode, child.stderr[-2000:])
    results = json.loads(child.stdout)
    expected = [f"nested deeper than {MAX_NESTING} levels"] * 3 + [
        "not a regular file (a character device)", "not a regular file (a FIFO"]
    for (path, code, err), message in zip(results, expected, strict=True):
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1, (path, err)
        assert lines[0].startswith(f"nail2nail import-calibration: error: {path}: "), lines[0]
        assert message in lines[0], lines[0]
    assert _listing(tmp_path) == ["deep.json", "deep.xml", "deep.yml", "fifo.yml"]


def test_fifo_refused_by_the_library_without_opening_it(tmp_path):
    if not hasattr(os, "mkfifo"):
        pytest.skip("no FIFOs here")
    os.mkfifo(tmp_path / "calibration.xml")
    # O_NONBLOCK open and stat first: this returns at once (an open() would wait for a writer)
    with pytest.raises(ValueError, match=r"calibration\.xml: not a regular file \(a FIFO"):
        read_opencv_calibration(tmp_path / "calibration.xml")


def _matrix(rows, cols, dt="d", data="[ 1200., 0., 127.5, 0., 1200., 159.5, 0., 0., 1. ]"):
    return (f"Kc: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: {dt}\n"
            f"   data: {data}\n")


#: Tp's first number (a regular expression)
_TP = re.compile(r"(Tp: !!opencv-matrix\n   rows: 3\n   cols: 1\n   dt: d\n   data: \[ )[^,]+,")
# (replace what, by what, the message's words after the file name)
_BAD_CONTENT = {
    "header_100000_squared": (None, _matrix(100000, 100000),
                              ["Kc: a 100000 x 100000 matrix", "10000000000 numbers"]),
    "header_16384_squared": (None, _matrix(16384, 16384),
                             ["Kc: a 16384 x 16384 matrix", "268435456 numbers"]),
    "rows_cols_disagree_with_data": (None, _matrix(3, 4),
                                     ["Kc: a 3 x 4 matrix", "needs 12 numbers, its data holds 9"]),
    "unknown_dt": (None, _matrix(3, 3, dt="q"), ["Kc.dt: expected an OpenCV element type",
                                                 "got 'q'"]),
    "rows_wrapped_to_3": (None, _matrix(4294967299, 3),
                          ["rows: 4294967299", "beyond the 32-bit integers"]),
    "width_1e10_integer": ("frameWidth: 256\n", "frameWidth: 10000000000\n",
                           ["frameWidth: 10000000000", "beyond the 32-bit integers"]),
    "width_wrapped_to_256": ("frameWidth: 256\n", "frameWidth: 4294967552\n",
                             ["frameWidth: 4294967552", "beyond the 32-bit integers"]),
    "width_1e10_real": ("frameWidth: 256\n", "frameWidth: 1e10\n",
                        ["frameWidth: 1e+10 px, beyond 100000 px"]),
    "kc_1e308": (None, _matrix(3, 3, data="[ 1e308, 0., 127.5, 0., 1200., 159.5, 0., 0., 1. ]"),
                 ["camera 'cam0': Kc: fx = 1e+308 px, beyond 1e+06 px"]),
    "translation_1e308": (_TP, r"\g<1>1e308,", ["the projector (of camera 'cam0'): Tp: "
                                                "translation [1e+308,", "|t| = 1e+308 mm"]),
    "translation_1e6_mm": (_TP, r"\g<1>1e6,", ["Tp: translation [1e+06,",
                                               "not below 100000 mm"]),
    "deep_block_yaml": ("frameWidth: 256\n", "frameWidth: 256\nextra:\n" + "".join(
        " " * (i + 1) + f"k{i}:\n" for i in range(MAX_NESTING + 2)) + " " * 40 + "v: 1\n",
        [f"nested deeper than {MAX_NESTING} levels (line "]),
}


@pytest.mark.parametrize("case", sorted(_BAD_CONTENT))
def test_bad_calibration_content_exit_2_naming_the_file(case, slstudio_text, tmp_path, capsys):
    old, new, words = _BAD_CONTENT[case]
    if isinstance(old, re.Pattern):
        text, n = old.subn(new, slstudio_text, count=1)
        assert n == 1
    else:
        old = _matrix(3, 3) if old is None else old
        assert old in slstudio_text
        text = slstudio_text.replace(old, new, 1)
    path = tmp_path / "calibration.yml"
    path.write_text(text)
    assert main(["import-calibration", str(path), "-o", str(tmp_path / "rig.json")]) == 2
    line = _one_error_line(capsys, f"nail2nail import-calibration: error: {path}: ", *words)
    assert "rank-deficient" not in line and "internal error" not in line
    assert _listing(tmp_path) == ["calibration.yml"]


def test_oversized_file_refused_before_reading_it(tmp_path, capsys):
    """A 300 MB file of spaces gave OpenCV's message as an internal error: any file beyond
    MAX_FILE_BYTES (1 MiB) is refused from its size."""
    path = tmp_path / "spaces.yml"
    with open(path, "wb") as fh:  # sparse where the file system allows: no 300 MB written
        fh.truncate(300 * 2**20)
    assert main(["import-calibration", str(path), "-o", str(tmp_path / "rig.json")]) == 2
    _one_error_line(capsys, f"{path}: larger than 1 MiB")
    path.write_bytes(b" " * (MAX_FILE_BYTES + 1))
    with pytest.raises(ValueError, match=r"spaces\.yml: larger than 1 MiB"):
        read_opencv_calibration(path)
    assert _listing(tmp_path) == ["spaces.yml"]


def test_xml_values_checked_as_yaml(slstudio_text, tmp_path, capsys):
    """The same guards on OpenCV's XML: a frame width beyond 32 bits, a huge header."""
    yml = tmp_path / "good.yml"
    yml.write_text(slstudio_text)
    fs = cv2.FileStorage(str(yml), cv2.FILE_STORAGE_READ)
    out = cv2.FileStorage(str(tmp_path / "good.xml"), cv2.FILE_STORAGE_WRITE)
    for key in fs.root().keys():
        node = fs.getNode(key)
        out.write(key, node.mat() if node.isMap() else int(node.real()))
    out.release()
    fs.release()
    text = (tmp_path / "good.xml").read_text()
    assert "<frameWidth>256</frameWidth>" in text and "<rows>3</rows>" in text
    for old, new, words in [("<frameWidth>256<", "<frameWidth>10000000000<",
                             ["frameWidth: 10000000000", "32-bit"]),
                            ("<rows>3</rows>\n  <cols>3</cols>",
                             "<rows>100000</rows>\n  <cols>100000</cols>",
                             ["Kc: a 100000 x 100000 matrix"])]:
        path = tmp_path / "calibration.xml"
        path.write_text(text.replace(old, new, 1))
        assert main(["import-calibration", str(path), "-o", str(tmp_path / "rig.json")]) == 2
        _one_error_line(capsys, f"{path}: ", *words)
    assert not (tmp_path / "rig.json").exists()


# -- 2. values checked on import and on export -------------------------------------------------

def _pinhole_rig_json(path: Path, **edit) -> Path:
    rig = default_rig(0.25, projector_distortion="none")
    data = ideal_calibration(rig)
    for key, value in edit.items():  # "camera_t" -> cameras[0].camera.t
        role, field = key.split("_")
        data["cameras"][0][role][field] = value
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize(("edit", "words"), [
    ({"projector_t": [1e308, 0.0, 300.0]}, ["cameras[0] ('cam0').projector: t: translation "
                                            "[1e+308, 0, 300] mm"]),
    ({"camera_size": [10000000000, 80]}, ["cameras[0] ('cam0').camera: size: expected [W, H], "
                                          "integers in 1 … 100000 px, got [10000000000, 80]"]),
])
def test_export_refuses_the_values_import_refuses(edit, words, tmp_path, capsys):
    calib = _pinhole_rig_json(tmp_path / "rig.json", **edit)
    calib_text = calib.read_text()
    assert main(["export-calibration", str(calib), "-o", str(tmp_path / "rig.yml")]) == 2
    _one_error_line(capsys, f"error: {calib}: ", *words)
    with pytest.raises(ValueError, match="cameras"):
        load_calibration(calib)
    assert _listing(tmp_path) == ["rig.json"] and calib.read_text() == calib_text


def test_export_library_refuses_out_of_range_models(tmp_path):
    calib = RigCalibration.from_dict(ideal_calibration(default_rig(0.25,
                                                                   projector_distortion="none")))
    cam = calib.cameras[1]
    cam.projector.t = np.array([0.0, 0.0, 1e308])  # set after the checks of from_dict
    with pytest.raises(ValueError, match=r"calibration: the projector of 'cam1': t: translation "
                                         r"\[0, 0, 1e\+308\] mm"):
        write_opencv_calibration(tmp_path / "rig.yml", calib)
    assert _listing(tmp_path) == []


# -- 3. calibrate -o DIR: nothing written ------------------------------------------------------

def test_calibrate_capture_output_directory_refused_before_any_work(tmp_path, monkeypatch,
                                                                     capsys):
    """-o naming a directory was refused only after the points tables were moved beside it."""
    import nail2nail.cli._calibrate_capture as cc

    capture = _capture(tmp_path / "capture")
    called = []
    obs = [SimpleNamespace(name=n, grid=None, xyz_world=np.eye(3) + i,
                           xy_camera=np.ones((3, 2)), xy_projector=np.ones((3, 2)))
           for i, n in enumerate(("cam0", "cam1"))]
    monkeypatch.setattr(cc, "target_observations", lambda *a, **k: called.append(1) or obs)
    monkeypatch.setattr(cc, "calibrate_from_observations",
                        lambda *a, **k: (RigCalibration(cameras=[CameraCalibration(
                            "cam0", np.hstack([np.eye(3), np.ones((3, 1))]),
                            np.hstack([np.eye(3), np.ones((3, 1))]), (8, 6))]), {}))
    monkeypatch.setattr(cc, "check_handedness", lambda *a, **k: None)
    out = tmp_path / "out"
    (out / "rig.json").mkdir(parents=True)
    assert main(["calibrate", str(capture), "-o", str(out / "rig.json")]) == 2
    _one_error_line(capsys, f"-o/--output: {out / 'rig.json'}: is a directory")
    assert called == [] and _listing(out) == ["rig.json"] and _listing(out / "rig.json") == []


def test_calibrate_table_output_directory_refused(table_paths, tmp_path, capsys):
    out = tmp_path / "calib.json"
    out.mkdir()
    assert main(["calibrate", str(table_paths[0]), "-o", str(out)]) == 2
    _one_error_line(capsys, f"-o/--output: {out}: is a directory")
    assert _listing(tmp_path) == ["calib.json"] and _listing(out) == []


# -- 4. calibrate-board: options and poses checked first ---------------------------------------

def _poses(tmp_path: Path, n: int = 3) -> list[Path]:
    ps = PatternSet(x=((1, 3),), y=((1, 3),))
    frames = [np.full((6, 8), 100, np.uint8)] * ps.n_frames
    return [_capture(tmp_path / f"pose{k}", frames=frames, pattern_set=ps.to_dict())
            for k in range(n)]


_BOARD = ["--board", "circles", "--rows", "11", "--cols", "8", "--spacing", "2.5"]


@pytest.mark.parametrize(("extra", "words"), [
    (["--marker", "nan"], ["--marker: expected a positive length in mm, got nan"]),
    (["--marker", "-1"], ["--marker: expected a positive length in mm, got -1.0"]),
    (["--spacing", "inf"], ["--spacing: expected a positive length in mm, got inf"]),
    (["--window", "nan"], ["--window: expected a positive number of pixels, got nan"]),
    (["--camera-distortion", "k9"], ["--camera-distortion: expected one of", "got 'k9'"]),
    (["--projector-lens", "p1"], ["--projector-lens: p1 and p2 are fitted together",
                                  "got 'p1'"]),
    (["--world", "cam7"], ["--world: expected 'board' or a camera name (cam0)", "got 'cam7'"]),
])
def test_calibrate_board_bad_option_first_and_alone(extra, words, tmp_path, capsys):
    """Refused before any pose is decoded: one line, no warning lines before it."""
    poses = _poses(tmp_path)
    out = tmp_path / "rig.json"
    assert main(["calibrate-board", *map(str, poses), *_BOARD, *extra, "-o", str(out)]) == 2
    _one_error_line(capsys, "nail2nail calibrate-board: error: ", *words)
    assert not out.exists()


def test_calibrate_board_same_pose_three_times(tmp_path, capsys):
    (pose,) = _poses(tmp_path, 1)
    out = tmp_path / "rig.json"
    assert main(["calibrate-board", str(pose), str(pose), str(pose), *_BOARD,
                 "-o", str(out)]) == 2
    _one_error_line(capsys, f"POSE_DIR: {pose} given more than once")
    other = tmp_path / "link"
    other.symlink_to(pose)
    assert main(["calibrate-board", str(pose), str(other), str(tmp_path / "pose0" / "."),
                 *_BOARD, "-o", str(out)]) == 2
    _one_error_line(capsys, f"POSE_DIR: {other} given more than once (as {pose} and {other})")
    assert not out.exists()


def test_calibrate_board_frame_sizes_checked_before_decoding(tmp_path, capsys):
    poses = _poses(tmp_path)
    ps = PatternSet(x=((1, 3),), y=((1, 3),)).to_dict()
    big = _capture(tmp_path / "big", frames=[np.full((10, 12), 100, np.uint8)] * 6,
                   size=(12, 10), pattern_set=ps)
    out = tmp_path / "rig.json"
    assert main(["calibrate-board", *map(str, poses), str(big), *_BOARD, "-o", str(out)]) == 2
    _one_error_line(capsys, f"{big}: camera cam0 has 12x10 images, 8x6 in an earlier pose")
    assert not out.exists()


def test_calibrate_board_output_directory_refused_first(tmp_path, capsys):
    out = tmp_path / "rig.json"
    out.mkdir()
    assert main(["calibrate-board", str(tmp_path / "nowhere"), *_BOARD, "-o", str(out)]) == 2
    _one_error_line(capsys, f"-o/--output: {out}: is a directory")


# -- 5. errors name the user's path, never the hidden temporary file ---------------------------

def test_output_directory_named_as_given(slstudio_text, tmp_path, capsys):
    (tmp_path / "calibration.yml").write_text(slstudio_text)
    for name in ("x.json", "x.yml"):
        (tmp_path / name).mkdir()
    assert main(["import-calibration", str(tmp_path / "calibration.yml"), "-o",
                 str(tmp_path / "x.json")]) == 2
    line = _one_error_line(capsys, f"{tmp_path / 'x.json'}: is a directory")
    assert ".tmp" not in line
    save_calibration(tmp_path / "rig.json",
                     RigCalibration.from_dict(ideal_calibration(default_rig(
                         0.25, projector_distortion="none"))))
    assert main(["export-calibration", str(tmp_path / "rig.json"), "-o",
                 str(tmp_path / "x.yml")]) == 2
    line = _one_error_line(capsys, f"{tmp_path / 'x.yml'}: is a directory")
    assert ".tmp" not in line
    assert main(["export-calibration", str(tmp_path / "rig.json"), "-o",
                 str(tmp_path / "rig.json" / "a.yml")]) == 2
    _one_error_line(capsys, f"{tmp_path / 'rig.json' / 'a.yml'}: cannot write "
                            f"({tmp_path / 'rig.json'} is not a directory)")
    assert _listing(tmp_path) == ["calibration.yml", "rig.json", "x.json", "x.yml"]
    assert _listing(tmp_path / "x.yml") == [] and _listing(tmp_path / "x.json") == []


def test_write_failure_named_by_the_users_path(slstudio_text, tmp_path, monkeypatch, capsys):
    """A failed write (disk full) named the hidden temporary file, e.g. .x.yml.pev2m27d.tmp."""
    import nail2nail.calibration.opencv_files as of
    import nail2nail.cli._import_calibration as ic

    def full(path, *args, **kwargs):
        hidden = Path(path).parent / f".{Path(path).name}.pev2m27d.tmp"
        raise OSError(28, "No space left on device", str(hidden))

    (tmp_path / "calibration.yml").write_text(slstudio_text)
    monkeypatch.setattr(ic, "save_calibration", full)
    assert main(["import-calibration", str(tmp_path / "calibration.yml"), "-o",
                 str(tmp_path / "x.json")]) == 2
    line = _one_error_line(capsys, f"--out: {tmp_path / 'x.json'}: cannot write (No space left")
    assert ".tmp" not in line

    @contextlib.contextmanager
    def full_atomic(path):
        full(path)
        yield Path(path)

    monkeypatch.setattr(of, "atomic_path", full_atomic)
    save_calibration(tmp_path / "rig.json",
                     RigCalibration.from_dict(ideal_calibration(default_rig(
                         0.25, projector_distortion="none"))))
    assert main(["export-calibration", str(tmp_path / "rig.json"), "-o",
                 str(tmp_path / "x.yml")]) == 2
    line = _one_error_line(capsys, f"{tmp_path / 'x.yml'}: cannot write (No space left")
    assert ".tmp" not in line
    assert _listing(tmp_path) == ["calibration.yml", "rig.json"]
