"""Capture directories: writing (virtual scanner, CLI) and reading (issue 3)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from nail2nail.calibration.files import load_calibration
from nail2nail.cli import main
from nail2nail.io.capture import read_capture, read_frame, read_truth, write_frame
from nail2nail.scan.patterns import PatternSet, default_pattern_set
from nail2nail.simulation.capture import simulate, simulate_capture
from nail2nail.simulation.rig import Photometry, Rig, default_rig, save_rig

SMALL = PatternSet(y=[(1, 3)])


def test_simulate_capture_round_trip(tmp_path):
    rig = default_rig(0.125)
    manifest = simulate_capture(tmp_path / "cap", "sphere", rig=rig, pattern_set=SMALL, seed=5)
    cap = read_capture(tmp_path / "cap")
    assert cap.camera_names == ["cam0", "cam1", "cam2"]
    assert cap.pattern_set == SMALL
    assert cap.manifest["n_frames"] == 3 == manifest["n_frames"]
    frames = cap.frames["cam1"]
    assert frames.shape == (3, 160, 128) and frames.dtype == np.float32
    assert 0 <= frames.min() and frames.max() <= 1
    # the files hold exactly what simulate renders in memory
    sim = simulate("sphere", rig=rig, pattern_set=SMALL, seed=5)
    np.testing.assert_array_equal(np.rint(frames * 255).astype(np.uint8), sim.frames["cam1"])
    truth = read_truth(tmp_path / "cap", "cam1")
    for key in ("xyz", "xp", "yp", "mask", "normal", "xp_ideal", "yp_ideal", "surface"):
        assert key in truth
    assert truth["xyz"].shape == (160, 128, 3) and truth["mask"].dtype == bool
    np.testing.assert_array_equal(truth["xp"], sim.geometry["cam1"].xp)
    calib = load_calibration(tmp_path / "cap" / cap.manifest["truth"]["calibration"])
    assert len(calib.cameras) == 3
    assert Rig.from_capture(cap).to_dict() == rig.to_dict()


def test_sixteen_bit_frames(tmp_path):
    frame = (np.arange(12, dtype=np.uint16).reshape(3, 4) * 300) << 4
    write_frame(tmp_path / "f.png", frame)
    back = read_frame(tmp_path / "f.png", bit_depth=12)
    np.testing.assert_allclose(back, (frame >> 4) / 4095, atol=1e-7)
    rig = default_rig(0.0625)
    rig.photometry = Photometry(bit_depth=10)
    simulate_capture(tmp_path / "c10", "plane", rig=rig, pattern_set=SMALL, write_truth=False)
    cap = read_capture(tmp_path / "c10")
    assert cap.bit_depth == 10
    with Image.open(tmp_path / "c10" / "cam0" / "000.png") as im:
        assert np.asarray(im).dtype == np.uint16
    assert "truth" not in cap.manifest


def test_read_capture_errors(tmp_path):
    with pytest.raises(ValueError, match="not a capture directory"):
        read_capture(tmp_path)
    (tmp_path / "capture.json").write_text(json.dumps({"format": "x"}))
    with pytest.raises(ValueError, match="not a nail2nail capture"):
        read_capture(tmp_path)
    (tmp_path / "capture.json").write_text(json.dumps(
        {"format": "nail2nail-capture", "version": 1, "n_frames": 1,
         "cameras": [{"name": "cam0", "frames": ["cam0/000.png"]}]}))
    with pytest.raises(ValueError, match="missing"):
        read_capture(tmp_path)
    with pytest.raises(ValueError, match="no ground truth"):
        read_truth(tmp_path, "cam0")
    with pytest.raises(ValueError, match="frame"):
        write_frame(tmp_path / "bad.png", np.zeros((2, 2), np.float32))


def test_cli_simulate_finger(tmp_path, capsys):
    out = tmp_path / "finger"
    rc = main(["simulate", "--scene", "finger", "--out", str(out), "--scale", "0.125",
               "--seed", "2", "--json"])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["n_frames"] == default_pattern_set().n_frames == 24
    cap = read_capture(out, load=False)
    assert cap.pattern_set == default_pattern_set()
    assert len(cap.camera("cam2")["frames"]) == 24
    assert (out / "cam0" / "023.png").is_file()
    # the truth print: nail edge to nail edge (~31 mm with its margins), tip to 25 mm below
    with Image.open(out / "truth" / "rolled_print.png") as im:
        assert im.mode == "L" and 600 < im.size[0] < 640 and 520 < im.size[1] < 545
        truth = np.asarray(im)
    fingerprint = json.loads((out / "truth" / "fingerprint.json").read_text())
    assert fingerprint["ppi"] == pytest.approx(500) and len(fingerprint["minutiae"]) > 50
    assert fingerprint["shape"] == list(truth.shape)
    assert fingerprint["n_minutiae"] == len(fingerprint["minutiae"])
    assert fingerprint["ridge_arc_deg"] == 110 and fingerprint["rolled_length_mm"] == 25
    extent = fingerprint["rolled_extent"]
    assert extent["v_tip_mm"] - extent["v_min_mm"] == pytest.approx(25)
    assert fingerprint["skin_grid"]["shape"][1] > 900  # ridges all over the skin grid
    pitch = fingerprint["pitch_mm"]
    for m in fingerprint["minutiae"]:
        assert 0 <= m["col"] < truth.shape[1] and 0 <= m["row"] < truth.shape[0]
        assert m["col"] == round((fingerprint["u_of_col0_mm"] - m["u"]) / pitch)
        assert m["row"] == round((fingerprint["v_of_row0_mm"] - m["v"]) / pitch)
    assert cap.manifest["scene"]["ridge_arc_deg"] == 110
    assert cap.manifest["rig"]["projector_distortion"]["rho"] == -0.004


def test_cli_simulate_pattern_dir_and_rig(tmp_path, capsys):
    patterns = tmp_path / "patterns"
    patterns.mkdir()
    for k, level in enumerate((0, 128, 255)):
        Image.fromarray(np.full((1040, 1280), level, np.uint8)).save(patterns / f"p{k}.png")
    save_rig(tmp_path / "rig.json", default_rig(0.125))
    rc = main(["simulate", "--scene", "target", "--out", str(tmp_path / "t"), "--rig",
               str(tmp_path / "rig.json"), "--patterns", str(patterns),
               "--projector-distortion", "none", "--no-truth"])
    assert rc == 0
    cap = read_capture(tmp_path / "t")
    assert cap.manifest["patterns"] == {"source": "directory",
                                        "files": ["p0.png", "p1.png", "p2.png"]}
    assert cap.pattern_set is None and cap.manifest["rig"]["projector_distortion"] is None
    means = cap.frames["cam1"].mean(axis=(1, 2))
    assert means[0] < means[1] < means[2]
    assert "wrote" not in capsys.readouterr().err


def test_cli_simulate_errors(tmp_path, capsys):
    rc = main(["simulate", "--scene", "sphere", "--out", str(tmp_path / "x"), "--patterns",
               str(tmp_path / "nope")])
    assert rc == 2
    assert "error" in capsys.readouterr().err
    assert not (tmp_path / "x" / "capture.json").exists()
