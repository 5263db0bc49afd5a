"""Issue 29: options out of range refused up front (batch, scan/process, simulate, print-target,
distortion, demo) and read-only output directories: exit 2, one line naming the option (or the
file) and the value as given, nothing written."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from _robustness import _calibration, _capture, _one_error_line

from nail2nail.cli import main


def _nothing_written(path: Path) -> None:
    assert not path.exists(), sorted(p.name for p in path.parent.iterdir())


# -- batch ---------------------------------------------------------------------------------
@pytest.fixture
def batch_inputs(tmp_path, monkeypatch):
    """Two tiny captures (camera cam0), their calibration; a cluster must never start."""
    import nail2nail.cli._batch as cli_batch

    def no_cluster(*args, **kwargs):
        raise AssertionError("the cluster started before the options were checked")

    monkeypatch.setattr(cli_batch, "local_client", no_cluster)
    for name in ("a", "b"):
        _capture(tmp_path / "caps" / name)
    return f"{tmp_path / 'caps'}/*", _calibration(tmp_path / "calib.json"), tmp_path / "out"


@pytest.mark.parametrize(("extra", "needles"), [
    (["--workers", "1000"], ["--workers", "1000", "at most"]),
    (["--workers", "0"], ["--workers", "expected at least 1", "got 0"]),
    (["--memory-per-capture", "0"], ["--memory-per-capture", "got 0"]),
    (["--memory-per-capture", "nan"], ["--memory-per-capture", "got nan"]),
    (["--memory-per-capture=-inf"], ["--memory-per-capture", "got -inf"]),
    (["--memory-per-capture", "500", "--workers", "1"], ["--memory-per-capture", "--workers"]),
    (["--workers", "1", "--scheduler", "tcp://127.0.0.1:1"], ["--workers", "--scheduler"]),
    (["--frame", "cam9"], ["--frame", "'cam9'", "cam0"]),
    (["--pairs", "0-5"], ["--pairs 0-5", "1 camera(s)"]),
    (["--pairs="], ["--pairs", "got ''"]),
])
def test_issue29_batch_options_checked_before_the_cluster(batch_inputs, capsys, extra, needles):
    captures, calib, out = batch_inputs
    assert main(["batch", captures, "--calib", str(calib), "--out", str(out), *extra]) == 2
    _one_error_line(capsys, "nail2nail batch: error: ", *needles)
    _nothing_written(out)


def test_issue29_batch_mask_of_a_camera_the_captures_lack(batch_inputs, tmp_path, capsys):
    captures, calib, out = batch_inputs
    mask = tmp_path / "mask.png"
    mask.write_bytes(b"")  # the camera is checked before the file is read
    assert main(["batch", captures, "--calib", str(calib), "--out", str(out),
                 "--mask", f"cam7={mask}"]) == 2
    _one_error_line(capsys, "--mask", "'cam7'", "cam0")
    _nothing_written(out)


def test_issue29_batch_library_checks(tmp_path):
    from nail2nail.batch import check_cameras, default_workers
    from nail2nail.calibration.files import load_calibration

    capture = _capture(tmp_path / "c")
    for bad in (0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="memory_mb"):
            default_workers([capture], memory_mb=bad)
    assert default_workers([capture], memory_mb=1e-300) >= 1  # tiny: no int(inf)
    calib = load_calibration(_calibration(tmp_path / "calib.json"))
    with pytest.raises(ValueError, match=r"frame: 'cam9' .* cam0"):
        check_cameras([capture], calib, frame="cam9")
    check_cameras([capture], calib, frame="cam0", masks={"cam0": "m.png"})


def test_issue29_batch_refuses_a_read_only_out(batch_inputs, capsys):
    captures, calib, out = batch_inputs
    out.mkdir(mode=0o555)
    try:
        assert main(["batch", captures, "--calib", str(calib), "--out", str(out)]) == 2
        _one_error_line(capsys, str(out), "read-only")
        assert list(out.iterdir()) == []
    finally:
        out.chmod(0o755)


# A batch interrupted by Ctrl-C (SIGINT to its process group, as a terminal sends it) while its
# one worker hashes a capture holding a 4 GB sparse file (seconds of reading zeros).
_SPARSE_GB = 4


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.skipif(sys.platform != "linux", reason="process groups and /proc: Linux only")
def test_issue29_batch_ctrl_c_is_one_line_and_stops_the_workers(tmp_path):
    psutil = pytest.importorskip("psutil")
    capture = _capture(tmp_path / "caps" / "big")
    with open(capture / "big.bin", "wb") as f:
        f.truncate(_SPARSE_GB * 2**30)
    calib, out = _calibration(tmp_path / "calib.json"), tmp_path / "out"
    cmd = [sys.executable, "-c", "import sys; from nail2nail.cli import main; "
           "sys.exit(main(sys.argv[1:]))", "batch", f"{tmp_path / 'caps'}/*",
           "--calib", str(calib), "--out", str(out), "--workers", "1"]
    # Ctrl-C as a shell gives it: pytest-xdist's workers ignore SIGINT, and an ignored signal
    # is inherited through exec (Python would then never raise KeyboardInterrupt)
    child = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             start_new_session=True, preexec_fn=_default_sigint)
    try:
        parent, busy, start = psutil.Process(child.pid), False, time.monotonic()
        while not busy and time.monotonic() - start < 60 and child.poll() is None:
            for proc in parent.children(recursive=True):
                try:
                    busy = busy or any(f.path.endswith("big.bin") for f in proc.open_files())
                except psutil.Error:
                    continue
            time.sleep(0.05)
        assert busy, "the worker never started the capture"
        workers = parent.children(recursive=True)
        os.killpg(child.pid, signal.SIGINT)
        stdout, stderr = child.communicate(timeout=60)
    finally:
        if child.poll() is None:
            os.killpg(child.pid, signal.SIGKILL)
            child.communicate()
    assert child.returncode == 130
    assert stderr.decode() == "nail2nail batch: interrupted\n"  # no Dask log, no traceback
    assert stdout == b""
    time.sleep(0.5)
    assert [p.pid for p in workers if p.is_running() and p.status() != psutil.STATUS_ZOMBIE] == []
    import json

    rows = json.loads((out / "batch.json").read_text())
    assert [(r["capture"], r["status"], r["ran"]) for r in rows] == [("big", "failed", False)]
    assert rows[0]["error"].startswith("interrupted")
    assert sorted(p.name for p in out.iterdir()) == [".batch.lock", "batch.csv", "batch.json"]


# -- scan / process ------------------------------------------------------------------------
@pytest.mark.parametrize("command", ["scan", "process"])
@pytest.mark.parametrize(("extra", "needles"), [
    (["--erode", "1000000000"], ["--erode", "0..64", "got 1000000000"]),
    (["--erode", "65"], ["--erode", "got 65"]),
    (["--max-gradient", "-1"], ["--max-gradient", "got -1"]),
    (["--max-gradient", "nan"], ["--max-gradient", "got nan"]),
])
def test_issue29_scan_options_as_given(tmp_path, capsys, command, extra, needles):
    capture, calib = _capture(tmp_path / "c"), _calibration(tmp_path / "calib.json")
    out = tmp_path / "out"
    assert main([command, str(capture), "--calib", str(calib), "--out", str(out), *extra]) == 2
    line = _one_error_line(capsys, *needles)
    assert "-4" not in line and "-8" not in line  # never the value scaled to the camera
    _nothing_written(out)


def test_issue29_scan_capture_checks_before_reading(tmp_path):
    from nail2nail.calibration.files import load_calibration
    from nail2nail.io.capture import read_capture
    from nail2nail.scan.capture import scan_capture

    capture = read_capture(_capture(tmp_path / "c"), load=False)
    calib = load_calibration(_calibration(tmp_path / "calib.json"))
    with pytest.raises(ValueError, match=r"max_gradient: .* got -1\b"):
        scan_capture(capture, calib, max_gradient=-1)
    with pytest.raises(ValueError, match=r"erode: expected an integer in 0\.\.64"):
        scan_capture(capture, calib, erode=10**9)


# -- simulate ------------------------------------------------------------------------------
@pytest.fixture
def print_png(tmp_path):
    from nail2nail.io.prints import write_print_image

    return write_print_image(tmp_path / "print.png", np.full((40, 30), 200, np.uint8), ppi=500)


@pytest.mark.parametrize(("extra", "needles"), [
    (["--print-ppi", "1e12", "--print", "PRINT"], ["--print-ppi", "got 1e+12", "2000"]),
    (["--print-ppi", "inf", "--print", "PRINT"], ["--print-ppi", "got inf"]),
    (["--print-ppi", "50", "--print", "PRINT"], ["--print-ppi", "got 50"]),
    (["--print-ppi", "500"], ["--print-ppi 500", "only with --print"]),
    (["--seed", "-1"], ["--seed", "got -1"]),
    (["--seed", str(2**32)], ["--seed", f"got {2**32}"]),
    (["--conditions", "-1"], ["--conditions", "got -1"]),
    (["--scale", "1000"], ["--scale", "got 1000"]),
    (["--scene", "board", "--marker", "-1"], ["--marker -1", "checkerboard has no markers"]),
    (["--scene", "board", "--board", "charuco", "--marker", "-1"], ["--marker -1", "marker"]),
    (["--scene", "board", "--rows", "3000"], ["--rows", "got 3000"]),
    (["--scene", "board", "--spacing", "1e300"], ["--spacing 1e+300", "A0"]),
    # bench/fuzz_cli.py: the library's check named "pose", not the option
    (["--scene", "board", "--pose", "nan", "0", "0", "0", "0", "0"], ["--pose", "got nan 0"]),
    (["--scene", "board", "--pose", "0", "0", "0", "0", "inf", "0"], ["--pose", "inf"]),
])
def test_issue29_simulate_options(tmp_path, capsys, print_png, extra, needles):
    out = tmp_path / "sim"
    extra = [str(print_png) if a == "PRINT" else a for a in extra]
    assert main(["simulate", "--out", str(out), *extra]) == 2
    _one_error_line(capsys, "nail2nail simulate: error: ", *needles)
    _nothing_written(out)


def test_issue29_simulate_print_file_resolution(tmp_path, capsys):
    from nail2nail.io.prints import write_print_image

    image = write_print_image(tmp_path / "fine.png", np.full((40, 30), 200, np.uint8), ppi=3000)
    out = tmp_path / "sim"
    assert main(["simulate", "--print", str(image), "--out", str(out)]) == 2
    _one_error_line(capsys, "fine.png", "3000 ppi", "--print-ppi")
    _nothing_written(out)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes here")
def test_issue29_simulate_print_fifo_is_named_as_such(tmp_path, capsys):
    """A FIFO given as the print image is refused unopened, named for what it is (it said
    "no such print image file")."""
    fifo = tmp_path / "print.png"
    os.mkfifo(fifo)
    out = tmp_path / "sim"
    assert main(["simulate", "--print", str(fifo), "--out", str(out)]) == 2
    _one_error_line(capsys, "print.png", "a FIFO, a named pipe", "PNG or WSQ")
    _nothing_written(out)


def test_issue29_simulate_truncated_pattern_png(tmp_path, capsys):
    from PIL import Image

    patterns = tmp_path / "patterns"
    patterns.mkdir()
    for i in range(2):
        Image.fromarray(np.full((20, 30), 100 * i, np.uint8)).save(patterns / f"p{i}.png")
    data = (patterns / "p1.png").read_bytes()
    (patterns / "p1.png").write_bytes(data[: len(data) // 2])
    out = tmp_path / "sim"
    assert main(["simulate", "--scene", "plane", "--patterns", str(patterns),
                 "--out", str(out)]) == 2
    _one_error_line(capsys, "p1.png", "cannot read pattern image")
    _nothing_written(out)


# -- print-target --------------------------------------------------------------------------
@pytest.mark.parametrize(("extra", "needles"), [
    (["--rows", "1000000", "--cols", "7"], ["--rows", "got 1000000"]),
    (["--rows", "3001", "--cols", "3000"], ["--rows", "got 3001"]),
    (["--cols", "201"], ["--cols", "got 201"]),
    (["--spacing", "1000"], ["--spacing 1000", "A0"]),
    (["--spacing", "1e300"], ["--spacing 1e+300", "A0"]),
    (["--spacing", "1e-9"], ["--spacing 1e-09", "at least 0.5 mm"]),
    (["--spacing", "nan"], ["--spacing nan"]),
    (["--margin", "1e9"], ["--margin 1e+09", "A0"]),
    (["--marker", "2"], ["--marker 2", "checkerboard has no markers"]),
])
def test_issue29_print_target_bounds(tmp_path, capsys, extra, needles):
    out = tmp_path / "board.svg"
    assert main(["print-target", "board", "-o", str(out), *extra]) == 2
    _one_error_line(capsys, "nail2nail print-target: error: ", *needles)
    _nothing_written(out)


def test_issue29_print_target_largest_board_is_written(tmp_path):
    out = tmp_path / "board.svg"
    assert main(["-q", "print-target", "board", "--rows", "200", "--cols", "200",
                 "--spacing", "4", "-o", str(out)]) == 0
    assert out.stat().st_size < 5e6


# -- distortion ----------------------------------------------------------------------------
def _grid(h=96, w=120):
    y, x = np.mgrid[0:h, 0:w].astype(float)
    return x, y


def _plane_views(noise=0.05):
    """A flat plane's decoded maps: a homography and the thesis's radial distortion."""
    x, y = _grid()
    d = 2e-4 * x + 1e-4 * y + 1
    xp, yp = (9 * x + 0.4 * y + 100) / d, (0.3 * x + 8.5 * y + 80) / d
    cx, cy, rho = 640.0, 1000.0, -0.004
    r2 = ((xp - cx) ** 2 + (yp - cy) ** 2) / 1280.0**2
    rng = np.random.default_rng(0)
    return {"cam0": (cx + (xp - cx) * (1 + rho * r2) + rng.normal(0, noise, x.shape),
                     cy + (yp - cy) * (1 + rho * r2) + rng.normal(0, noise, x.shape), None)}


def _cylinder_views():
    """A cylinder bulging towards the camera (a finger): 100 projector px of parallax."""
    x, y = _grid()
    u = (x - x.shape[1] / 2) / (x.shape[1] / 2 + 1)
    return {"cam0": (100 + 9 * x + 100 * np.sqrt(1 - u**2), 80 + 8.5 * y, None)}


def test_issue29_distortion_plane_check():
    from nail2nail.calibration.distortion import PLANE_RMS_LIMIT_PX, check_plane

    assert check_plane(_plane_views(), "plane")["cam0"] < PLANE_RMS_LIMIT_PX / 2
    with pytest.raises(ValueError, match=r"finger: not a capture of a flat plane: .* 'cam0'"):
        check_plane(_cylinder_views(), "finger")


def test_issue29_distortion_refuses_a_finger_before_the_fit(tmp_path, capsys, monkeypatch):
    import nail2nail.cli._distortion as cli_distortion

    def fit(*args, **kwargs):
        raise AssertionError("the fit ran on a capture that is not a plane")

    views = _cylinder_views()
    monkeypatch.setattr(cli_distortion, "_load", lambda path: (views, {}, {}, None, (1280, 1040)))
    monkeypatch.setattr(cli_distortion, "estimate_from_decoded", fit)
    out = tmp_path / "grids"
    assert main(["distortion", str(tmp_path / "finger"), "--out", str(out)]) == 2
    _one_error_line(capsys, "finger: not a capture of a flat plane", "px RMS")
    _nothing_written(out)


# -- demo ----------------------------------------------------------------------------------
def test_issue29_demo_small_scale_refused(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--scale", "0.25", "--out", str(out)]) == 2
    _one_error_line(capsys, "--scale", "got 0.25", "key mark")
    _nothing_written(out)


@pytest.mark.parametrize("before", ["none", "empty", "earlier"])
def test_issue29_demo_failure_leaves_no_partial_output(tmp_path, capsys, monkeypatch, before):
    import nail2nail.cli._demo as cli_demo

    def failing(out, **kwargs):
        (Path(out) / "captures" / "plane").mkdir(parents=True)
        (Path(out) / "captures" / "plane" / "capture.json").write_text("{}")
        raise OSError(f"{out}/captures/target: disk full")

    monkeypatch.setattr(cli_demo, "run_demo", failing)
    monkeypatch.setattr(cli_demo, "thesis_part", lambda quiet: {})
    out = tmp_path / "demo"
    if before != "none":
        out.mkdir()
    if before == "earlier":
        (out / "summary.json").write_text('{"old": true}')
        (out / "print").mkdir()
    assert main(["-q", "demo", "--scale", "0.5", "--out", str(out), "--json"]) == 2
    _one_error_line(capsys, "disk full")
    if before == "none":
        _nothing_written(out)
    elif before == "empty":
        assert list(out.iterdir()) == []
    else:
        assert sorted(p.name for p in out.iterdir()) == ["print", "summary.json"]
        assert (out / "summary.json").read_text() == '{"old": true}'
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_issue29_demo_refuses_a_directory_not_its_own(tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep")
    assert main(["demo", "--scale", "0.5", "--out", str(out)]) == 2
    _one_error_line(capsys, str(out), "summary.json")
    assert [p.name for p in out.iterdir()] == ["notes.txt"]


# -- read-only output directories ----------------------------------------------------------
def test_issue29_read_only_output_directory_is_refused(tmp_path, capsys):
    from nail2nail.io._atomic import OutputRefusedError, atomic_directory

    out = tmp_path / "capture"
    out.mkdir()
    (out / "capture.json").write_text("{}")  # an earlier result, protected by its owner
    out.chmod(0o555)
    try:
        with pytest.raises(OutputRefusedError, match="read-only"), \
                atomic_directory(out, marker="capture.json"):
            pass
        assert main(["simulate", "--scene", "plane", "--out", str(out)]) == 2
        _one_error_line(capsys, f"{out}: the directory is read-only")
        assert [p.name for p in out.iterdir()] == ["capture.json"]
        assert out.stat().st_mode & 0o777 == 0o555
        assert [p.name for p in tmp_path.iterdir()] == ["capture"]
    finally:
        out.chmod(0o755)
