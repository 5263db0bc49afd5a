"""Issue 10: exit codes, one-line messages naming the file, strict JSON (real files, the CLI)."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest
from _robustness import _calibration, _capture, _one_error_line, _scan_dir

from nail2nail.cli import _main, main
from nail2nail.io._json import dumps_json, read_json, write_json
from nail2nail.io._npz import read_npz

# ------------------------------------------------------------------------- exit codes


def test_bad_input_exit_2_one_line(tmp_path, capsys):
    rc = main(["scan", str(tmp_path / "nocapture"), "--calib", str(tmp_path / "none.json"),
               "--out", str(tmp_path / "out")])
    assert rc == 2
    line = _one_error_line(capsys, "none.json", "no such file")
    assert line.startswith("nail2nail scan: error: ")
    assert not (tmp_path / "out").exists()


def test_keyboard_interrupt_exit_130(monkeypatch, tmp_path, capsys):
    def interrupted(args):
        raise KeyboardInterrupt

    parser = _main.build_parser()
    args = parser.parse_args(["merge", str(tmp_path), "--out", str(tmp_path / "o")])
    monkeypatch.setattr(_main, "build_parser", lambda: _FixedParser(args, interrupted))
    assert main(["merge"]) == 130
    assert _one_error_line(capsys) == "nail2nail merge: interrupted"


class _FixedParser:
    def __init__(self, args, func):
        self.args, self.args.func = args, func

    def parse_args(self, argv):
        return self.args


@pytest.mark.parametrize("debug", [None, "1"])
def test_internal_error_exit_1_with_hint(monkeypatch, tmp_path, capsys, debug):
    def broken(args):
        raise ZeroDivisionError("division by zero")

    args = _main.build_parser().parse_args(["merge", str(tmp_path), "--out", str(tmp_path)])
    monkeypatch.setattr(_main, "build_parser", lambda: _FixedParser(args, broken))
    if debug:
        monkeypatch.setenv("NAIL2NAIL_DEBUG", debug)
    else:
        monkeypatch.delenv("NAIL2NAIL_DEBUG", raising=False)
    assert main(["merge"]) == 1
    err = capsys.readouterr().err
    last = err.strip().splitlines()[-1]
    assert "internal error: ZeroDivisionError: division by zero" in last
    assert "report" in last
    assert ("Traceback" in err) == bool(debug)


def test_bare_key_error_in_words(monkeypatch, tmp_path, capsys):
    def missing(args):
        return {}["npz"]

    args = _main.build_parser().parse_args(["merge", str(tmp_path), "--out", str(tmp_path)])
    monkeypatch.setattr(_main, "build_parser", lambda: _FixedParser(args, missing))
    assert main(["merge"]) == 2
    line = _one_error_line(capsys, "lacks the required entry 'npz'")
    assert "KeyError" not in line


# ------------------------------------------------------------------------- npz files


@pytest.mark.parametrize("cut", [0, 10, 200, -30])
def test_truncated_npz_names_file(tmp_path, capsys, cut):
    good = tmp_path / "good.npz"
    np.savez_compressed(good, xyz=np.zeros((20, 20, 3)), mask=np.ones((20, 20), bool))
    data = good.read_bytes()
    scans = _scan_dir(tmp_path / "scans", npz=data[:cut])
    with pytest.raises(ValueError, match=r"cam0.npz"):
        read_npz(scans / "cam0.npz")
    assert main(["merge", str(scans), "--out", str(tmp_path / "m")]) == 2
    _one_error_line(capsys, "cam0.npz", "scan file")
    assert not (tmp_path / "m").exists()


def test_npz_not_an_archive_and_pickles(tmp_path):
    np.save(tmp_path / "a.npy", np.ones(3))
    (tmp_path / "a.npz").write_bytes((tmp_path / "a.npy").read_bytes())
    with pytest.raises(ValueError, match=r"a.npz: not a valid"):
        read_npz(tmp_path / "a.npz")
    np.savez(tmp_path / "o.npz", x=np.array([{1: 2}], dtype=object))
    with pytest.raises(ValueError, match=r"o.npz"):
        read_npz(tmp_path / "o.npz")
    with zipfile.ZipFile(tmp_path / "z.npz", "w") as z:
        z.writestr("x.npy", b"\x93NUMPY garbage")
    with pytest.raises(ValueError, match=r"z.npz"):
        read_npz(tmp_path / "z.npz")
    np.savez(tmp_path / "m.npz", x=np.ones(2))
    with pytest.raises(ValueError, match=r"m.npz: scan file lacks array.*mask"):
        read_npz(tmp_path / "m.npz", required=["x", "mask"], what="scan file")


def test_scan_json_missing_npz_entry(tmp_path, capsys):
    scans = _scan_dir(tmp_path / "scans")
    manifest = read_json(scans / "scan.json")
    del manifest["cameras"][0]["npz"]
    write_json(scans / "scan.json", manifest)
    assert main(["merge", str(scans), "--out", str(tmp_path / "m")]) == 2
    _one_error_line(capsys, "scan.json", "cameras[0]", "'npz'")


# ------------------------------------------------------------------------- frames


def test_truncated_png_frame_names_file(tmp_path, capsys):
    cap = _capture(tmp_path / "cap", frames=[np.arange(48, dtype=np.uint8).reshape(6, 8)] * 2)
    frame = cap / "cam0" / "001.png"
    data = frame.read_bytes()
    frame.write_bytes(data[: len(data) // 2])
    calib = _calibration(tmp_path / "calib.json")
    assert main(["scan", str(cap), "--calib", str(calib), "--out", str(tmp_path / "o")]) == 2
    _one_error_line(capsys, "001.png", "cannot read frame")
    assert not (tmp_path / "o").exists()
    frame.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 40)  # corrupt header
    assert main(["scan", str(cap), "--calib", str(calib), "--out", str(tmp_path / "o")]) == 2
    _one_error_line(capsys, "001.png")


# ------------------------------------------------------------------------- JSON


def test_json_never_holds_nan(tmp_path):
    data = {"a": float("nan"), "b": [np.float64("inf"), -np.inf, 1.0], "c": np.array([np.nan])}
    text = dumps_json(data)
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text) == {"a": None, "b": [None, None, 1.0], "c": [None]}
    write_json(tmp_path / "x.json", data)
    back = json.loads((tmp_path / "x.json").read_text(), parse_constant=_refuse)
    assert back["a"] is None
    assert json.loads(dumps_json({"x": object()}, default=lambda o: float("nan"))) == {"x": None}


def _refuse(name):
    raise AssertionError(f"non-standard JSON constant {name}")


def test_cli_json_prints_are_strict(tmp_path, capsys, table_paths):
    # every --json print goes through dumps_json: no bare json.dumps left in the CLI
    from pathlib import Path

    import nail2nail.cli as cli

    for module in Path(cli.__file__).parent.glob("_*.py"):
        assert "json.dumps(" not in module.read_text(), module.name
    assert main(["crosscheck", str(table_paths[0]), str(table_paths[1]), "--json"]) == 0
    json.loads(capsys.readouterr().out, parse_constant=_refuse)
