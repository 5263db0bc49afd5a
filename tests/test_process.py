"""``nail2nail process``: the whole job for one capture (issue 11), against the separate commands.

A small virtual finger (scale 0.5, the true calibration) written to disk once per module; the
one-process job must give the files and figures of ``scan`` → ``merge`` → ``unroll`` run one
after the other, with the seconds of every stage in ``process.json``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from nail2nail.calibration.files import RigCalibration, save_calibration
from nail2nail.cli import main
from nail2nail.io.capture import read_capture
from nail2nail.io.scans import load_scans
from nail2nail.simulation.capture import simulate_capture
from nail2nail.simulation.rig import default_rig, ideal_calibration

SCALE = 0.5
STAGES = ("scan", "write_scans", "merge", "unroll", "write_print")


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    root = tmp_path_factory.mktemp("process")
    rig = default_rig(SCALE, projector_distortion="none")
    simulate_capture(root / "finger", "finger", rig=rig, seed=2, write_truth=False)
    calib = root / "rig.json"
    save_calibration(calib, RigCalibration.from_dict(ideal_calibration(rig)))
    return root / "finger", calib


@pytest.fixture(scope="module")
def processed(capture, tmp_path_factory):
    finger, calib = capture
    out = tmp_path_factory.mktemp("out") / "job"
    assert main(["process", str(finger), "--calib", str(calib), "--out", str(out)]) == 0
    return out, json.loads((out / "process.json").read_text())


def test_outputs_and_stage_times(processed):
    out, summary = processed
    assert set(summary["seconds"]) == {*STAGES, "total"}
    assert all(v >= 0 for v in summary["seconds"].values())
    assert summary["seconds"]["total"] == pytest.approx(
        sum(summary["seconds"][s] for s in STAGES), abs=0.01)
    assert summary["peak_rss_mb"] is None or summary["peak_rss_mb"] > 50
    parts = summary["scan_seconds"]
    assert set(parts) == {"read_frames", "decode", "motion"}
    assert all(v > 0 for v in parts.values())
    assert summary["motion"]["moving"] is False  # the demo's finger holds still
    assert sum(parts.values()) <= summary["seconds"]["scan"] + 0.002
    merge = summary["merge_seconds"]
    assert set(merge) == {"correspond", "fuse", "write", "figures"}
    assert merge["correspond"] > 0 and merge["fuse"] > 0
    assert sum(merge.values()) <= summary["seconds"]["merge"] + 0.005
    assert (out / "scans" / "scan.json").exists()
    assert (out / "merge" / "merge.json").exists() and (out / "merge" / "super.ply").exists()
    assert (out / "print" / "print.png").exists() and (out / "print" / "print.wsq").exists()
    assert not list(out.glob("merge/*.png")), "figures are off by default"
    assert not list(out.glob("scans/*.ply")), "per-camera PLY only with --ply"
    assert not list(out.glob("**/*.by")), "mat5 only with --mat5"
    # every path the summary names is under OUT, not the temporary directory it was written in
    files = summary["print"]["files"]
    assert all((out / "print" / name).exists() for name in files.values())
    assert str(out) in summary["out"] and ".tmp" not in json.dumps(summary)
    merged = json.loads((out / "merge" / "merge.json").read_text())
    assert ".tmp" not in json.dumps(merged)
    named = [*merged["super_scan"]["files"].values(),
             *(f for m in merged["merge"].values() for f in m["files"].values())]
    assert named and all(Path(f).exists() and Path(f).is_relative_to(out) for f in named)


def test_same_result_as_the_separate_commands(capture, processed, tmp_path, capsys):
    finger, calib = capture
    out, summary = processed
    scan_dir, merge_dir = tmp_path / "scan", tmp_path / "merge"
    assert main(["scan", str(finger), "--calib", str(calib), "--out", str(scan_dir),
                 "--no-mat5", "--no-ply"]) == 0
    assert main(["merge", str(scan_dir), "--out", str(merge_dir), "--no-figures"]) == 0
    capsys.readouterr()
    for a, b in zip(load_scans(scan_dir), load_scans(out / "scans"), strict=True):
        assert a.name == b.name
        np.testing.assert_array_equal(a.mask, b.mask)
        np.testing.assert_array_equal(a.xyz, b.xyz)
    merged = json.loads((merge_dir / "merge.json").read_text())
    for key, stats in summary["merge"].items():
        assert stats["pairs"] == merged["merge"][key]["pairs"]
        assert stats["distance_mm"] == merged["merge"][key]["distance_mm"]
    assert summary["super_scan"]["vertices"] == merged["super_scan"]["vertices"]


def test_json_and_options(capture, tmp_path, capsys):
    finger, calib = capture
    out = tmp_path / "job"
    assert main(["process", str(finger), "--calib", str(calib), "--out", str(out), "--json",
                 "--no-unroll", "--pairs", "0-2", "--mat5"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert (out / "merge" / "superZ.by").exists() and (out / "scans" / "cam0Z.by").exists()
    assert list(summary["merge"]) == ["0-2"]
    assert "print" not in summary and "unroll" not in summary["seconds"]
    assert not (out / "print").exists()


def test_bad_input_writes_nothing(capture, tmp_path, capsys):
    finger, calib = capture
    out = tmp_path / "job"
    assert main(["process", str(tmp_path / "missing"), "--calib", str(calib),
                 "--out", str(out)]) == 2
    assert "missing" in capsys.readouterr().err
    assert not out.exists()
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    assert main(["process", str(finger), "--calib", str(bad), "--out", str(out)]) == 2
    assert "bad.json" in capsys.readouterr().err and not out.exists()
    assert main(["process", str(finger), "--calib", str(calib), "--out", str(out),
                 "--ppi", "20"]) == 2
    assert "--ppi" in capsys.readouterr().err and not out.exists()
    # a directory of the user's, not an earlier result: refused before any work
    other = tmp_path / "mine"
    other.mkdir()
    (other / "notes.txt").write_text("keep")
    assert main(["process", str(finger), "--calib", str(calib), "--out", str(other)]) == 2
    assert "process.json" in capsys.readouterr().err
    assert [p.name for p in other.iterdir()] == ["notes.txt"]


def test_capture_object_api(capture, tmp_path):
    """The library call takes objects as well as paths."""
    from nail2nail.calibration.files import load_calibration
    from nail2nail.process import process_capture

    finger, calib = capture
    summary = process_capture(read_capture(finger, load=False), load_calibration(calib),
                              tmp_path / "job", unroll=False)
    assert summary["super_scan"]["vertices"] > 10_000
    assert set(summary["cameras"]) == {"cam0", "cam1", "cam2"}
