"""Issue 29: messages that name the file or option, a report whose parts are corrupt, Ctrl-C
while the command line loads.

- ``report``: each section stands on its own. A part that cannot be used (not JSON, truncated,
  a string or NaN where a number belongs) gives a note in the sections that read it and one
  warning line naming the file (and the key); the rest of the page is written, exit 0.
- The frame count against the pattern set, a null pattern set, a calibration of other cameras,
  ``--seed -1``, ``--frame`` and ``--pairs`` checked by the library: exit 2, one line naming
  the file (and the camera) or the option and the value, nothing written.
- Ctrl-C while ``nail2nail.cli`` imports its subcommands: one line, exit 130.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _robustness import _calibration, _capture, _one_error_line
from PIL import Image

from nail2nail.cli import main
from nail2nail.io._json import write_json
from nail2nail.io.capture import read_capture
from nail2nail.io.ply import write_ply
from nail2nail.report import build_report
from nail2nail.scan.patterns import Frequency, PatternSet

# -- report: every section on its own ------------------------------------------------------------


@pytest.fixture
def job(tmp_path) -> Path:
    """A small `process` output directory, written directly: summary, merge (one pair, a super
    scan of 200 points), print (print.json and the print image)."""
    out = tmp_path / "job"
    write_json(out / "process.json", {"seconds": {"scan": 1.0, "total": 2.0},
                                      "peak_rss_mb": 300.0, "options": {"use": "xpyp"}})
    write_json(out / "merge" / "merge.json", {
        "merge": {"0-1": {"parent": "cam0", "child": "cam1", "pairs": 10,
                          "distance_mm": {"median": 0.01, "mean": 0.011, "p95": 0.02,
                                          "max": 0.03}}},
        "super_scan": {"vertices": 200, "faces": 0, "cameras": {}}})
    rng = np.random.default_rng(0)
    write_ply(out / "merge" / "super.ply", rng.normal(size=(200, 3)) * [8, 10, 2])
    write_json(out / "print" / "print.json", {
        "method": "rolled", "ppi": 500.0, "shape": [60, 50], "print_size_mm": [2.5, 3.0],
        "quality": {"clarity_median": 0.9, "clarity_p10": 0.8, "blocks": 4},
        "files": {"print": "print.png"}})
    Image.fromarray(rng.integers(0, 256, (60, 50), np.uint8)).save(out / "print" / "print.png")
    return out


def _edit_json(path: Path, edit) -> None:
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))


def _warnings(capsys) -> list[str]:
    return capsys.readouterr().err.strip().splitlines()


def test_report_print_json_with_nan_and_strings(job, capsys):
    """The user's print.json: "Unknown format code 'g' for object of type 'str'" before."""
    _edit_json(job / "print" / "print.json",
               lambda m: (m.update(ppi="abc"), m["quality"].update(clarity_median=float("nan"))))
    assert main(["report", str(job), "--report-points", "100"]) == 0
    lines = _warnings(capsys)
    assert lines == [f"nail2nail report: warning: {job / 'print' / 'print.json'}: ppi: expected "
                     "a number, got 'abc'; the report says so in its section and shows the rest"]
    html = (job / "report.html").read_text()
    assert "ppi: expected a number, got &#x27;abc&#x27;; the section is not drawn." in html
    assert "0-1" in html and "window.nail2nailReport" in html  # merge and viewer drawn
    assert 'id="print"' in html and 'id="overview"' in html


def test_report_nan_alone_is_shown_as_a_dash(job, capsys):
    _edit_json(job / "print" / "print.json",
               lambda m: m["quality"].update(clarity_median=float("nan")))
    assert main(["-q", "report", str(job), "--report-points", "100"]) == 0
    assert _warnings(capsys) == []
    assert "—, 0.800 over 4 blocks" in (job / "report.html").read_text()


def test_report_truncated_super_ply(job, capsys):
    ply = job / "merge" / "super.ply"
    ply.write_bytes(ply.read_bytes()[:600])
    assert main(["report", str(job), "--report-points", "100"]) == 0
    (line,) = _warnings(capsys)
    assert line.startswith(f"nail2nail report: warning: {ply}: truncated element vertex")
    html = (job / "report.html").read_text()
    # the page keeps its script contract without a viewer; the print is drawn
    assert "window.nail2nailReport = {ready: Promise.resolve()" in html
    assert "the section is not drawn" in html and "data:image/png" in html


@pytest.mark.parametrize("text", ["{not json", "[1, 2]", '{"merge": {"0-1": "x"}}',
                                  '{"merge": {"0-1": {"pairs": "many", "distance_mm": {}}}}'])
def test_report_corrupt_merge_json(job, capsys, text):
    (job / "merge" / "merge.json").write_text(text)
    assert main(["report", str(job), "--report-points", "100"]) == 0
    lines = _warnings(capsys)
    assert lines and all(f"{job / 'merge' / 'merge.json'}: " in line for line in lines), lines
    assert len(lines) == 1  # once, though the overview, merge and viewer read it
    html = (job / "report.html").read_text()
    assert "rolled-equivalent print" in html and "Geometry and quality" in html  # drawn


def test_report_corrupt_summary(job, capsys):
    (job / "process.json").write_text('{"seconds": {"scan": "slow"}, "capture": 5}')
    assert main(["report", str(job), "--report-points", "100"]) == 0
    lines = _warnings(capsys)
    assert len(lines) == 2 and all(str(job / "process.json") in line for line in lines)
    assert "capture: expected a path, got 5" in lines[0]
    assert "seconds.scan: expected a number, got 'slow'" in lines[1]
    html = (job / "report.html").read_text()
    assert "super scan vertices" in html and "print px at 500 ppi" in html  # overview drawn


def test_report_build_report_warns(job):
    (job / "print" / "print.json").write_text("")
    with pytest.warns(UserWarning, match="print.json: not valid JSON"):
        html = build_report(job, max_points=100)
    assert "not valid JSON" in html


def test_report_out_under_a_file_writes_nothing(job, capsys):
    (job / "a_file").write_text("x")
    assert main(["report", str(job), "--out", str(job / "a_file" / "r.html")]) == 2
    _one_error_line(capsys, job / "a_file" / "r.html", "is not a directory")
    os.mkfifo(job / "fifo.html")
    assert main(["report", str(job), "--out", str(job / "fifo.html")]) == 2
    _one_error_line(capsys, job / "fifo.html", "not a regular file")
    assert not (job / "report.html").exists()


# -- messages that name the file and the option --------------------------------------------------

_PATTERN = PatternSet(x=(Frequency(1, 3),), y=(Frequency(1, 3),))  # 6 frames


def _patterned_capture(directory: Path, n_frames: int, names=("cam0", "cam1")) -> Path:
    frames = [np.full((6, 8), 100, np.uint8)] * n_frames
    return _capture(directory, frames=frames, names=names, pattern_set=_PATTERN.to_dict())


def test_frame_count_against_the_pattern_set(tmp_path, capsys):
    """"the pattern set has 24 frames, got 23" named neither the capture nor the camera."""
    capture = _patterned_capture(tmp_path / "cap", 5)
    calib = _calibration(tmp_path / "calib.json", names=("cam0", "cam1"))
    for command in (["scan", str(capture), "--calib", str(calib), "--out", str(tmp_path / "o")],
                    ["distortion", str(capture), "--out", str(tmp_path / "o")]):
        assert main(command) == 2
        _one_error_line(capsys, capture / "capture.json", "camera 'cam0'", "lists 5 frames",
                        "projects 6")
    with pytest.raises(ValueError, match="camera 'cam0' lists 5 frames, its pattern_set"):
        read_capture(capture)
    assert not (tmp_path / "o").exists()


def test_null_pattern_set_names_the_file(tmp_path, capsys):
    capture = _capture(tmp_path / "cap", names=("cam0", "cam1"))
    calib = _calibration(tmp_path / "calib.json", names=("cam0", "cam1"))
    assert main(["process", str(capture), "--calib", str(calib), "--out",
                 str(tmp_path / "o")]) == 2
    _one_error_line(capsys, capture / "capture.json", '"pattern_set" is null')
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("command", ["process", "scan"])
def test_calibration_of_other_cameras(command, tmp_path, capsys):
    capture = _patterned_capture(tmp_path / "cap", 6)
    calib = _calibration(tmp_path / "calib.json", names=("left", "right"))
    assert main([command, str(capture), "--calib", str(calib), "--out",
                 str(tmp_path / "o")]) == 2
    _one_error_line(capsys, calib, capture / "capture.json", "['left', 'right']",
                    "['cam0', 'cam1']")
    assert not (tmp_path / "o").exists()


def test_seed_minus_one(tmp_path, capsys):
    assert main(["simulate", "--seed", "-1", "--scale", "0.125", "--out",
                 str(tmp_path / "o")]) == 2
    _one_error_line(capsys, "--seed", "-1")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(("option", "needles"), [
    (["--frame", "cam9"], ["--frame:", "'cam9'"]),
    (["--pairs", "0-0"], ["--pairs:", "'0-0'"]),
    # found by bench/fuzz_cli.py: an empty --pairs ran the whole job with the default pairs
    (["--pairs="], ["--pairs:", "got ''"]),
    (["--pairs", " "], ["--pairs:", "got ' '"]),
    (["--frame=--"], ["--frame: expected a value, got '--'"]),
    (["--mask", "cam9=calib.json"], ["--mask:", "cam9"]),
])
def test_process_options_checked_by_the_library(tmp_path, capsys, option, needles):
    """The library's name of an option (``frame:``) was the message's; and the syntax check of
    --pairs said "among 0..2147483647"."""
    capture = _patterned_capture(tmp_path / "cap", 6)
    calib = _calibration(tmp_path / "calib.json", names=("cam0", "cam1"))
    assert main(["process", str(capture), "--calib", str(calib), "--out", str(tmp_path / "o"),
                 *option]) == 2
    line = _one_error_line(capsys, *needles)
    assert "2147483647" not in line and "frame: expected" not in line.replace("--frame:", "")
    assert not (tmp_path / "o").exists()


def test_output_under_a_file_names_the_output(tmp_path, capsys):
    """A writer's mkdir of the output's directory said "empty.json: file exists"."""
    (tmp_path / "a_file").write_text("x")
    target = tmp_path / "a_file" / "target.svg"
    assert main(["print-target", "board", "-o", str(target)]) == 2
    _one_error_line(capsys, target, "a_file is a file, not a directory")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


# -- Ctrl-C while the command line loads ---------------------------------------------------------

def test_interrupt_while_importing_in_process(monkeypatch, capsys):
    import builtins

    real = builtins.__import__

    def interrupted(name, *args, **kwargs):
        if name == "nail2nail.cli._main":
            raise KeyboardInterrupt
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", interrupted)
    assert main(["report", "x"]) == 130
    assert capsys.readouterr().err == "nail2nail: interrupted\n"


_INTERRUPT_DURING_IMPORT = """
import builtins, os, signal, sys
real = builtins.__import__
def hook(name, *args, **kwargs):
    if name == "numpy" and "numpy" not in sys.modules:  # the heavy imports begin: Ctrl-C
        os.kill(os.getpid(), signal.SIGINT)
    return real(name, *args, **kwargs)
builtins.__import__ = hook
from nail2nail.cli import main  # what the console script does
sys.exit(main())
"""


def test_interrupt_while_importing_a_real_sigint(tmp_path):
    """A real SIGINT while the subcommands import (the console script's path): one line, 130
    (it was a traceback and the signal's exit)."""
    env = {k: v for k, v in os.environ.items() if k != "NAIL2NAIL_DEBUG"}
    # SIGINT as a shell leaves it: pytest-xdist's workers ignore it, and an ignored signal is
    # inherited through exec (Python would then never raise KeyboardInterrupt)
    done = subprocess.run([sys.executable, "-c", _INTERRUPT_DURING_IMPORT, "report", "x"],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path, env=env,
                          preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert done.returncode == 130, done.stderr
    assert done.stderr == "nail2nail: interrupted\n"
    assert done.stdout == "" and list(tmp_path.iterdir()) == []

