"""The report's capture, calibration and projector distortion sections (issue 13)."""

from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pytest

from nail2nail.calibration.files import load_calibration
from nail2nail.io._json import write_json
from nail2nail.io.points import PointsTable, write_points
from nail2nail.io.scans import load_scans
from nail2nail.report import calibration, capture, distortion
from nail2nail.report.inputs import find_inputs
from nail2nail.scan.results import Reason
from nail2nail.scan.triangulation import _panel_of_points


def _cells(body: str) -> list[str]:
    return re.findall(r"<td>([^<]*)</td>", body)


def _rows(body: str, first: str) -> list[list[str]]:
    rows = [re.findall(r"<td>([^<]*)</td>", r) for r in re.findall(r"<tr>(.*?)</tr>", body)]
    return [r for r in rows if r and r[0] == first]


def test_capture_section(processed_finger):
    inputs = find_inputs(processed_finger)
    section = capture.section(inputs)
    assert (section.id, section.title, section.status) == ("capture", "Capture", "ok")
    scans = load_scans(inputs.scans)
    # 6 thumbnails per camera, modulation, validity, coverage
    assert section.body.count("data:image/png") == 6 * len(scans) + 3
    assert "decoder&#x27;s per-pixel reasons" in section.body
    for scan in scans:
        row = next(r for r in _rows(section.body, scan.name) if len(r) == 9)
        assert int(row[3].replace(",", "")) == int(scan.mask.sum())


def test_capture_section_motion(processed_finger, tmp_path):
    """The still finger's motion rows, then a scan.json edited to say a camera saw motion (and
    one with junk in it): the section warns and names the camera, and does not fail."""
    section = capture.section(find_inputs(processed_finger))
    assert "<h3>Motion</h3>" in section.body
    scans = load_scans(find_inputs(processed_finger).scans)
    for scan in scans:
        row = next(r for r in _rows(section.body, scan.name) if len(r) == 6)
        assert row[-1] == "still" and float(row[1]) < 20
    out = tmp_path / "out"
    shutil.copytree(processed_finger, out)
    manifest = json.loads((out / "scans" / "scan.json").read_text())
    cams = manifest["cameras"]
    cams[0]["motion"] = {**cams[0]["motion"], "motion_mm": 0.085, "moving": True}
    cams[1]["motion"] = {"motion_mm": "much", "groups": [{"label": 3, "shift_px": "x"}],
                         "compensation": [1]}
    (out / "scans" / "scan.json").write_text(json.dumps(manifest))
    section = capture.section(find_inputs(out))
    assert section.status == "warn"
    assert f"Camera {cams[0]['name']} saw the finger move by 85 µm" in section.body
    row = next(r for r in _rows(section.body, cams[1]["name"]) if len(r) == 6)
    assert row[1] == "—" and row[-1] == "still"


def test_capture_section_without_capture(processed_finger, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(processed_finger, out)
    summary = json.loads((out / "process.json").read_text())
    summary["capture"] = str(tmp_path / "gone")
    (out / "process.json").write_text(json.dumps(summary))
    section = capture.section(find_inputs(out))
    assert "not there any more" in section.body
    # the reasons travel with the scans: the validity map needs no capture to decode again
    assert "decoder&#x27;s per-pixel reasons" in section.body
    assert section.body.count("data:image/png") == 3  # the maps and coverage still


def test_capture_section_reason_counts_are_the_scans(processed_finger):
    """The table of decoder reasons counts the bits the scans stored (Scan.reason)."""
    inputs = find_inputs(processed_finger)
    body = capture.section(inputs).body
    scans = load_scans(inputs.scans)
    for scan in scans:
        assert scan.reason is not None and scan.reason.shape == scan.shape
        assert not np.any(scan.mask & (scan.reason != 0))  # valid pixels have no reason
    row = _rows(body, "no 3D point")[0]
    assert [int(v.replace(",", "")) for v in row[1:]] == [
        int(np.count_nonzero(s.reason & Reason.NO_POINT)) for s in scans]


def test_capture_section_of_scans_without_reasons(processed_finger, tmp_path):
    """Scan files that do not store the reasons (older ones): the map is derived from the
    stored arrays, and says so."""
    out = tmp_path / "out"
    shutil.copytree(processed_finger, out)
    for path in (out / "scans").glob("*.npz"):
        with np.load(path) as data:
            arrays = {k: data[k] for k in data.files if k != "reason"}
        np.savez(path, **arrays)
    section = capture.section(find_inputs(out))
    assert "derived from the stored arrays" in section.body


def test_sections_missing(tmp_path):
    write_json(tmp_path / "merge.json", {"super_scan": {}})
    inputs = find_inputs(tmp_path)
    for module in (capture, calibration, distortion):
        section = module.section(inputs)
        assert section.status == "missing"
        assert 'class="missing"' in section.body


@pytest.fixture(scope="module")
def calib_dir(processed_finger, tmp_path_factory):
    """A process directory whose calibration has exact points tables beside it."""
    root = tmp_path_factory.mktemp("calib")
    out = root / "out"
    shutil.copytree(processed_finger, out)
    summary = json.loads((out / "process.json").read_text())
    rig = root / "rig.json"
    shutil.copy(summary["calibration"], rig)
    summary["calibration"] = str(rig)
    (out / "process.json").write_text(json.dumps(summary))
    calib = load_calibration(rig)
    xyz = np.random.default_rng(0).uniform(-6, 6, (40, 3))
    for cam in calib.cameras:
        write_points(root / f"rig_points_{cam.name}.tsv", PointsTable.from_arrays(
            xyz, cam.camera.project(xyz),
            _panel_of_points(cam.projector, calib.projector_distortion, xyz)))
    return out


def test_calibration_section_residuals(calib_dir):
    section = calibration.section(find_inputs(calib_dir))
    assert section.status == "ok"
    assert section.body.count("data:image/png") == 1
    rows = [r for r in (_rows(section.body, f"cam{i}") for i in range(3))]
    residual_rows = [r for rs in rows for r in rs if len(r) == 8]
    assert len(residual_rows) == 3
    for row in residual_rows:
        assert row[1] == "40"
        assert all(float(v) < 1e-3 for v in row[2:])


def test_calibration_section_without_points(processed_finger):
    section = calibration.section(find_inputs(processed_finger))
    assert "nail2nail calibrate" in section.body
    assert section.body.count("data:image/png") == 0
    assert len(_cells(section.body)) == 6 * 10  # 3 cameras and their projectors


def test_distortion_section(processed_finger, tmp_path):
    section = distortion.section(find_inputs(processed_finger))
    rho = load_calibration(find_inputs(processed_finger).calibration).projector_distortion.rho
    assert section.status == "ok" and f"{rho:.6f}" in _cells(section.body)
    assert section.body.count("data:image/png") == 1
    # demo layout: projector_distortion.json wins, the thesis estimate beside it
    write_json(tmp_path / "summary.json", {})
    (tmp_path / "distortion").mkdir()
    write_json(tmp_path / "distortion" / "projector_distortion.json",
               {"center_px": [641.0, 990.0], "rho": -0.0031, "center_std_px": [0.1, 0.2],
                "rho_std": 1e-7, "rms_px": 0.05,
                "thesis": {"center_px": [630.0, 980.0], "rho": -0.0025}})
    section = distortion.section(find_inputs(tmp_path))
    cells = _cells(section.body)
    assert "-0.003100" in cells and "-0.002500" in cells and "641.00" in cells
