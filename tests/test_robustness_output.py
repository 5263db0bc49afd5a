"""Issue 10: every output directory is the old result, the new result, or visibly incomplete.

A failure mid-way (a corrupt frame, a writer that raises, a bad option) leaves nothing new and
the old result intact; a re-run replaces a directory wholly; Ctrl-C (SIGINT) and SIGKILL in
the middle of writing a capture leave the old capture readable, and the next command works on
it or refuses what is incomplete with a clear error.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
import time
from types import SimpleNamespace

import numpy as np
import pytest
from _robustness import _one_error_line
from _synthetic import synthetic_scans

from nail2nail.cli import main
from nail2nail.io._atomic import atomic_directory, atomic_files
from nail2nail.io.capture import read_capture
from nail2nail.io.scans import save_scans
from nail2nail.scan.patterns import PatternSet
from nail2nail.simulation.capture import simulate_capture
from nail2nail.simulation.rig import default_rig

SCALE = 0.25
TINY = PatternSet(y=[(1, 3)], panel_size=(32, 8))
SMALL = PatternSet(y=[(1, 3)])


def _snapshot(directory):
    """Every file under `directory` (hidden ones too) with the digest of its bytes."""
    return {str(p.relative_to(directory)): hashlib.sha1(p.read_bytes()).hexdigest()
            for p in sorted(directory.rglob("*")) if p.is_file()}


def _leftovers(parent):
    return sorted(p.name for p in parent.iterdir() if ".tmp-" in p.name or ".old-" in p.name)


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """A complete capture of a sphere (default patterns, truth with its ideal calibration)."""
    out = tmp_path_factory.mktemp("old") / "cap"
    simulate_capture(out, "sphere", rig=default_rig(SCALE, projector_distortion="none"), seed=1)
    return out


@pytest.fixture(scope="module")
def scan_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("scans") / "scans"
    save_scans(out, synthetic_scans(size=(48, 60)), mat5=False, ply=False)
    return out


# -- the helper ------------------------------------------------------------------------------
def test_atomic_directory_replaces_wholly_and_keeps_old_on_failure(tmp_path):
    out = tmp_path / "out"
    with atomic_directory(out, marker="m.json") as tmp:
        (tmp / "m.json").write_text("1")
        (tmp / "a.txt").write_text("old")
    old = _snapshot(out)
    with pytest.raises(RuntimeError), atomic_directory(out, marker="m.json") as tmp:
        (tmp / "m.json").write_text("2")
        raise RuntimeError("writer failed")
    assert _snapshot(out) == old and _leftovers(tmp_path) == []
    with pytest.raises(KeyboardInterrupt), atomic_directory(out, marker="m.json") as tmp:
        (tmp / "b.txt").write_text("half")
        raise KeyboardInterrupt
    assert _snapshot(out) == old and _leftovers(tmp_path) == []
    with atomic_directory(out, marker="m.json") as tmp:
        (tmp / "m.json").write_text("3")
    assert _snapshot(out).keys() == {"m.json"}  # a.txt of the old result is gone
    assert _leftovers(tmp_path) == []


def test_atomic_directory_refuses_what_is_not_an_earlier_result(tmp_path):
    (tmp_path / "mine.txt").write_text("user data")
    with pytest.raises(ValueError, match=r"holds no capture\.json"), \
            atomic_directory(tmp_path, marker="capture.json"):
        pass
    assert (tmp_path / "mine.txt").read_text() == "user data"
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="not a directory"), atomic_directory(tmp_path / "file"):
        pass


def test_atomic_files_all_or_none(tmp_path):
    (tmp_path / "rig.json").write_text("old")
    with pytest.raises(OSError), atomic_files(tmp_path, ["t.tsv", "rig.json"]) as tmp:
        (tmp / "t.tsv").write_text("new")
        raise OSError("disk full")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rig.json"]
    assert (tmp_path / "rig.json").read_text() == "old"


# -- simulate --------------------------------------------------------------------------------
def test_simulate_failure_mid_write_keeps_old_capture(tmp_path, monkeypatch, capsys):
    import nail2nail.simulation.capture as sc

    out = tmp_path / "cap"
    simulate_capture(out, "sphere", rig=default_rig(0.125), pattern_set=SMALL, write_truth=False)
    old = _snapshot(out)
    calls = []

    def failing(path, frame):
        calls.append(path)
        if len(calls) == 4:
            raise OSError(f"{path}: No space left on device")
        real(path, frame)

    real = sc.write_frame
    monkeypatch.setattr(sc, "write_frame", failing)
    assert main(["simulate", "--scene", "plane", "--scale", "0.125", "--out", str(out)]) == 2
    _one_error_line(capsys, "No space left on device")
    assert _snapshot(out) == old and _leftovers(tmp_path) == []


def test_simulate_refuses_a_directory_of_other_files(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("mine")
    assert main(["simulate", "--scene", "sphere", "--scale", "0.125", "--out",
                 str(tmp_path)]) == 2
    _one_error_line(capsys, str(tmp_path), "capture.json", "not replaced")
    assert [p.name for p in tmp_path.iterdir()] == ["notes.txt"]


# -- scan ------------------------------------------------------------------------------------
def test_scan_corrupt_frame_keeps_old_scans_rerun_replaces(capture, tmp_path, capsys):
    calib = capture / "truth" / "calibration.json"
    out = tmp_path / "scans"
    assert main(["scan", str(capture), "--calib", str(calib), "--out", str(out), "--no-mat5",
                 "--no-ply", "--json"]) == 0
    (out / "stray.txt").write_text("from an earlier version")
    old = _snapshot(out)
    broken = tmp_path / "broken"
    shutil.copytree(capture, broken)
    frame = broken / "cam1" / "012.png"
    frame.write_bytes(frame.read_bytes()[:200])  # truncated, in the middle of the capture
    capsys.readouterr()
    assert main(["scan", str(broken), "--calib", str(calib), "--out", str(out), "--json"]) == 2
    _one_error_line(capsys, "012.png")
    assert _snapshot(out) == old and _leftovers(tmp_path) == []
    assert main(["scan", str(capture), "--calib", str(calib), "--out", str(out), "--no-mat5",
                 "--no-ply", "--json"]) == 0
    assert not (out / "stray.txt").exists()  # replaced wholly
    assert _leftovers(tmp_path) == []


# -- merge -----------------------------------------------------------------------------------
def test_merge_writer_failure_keeps_old_merge(scan_dir, tmp_path, monkeypatch, capsys):
    import nail2nail.merge.report as mr

    out = tmp_path / "merged"
    args = ["merge", str(scan_dir), "--out", str(out), "--no-figures", "--stride", "4", "--json"]
    assert main(args) == 0
    old = _snapshot(out)

    def failing(*a, **k):
        raise OSError("super.ply: disk full")

    monkeypatch.setattr(mr, "write_super_ply", failing)
    capsys.readouterr()
    assert main(args) == 2
    _one_error_line(capsys, "disk full")
    assert _snapshot(out) == old and _leftovers(tmp_path) == []
    monkeypatch.undo()
    assert main([*args[:-1], "--no-super"]) == 0
    assert not (out / "super.ply").exists()  # the old super scan went with the old result
    assert str(tmp_path / "merged") in (out / "merge.json").read_text()
    assert ".tmp-" not in (out / "merge.json").read_text()


@pytest.mark.parametrize("extra", [["--stride", "0"], ["--max-residual", "0"],
                                   ["--border", "-1"]])
def test_merge_bad_option_writes_nothing(scan_dir, tmp_path, capsys, extra):
    assert main(["merge", str(scan_dir), "--out", str(tmp_path / "m"), *extra]) == 2
    _one_error_line(capsys, extra[0])
    assert list(tmp_path.iterdir()) == []


# -- unroll ----------------------------------------------------------------------------------
def test_unroll_writer_failure_keeps_old_print(scan_dir, tmp_path, monkeypatch, capsys):
    import nail2nail.cli._unroll as unroll_command
    import nail2nail.io.rolled as rolled_io

    out = tmp_path / "print"
    out.mkdir()
    (out / "print.json").write_text("{}")
    (out / "print.png").write_bytes(b"old print")
    old = _snapshot(out)
    fake = SimpleNamespace(ppi=500.0, image=np.zeros((8, 8), np.uint8))
    monkeypatch.setattr(unroll_command, "unroll_scans", lambda *a, **k: fake)
    real = rolled_io.write_print_image

    def failing(path, image, **k):
        if path.name == "print.wsq":
            raise OSError(f"{path}: disk full")
        real(path, image, **k)

    monkeypatch.setattr(rolled_io, "write_print_image", failing)
    assert main(["unroll", str(scan_dir), "--out", str(out)]) == 2
    _one_error_line(capsys, "disk full")
    assert _snapshot(out) == old and _leftovers(tmp_path) == []


def test_unroll_bad_length_checked_before_reading(tmp_path, capsys):
    assert main(["unroll", str(tmp_path / "none"), "--out", str(tmp_path / "p"),
                 "--length", "0"]) == 2
    _one_error_line(capsys, "--length")
    assert list(tmp_path.iterdir()) == []


# -- patterns --------------------------------------------------------------------------------
def test_patterns_bad_grid_spacing_writes_nothing_rerun_replaces(tmp_path, capsys):
    spec = tmp_path / "spec.json"
    spec.write_text(TINY.to_json())
    out = tmp_path / "patterns"
    assert main(["patterns", "--spec", str(spec), "--out", str(out), "--grid"]) == 0
    old = _snapshot(out)
    assert "grid.png" in old
    capsys.readouterr()
    assert main(["patterns", "--spec", str(spec), "--out", str(out), "--grid",
                 "--grid-spacing", "0"]) == 2
    _one_error_line(capsys, "spacing")
    assert _snapshot(out) == old and _leftovers(tmp_path) == []
    assert main(["patterns", "--out", str(tmp_path / "new"), "--grid", "--grid-spacing",
                 "0"]) == 2
    assert not (tmp_path / "new").exists()  # no frame written before refusing (was 24 PNGs)
    assert main(["patterns", "--spec", str(spec), "--out", str(out)]) == 0
    assert "grid.png" not in _snapshot(out)  # the old grid went with the old result


# -- calibrate CAPTURE -----------------------------------------------------------------------
def test_calibrate_capture_failure_writes_neither_tables_nor_calibration(
        capture, tmp_path, monkeypatch, capsys):
    import nail2nail.cli._calibrate_capture as cc

    obs = [SimpleNamespace(name=n, grid=None, xyz_world=np.eye(3) + i,
                           xy_camera=np.ones((3, 2)), xy_projector=np.ones((3, 2)))
           for i, n in enumerate(("cam0", "cam1"))]
    monkeypatch.setattr(cc, "target_observations", lambda *a, **k: obs)
    monkeypatch.setattr(cc, "calibrate_from_observations",
                        lambda *a, **k: (SimpleNamespace(extra={}, projector_distortion=None),
                                         {}))
    monkeypatch.setattr(cc, "check_handedness", lambda *a, **k: None, raising=False)

    def failing(path, calib):
        raise OSError(f"{path}: disk full")

    monkeypatch.setattr(cc, "save_calibration", failing)
    out = tmp_path / "calib"
    out.mkdir()
    (out / "rig.json").write_text("old")
    assert main(["calibrate", str(capture), "-o", str(out / "rig.json")]) == 2
    _one_error_line(capsys, "disk full")
    assert sorted(p.name for p in out.iterdir()) == ["rig.json"]
    assert (out / "rig.json").read_text() == "old"


# -- demo ------------------------------------------------------------------------------------
def test_demo_failure_leaves_it_visibly_incomplete(tmp_path, monkeypatch, capsys):
    import nail2nail.simulation.capture as sc
    from nail2nail.pipeline import run_demo

    out = tmp_path / "demo"
    plane = out / "captures" / "plane"
    simulate_capture(plane, "plane", rig=default_rig(0.125), pattern_set=SMALL,
                     write_truth=False)
    (out / "summary.json").write_text("{}")
    old = _snapshot(plane)

    def failing(path, frame):
        raise OSError(f"{path}: disk full")

    monkeypatch.setattr(sc, "write_frame", failing)
    with pytest.raises(OSError, match="disk full"):
        run_demo(out, scale=0.125, progress=False)
    assert not (out / "summary.json").exists()  # incomplete, and visibly so
    assert _snapshot(plane) == old and _leftovers(plane.parent) == []
    with pytest.raises(ValueError, match="scale"):
        run_demo(tmp_path / "demo2", scale=-1, progress=False)
    assert not (tmp_path / "demo2").exists()


# -- interrupts: the real CLI in a subprocess ------------------------------------------------
# The child is the CLI's main with its frame writer slowed down (20 ms a frame), so that the
# signal surely arrives while the capture's frames are being written.
_CHILD = """
import signal, sys, time
signal.signal(signal.SIGINT, signal.default_int_handler)
import nail2nail.simulation.capture as sc
from nail2nail.cli import main
real = sc.write_frame
def slow(path, frame):
    real(path, frame)
    time.sleep(0.02)
sc.write_frame = slow
sys.exit(main(sys.argv[1:]))
"""


def _interrupted_simulate(out, sig):
    env = {k: v for k, v in os.environ.items() if k != "NAIL2NAIL_DEBUG"}
    proc = subprocess.Popen(
        [sys.executable, "-c", _CHILD, "simulate", "--scene", "sphere", "--scale", str(SCALE),
         "--no-truth", "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline:
            tmps = [p for p in out.parent.glob(f".{out.name}.tmp-*")]
            if tmps and len(list(tmps[0].glob("cam*/*.png"))) >= 5:
                break
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.005)
        else:
            raise AssertionError("the capture's temporary directory never appeared")
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, err


def _scan(capture, calib, out):
    return main(["scan", str(capture), "--calib", str(calib), "--out", str(out), "--no-mat5",
                 "--no-ply", "--json"])


def test_sigint_mid_write_keeps_old_capture(capture, tmp_path, capsys):
    out = tmp_path / "cap"
    shutil.copytree(capture, out)
    old = _snapshot(out)
    rc, err = _interrupted_simulate(out, signal.SIGINT)
    assert rc == 130
    assert err.strip().splitlines() == ["nail2nail simulate: interrupted"]
    assert _snapshot(out) == old
    assert _leftovers(tmp_path) == []  # the temporary directory went with the interrupt
    assert _scan(out, out / "truth" / "calibration.json", tmp_path / "scans") == 0


def test_sigkill_mid_write_keeps_old_capture_and_next_command_refuses_the_rest(
        capture, tmp_path, capsys):
    out = tmp_path / "cap"
    shutil.copytree(capture, out)
    old = _snapshot(out)
    rc, _ = _interrupted_simulate(out, signal.SIGKILL)
    assert rc == -signal.SIGKILL
    assert _snapshot(out) == old  # the old capture, whole
    calib = out / "truth" / "calibration.json"
    assert _scan(out, calib, tmp_path / "scans") == 0
    assert read_capture(out, load=False).camera_names == ["cam0", "cam1", "cam2"]
    (partial,) = [tmp_path / name for name in _leftovers(tmp_path)]  # hidden, incomplete
    capsys.readouterr()
    assert _scan(partial, calib, tmp_path / "scans2") == 2
    _one_error_line(capsys, "capture.json")
    assert not (tmp_path / "scans2").exists()
