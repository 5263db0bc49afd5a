"""CLI: calibrate and crosscheck on the thesis tables (issue 2)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nail2nail.calibration.files import load_calibration
from nail2nail.cli import main


def test_calibrate_json_and_file(tmp_path, table_paths, capsys):
    out = tmp_path / "calib.json"
    assert main(["calibrate", str(table_paths[0]), "-o", str(out), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert len(data["points"]) == 30
    assert set(data["points"][0]) >= {"point", "error_mm"}
    assert len(data["rms_mm"]) == 3 and max(data["rms_mm"]) < 0.06
    calib = load_calibration(out)
    assert np.asarray(calib.cameras[0].camera).shape == (3, 4)
    assert calib.cameras[0].camera[2, 3] == 1.0


def test_calibrate_prints_table(table_paths, capsys):
    assert main(["calibrate", str(table_paths[1])]) == 0
    text = capsys.readouterr().out
    assert "err_Xw" in text and "RMS error" in text


@pytest.mark.parametrize(("use", "median_max"), [("yp", 0.1), ("xpyp", 0.06)])
def test_crosscheck_json(table_paths, capsys, use, median_max):
    assert main(["crosscheck", *map(str, table_paths), "--use", use, "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["pairs"] == 24
    assert data["distance_mm"]["median"] <= median_max
    assert set(data["distance_mm"]) >= {"median", "max", "mean", "values"}
    if use == "yp":
        assert data["squared_mm2"]["max"] < 0.05


def test_bad_table_exits_2_without_output(tmp_path, capsys):
    bad = tmp_path / "bad.tsv"
    bad.write_text("Xw\tYw\n1\t2\n")
    out = tmp_path / "calib.json"
    assert main(["calibrate", str(bad), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "bad.tsv" in err and "missing column" in err
    assert not out.exists()


@pytest.mark.parametrize(
    ("distortion", "message"),
    [
        (["center", "rho"], "needs 'center' and 'rho'"),
        ({"center": [1.0], "rho": 0.1}, r"center must be \[x, y\]"),
        ({"center": [1.0, 2.0], "rho": "x"}, "rho must be a finite number"),
    ],
)
def test_bad_projector_distortion_in_calibration_file(tmp_path, distortion, message):
    from nail2nail.calibration.files import RigCalibration, save_calibration

    good = RigCalibration.from_dict(
        {"format": "nail2nail-calibration", "version": 1,
         "cameras": [{"name": "cam0", "camera": {"model": "dlt", "matrix": np.eye(3, 4).tolist()},
                      "projector": {"model": "dlt", "matrix": np.eye(3, 4).tolist()}}]})
    path = tmp_path / "calib.json"
    save_calibration(path, good)
    data = json.loads(path.read_text())
    data["projector_distortion"] = distortion
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=message) as info:
        load_calibration(path)
    assert "calib.json" in str(info.value)


def test_calibrate_several_projectors_needs_the_joint_model(tmp_path, capsys):
    """A capture of several projectors (projectors.json) is calibrated jointly or not at all;
    a layout file that names no capture, or one outside the directory, is refused; nothing is
    written."""
    src = tmp_path / "target"
    src.mkdir()
    (src / "projectors.json").write_text(json.dumps({"captures": [{"capture": "p0"}]}))
    out = tmp_path / "rig.json"
    assert main(["calibrate", str(src), "-o", str(out)]) == 2
    assert "--model joint" in capsys.readouterr().err
    for captures, message in (([], "one or more distinct"), ([{"capture": "../x"}], "not a "
                              "directory name"), ("p0", "not a projector layout")):
        (src / "projectors.json").write_text(json.dumps({"captures": captures}))
        assert main(["calibrate", str(src), "-o", str(out), "--model", "joint"]) == 2
        assert message in capsys.readouterr().err
    assert not any(tmp_path.glob("rig*"))
