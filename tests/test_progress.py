"""Progress on stderr (issue 13): bars only on a terminal, none with --quiet, never on stdout."""

from __future__ import annotations

import io
import json
import sys

import pytest

from nail2nail._progress import (
    Stages,
    info,
    is_quiet,
    progress_bar,
    progress_enabled,
    quiet,
)
from nail2nail.cli._main import main


class FakeTerminal(io.StringIO):
    """A stderr that says it is a terminal and keeps what is written to it."""

    def isatty(self) -> bool:
        return True


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """A small simulated capture (scale 0.2) and its ideal calibration."""
    out = tmp_path_factory.mktemp("progress") / "capture"
    with quiet():
        assert main(["simulate", "--scale", "0.2", "--out", str(out), "--json"]) == 0
    return out, out / "truth" / "calibration.json"


@pytest.fixture
def terminal(monkeypatch):
    """Makes sys.stderr a FakeTerminal when called (in the test body: pytest's capture
    replaces sys.stderr again when the test starts)."""
    def install() -> FakeTerminal:
        fake = FakeTerminal()
        monkeypatch.setattr(sys, "stderr", fake)
        return fake
    return install


def _json(stdout: str) -> dict:
    return json.loads(stdout)  # the whole of stdout: nothing else mixed in


def _scan_args(capture, out) -> list[str]:
    path, calib = capture
    return ["scan", str(path), "--calib", str(calib), "--out", str(out), "--no-mat5",
            "--no-ply", "--json"]


def _only_errors_and_warnings(text: str) -> bool:
    return all(": warning: " in line or ": error: " in line for line in text.splitlines())


# -- the helper -----------------------------------------------------------------------------


def test_progress_bar_needs_a_terminal(terminal, capsys):
    terminal = terminal()
    assert progress_enabled()
    assert list(progress_bar(range(3), desc="work", unit="step")) == [0, 1, 2]
    assert "work" in terminal.getvalue() and "3/3" in terminal.getvalue()
    assert capsys.readouterr().out == ""


def test_progress_bar_silent_when_not_asked_or_quiet(terminal):
    terminal = terminal()
    assert list(progress_bar(range(3), desc="work", enabled=False)) == [0, 1, 2]
    with quiet():
        assert is_quiet() and not progress_enabled()
        assert list(progress_bar(range(3), desc="work")) == [0, 1, 2]
        Stages(2)("a stage")
        info("an informational line")
    assert not is_quiet()  # restored after the block
    assert terminal.getvalue() == ""


def test_progress_bar_silent_on_a_file(capsys):
    # pytest's capture is not a terminal
    assert not progress_enabled()
    assert list(progress_bar(range(3), desc="work", unit="step")) == [0, 1, 2]
    Stages(2)("a stage")
    assert capsys.readouterr().err == ""


def test_stages_lines(terminal, capsys):
    terminal = terminal()
    step = Stages(2, prefix="job: ")
    step("first")
    step("second")
    lines = terminal.getvalue().splitlines()
    assert len(lines) == 2
    assert lines[0].startswith("job: [ 1/2]") and lines[0].endswith("first")
    assert lines[1].startswith("job: [ 2/2]") and lines[1].endswith("second")
    Stages(1, terminal_only=False)("logged")  # a log line also on a file, unless quiet
    assert "logged" in terminal.getvalue()


def test_stages_not_terminal_only_on_a_file(capsys):
    Stages(1, terminal_only=False)("logged")
    assert "logged" in capsys.readouterr().err
    with quiet():
        Stages(1, terminal_only=False)("hidden")
        info("hidden too")
    assert capsys.readouterr().err == ""


# -- the command line -----------------------------------------------------------------------


def test_simulate_shows_bars_on_a_terminal(tmp_path, terminal, capsys):
    terminal = terminal()
    assert main(["simulate", "--scale", "0.2", "--out", str(tmp_path / "c"), "--json"]) == 0
    err = terminal.getvalue()
    assert "simulate" in err and "camera" in err and "100%" in err  # rendering per camera
    assert "write" in err and "frame" in err  # writing the frames
    summary = _json(capsys.readouterr().out)
    assert len(summary["cameras"]) == 3


def test_scan_shows_a_bar_on_a_terminal(capture, tmp_path, terminal, capsys):
    terminal = terminal()
    assert main(_scan_args(capture, tmp_path / "scans")) == 0
    assert "scan" in terminal.getvalue() and "3/3" in terminal.getvalue()
    assert set(_json(capsys.readouterr().out)["cameras"]) == {"cam0", "cam1", "cam2"}


@pytest.mark.parametrize("where", ["before", "after"])
def test_scan_quiet_on_a_terminal(capture, tmp_path, terminal, capsys, where):
    terminal = terminal()
    args = _scan_args(capture, tmp_path / "scans")
    args = ["-q", *args] if where == "before" else [*args, "--quiet"]
    assert main(args) == 0
    assert _only_errors_and_warnings(terminal.getvalue())
    assert "%|" not in terminal.getvalue()
    _json(capsys.readouterr().out)


def test_scan_no_bar_when_stderr_is_not_a_terminal(capture, tmp_path, capsys):
    assert main(_scan_args(capture, tmp_path / "scans")) == 0
    out, err = capsys.readouterr()
    assert "%|" not in err and _only_errors_and_warnings(err)
    _json(out)


def test_quiet_keeps_errors(tmp_path, terminal):
    terminal = terminal()
    code = main(["-q", "scan", str(tmp_path / "missing"), "--calib", str(tmp_path / "c.json"),
                 "--out", str(tmp_path / "scans")])
    assert code == 2
    lines = terminal.getvalue().splitlines()
    assert len(lines) == 1 and lines[0].startswith("nail2nail scan: error: ")


def test_merge_shows_a_bar_on_a_terminal(capture, tmp_path, terminal, capsys):
    terminal = terminal()
    with quiet():
        assert main(_scan_args(capture, tmp_path / "scans")) == 0
    capsys.readouterr()
    assert main(["merge", str(tmp_path / "scans"), "--out", str(tmp_path / "merge"),
                 "--no-figures", "--json"]) == 0
    err = terminal.getvalue()
    assert "merge" in err and "step" in err and "100%" in err
    assert "merge" in _json(capsys.readouterr().out)


def test_process_stages_and_bars_on_a_terminal(capture, tmp_path, terminal, capsys):
    terminal = terminal()
    path, calib = capture
    args = ["process", str(path), "--calib", str(calib), "--out", str(tmp_path / "job"),
            "--json"]
    assert main(args) == 0
    err = terminal.getvalue()
    assert "process: " in err and "scan" in err and "merge" in err and "3/3" in err
    _json(capsys.readouterr().out)
    terminal.seek(0)
    terminal.truncate()
    assert main(["--quiet", *args]) == 0
    assert _only_errors_and_warnings(terminal.getvalue())
    _json(capsys.readouterr().out)


def test_unroll_stages_on_a_terminal(capture, tmp_path, terminal, capsys):
    terminal = terminal()
    with quiet():
        assert main(_scan_args(capture, tmp_path / "scans")) == 0
    capsys.readouterr()
    args = ["unroll", str(tmp_path / "scans"), "--out", str(tmp_path / "print"), "--no-wsq",
            "--json"]
    assert main(args) == 0
    err = terminal.getvalue()
    lines = [line for line in err.splitlines() if ": warning: " not in line]
    assert len(lines) == 3, err
    stages = ["read the scans", "unroll (", "write the print"]
    for k, (line, stage) in enumerate(zip(lines, stages, strict=True)):
        assert line.startswith(f"unroll: [ {k + 1}/3]") and stage in line, err
    _json(capsys.readouterr().out)
