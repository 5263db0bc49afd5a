"""Issue 12: the decoder's thresholds and user masks on the CLI, and 10/12/16-bit captures end
to end (simulate → ``nail2nail process``) against the virtual scanner's truth."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from PIL import Image

from nail2nail.calibration.files import RigCalibration, save_calibration
from nail2nail.cli import main
from nail2nail.io.capture import read_capture, read_truth
from nail2nail.io.scans import load_scans
from nail2nail.scan.capture import scan_capture
from nail2nail.simulation.capture import simulate, write_capture
from nail2nail.simulation.rig import default_rig, ideal_calibration
from nail2nail.simulation.scenes import make_scene

SCALE = 0.3
BITS = (8, 10, 12, 16)


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """The same finger at 8, 10, 12 and 16 bits (geometry rendered once), and its ideal
    calibration."""
    root = tmp_path_factory.mktemp("bits")
    rig = default_rig(SCALE, projector_distortion="none")
    scene = make_scene("finger", rig=rig, seed=2)
    geometry = None
    for bits in BITS:
        deep = dataclasses.replace(rig, photometry=dataclasses.replace(rig.photometry,
                                                                       bit_depth=bits))
        sim = simulate(scene, rig=deep, seed=2, geometry=geometry)
        geometry = sim.geometry
        write_capture(root / f"finger{bits}", sim, seed=2)
    calib = root / "rig.json"
    save_calibration(calib, RigCalibration.from_dict(ideal_calibration(rig)))
    return root


def _surface_error_um(scan, truth) -> np.ndarray:
    ok = scan.mask & truth["mask"]
    return 1000 * np.sum((scan.xyz[ok] - truth["xyz"][ok]) * truth["normal"][ok], axis=-1)


@pytest.mark.parametrize("bits", BITS)
def test_deep_frames_process_end_to_end(captures, tmp_path, bits, capsys):
    """A 10/12/16-bit capture (16-bit PNGs, values left-aligned: docs/capture-format.md) runs
    the whole job; its scans are as close to the true surface as the 8-bit one's."""
    capture = captures / f"finger{bits}"
    frame = np.asarray(Image.open(capture / "cam0" / "000.png"))
    assert frame.dtype == (np.uint8 if bits == 8 else np.uint16)
    if 8 < bits < 16:  # left-aligned: the low bits are zero
        assert not np.any(frame.astype(np.int64) % 2 ** (16 - bits))
    if bits > 8:  # the extra bits are used: values an 8-bit frame cannot hold
        assert np.any((frame >> (16 - bits)) % 2 ** (bits - 8))
    out = tmp_path / "out"
    assert main(["process", str(capture), "--calib", str(captures / "rig.json"), "--out",
                 str(out), "--no-unroll", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["merge"]  # the merge ran on every pair
    for scan in load_scans(out / "scans"):
        err = _surface_error_um(scan, read_truth(capture, scan.name))
        # Measured at scale 0.3, ideal calibration: 1.50-1.92 µm RMS at 8 bits, 1.41-1.84 µm
        # at 10-16 bits (shot and read noise dominate quantisation beyond 10 bits).
        assert err.size > 0.5 * read_truth(capture, scan.name)["mask"].sum()
        assert np.sqrt(np.mean(err**2)) < (2.5 if bits == 8 else 2.0), (bits, scan.name)


def test_thresholds_reach_the_decoder(captures, tmp_path):
    """Each CLI threshold gives the library's result with the same option."""
    capture = captures / "finger12"
    calib = RigCalibration.from_dict(json.loads((captures / "rig.json").read_text()))
    options = {"min_modulation": 0.05, "cue_modulation": 0.04, "min_albedo": 0.05,
               "saturation": 0.9,
               "unwrap_tolerance": 2 * math.pi * 0.2, "erode": 2}
    want = scan_capture(read_capture(capture, load=False), calib, **options)
    out = tmp_path / "scan"
    assert main(["scan", str(capture), "--calib", str(captures / "rig.json"), "--out", str(out),
                 "--no-mat5", "--no-ply", "--min-modulation", "0.05", "--cue-modulation",
                 "0.04", "--min-albedo", "0.05",
                 "--saturation", "0.9", "--unwrap-tolerance", "0.2", "--erode", "2",
                 "--json"]) == 0
    got = load_scans(out)
    default = scan_capture(read_capture(capture, load=False), calib)
    for g, w, d in zip(got, want, default, strict=True):
        np.testing.assert_array_equal(g.mask, w.mask)
        assert g.mask.sum() < d.mask.sum()  # stricter thresholds keep fewer pixels


def test_erode_zero_keeps_more(captures):
    calib = RigCalibration.from_dict(json.loads((captures / "rig.json").read_text()))
    capture = read_capture(captures / "finger8", load=False)
    loose = scan_capture(capture, calib, erode=0)
    strict = scan_capture(capture, calib, erode=1)
    for a, b in zip(loose, strict, strict=True):
        assert a.mask.sum() > b.mask.sum()
        assert not np.any(b.mask & ~a.mask)


def test_user_mask_drops_pixels_of_one_camera(captures, tmp_path, capsys):
    capture = captures / "finger8"
    calib = str(captures / "rig.json")
    shape = read_truth(capture, "cam1")["mask"].shape
    mask = np.zeros(shape, np.uint8)
    mask[:, : shape[1] // 2] = 255  # keep the left half of cam1
    Image.fromarray(mask).save(tmp_path / "mask.png")
    base, masked = tmp_path / "base", tmp_path / "masked"
    assert main(["scan", capture.as_posix(), "--calib", calib, "--out", str(base),
                 "--no-mat5", "--no-ply"]) == 0
    assert main(["scan", capture.as_posix(), "--calib", calib, "--out", str(masked),
                 "--no-mat5", "--no-ply", "--mask", f"cam1={tmp_path / 'mask.png'}"]) == 0
    capsys.readouterr()
    for a, b in zip(load_scans(base), load_scans(masked), strict=True):
        if b.name != "cam1":
            np.testing.assert_array_equal(a.mask, b.mask)
            continue
        np.testing.assert_array_equal(b.mask, a.mask & (mask > 0))
        assert np.all(np.isnan(b.xyz[~b.mask]))
        assert b.mask.sum() > 0 and b.mask.sum() < a.mask.sum()


@pytest.mark.parametrize(("args", "message"), [
    (["--mask", "cam7=m.png"], "unknown camera"),
    (["--mask", "cam0"], "expected CAMERA=IMAGE"),
    (["--mask", "cam0=missing.png"], "no such file"),
    (["--mask", "cam0=small.png"], "the mask is 4 x 3 px"),
    (["--unwrap-tolerance", "0.7"], "--unwrap-tolerance"),
    (["--saturation", "1.5"], "--saturation"),
    (["--min-albedo", "nan"], "--min-albedo"),
    (["--erode", "-1"], "--erode"),
    (["--cue-modulation", "-0.1"], "--cue-modulation"),
    (["--min-albedo", "0.99"], "0 valid pixels"),
])
def test_bad_options_exit_2_and_write_nothing(captures, tmp_path, monkeypatch, capsys, args,
                                              message):
    monkeypatch.chdir(tmp_path)
    Image.fromarray(np.ones((3, 4), np.uint8)).save(tmp_path / "small.png")
    Image.fromarray(np.ones((3, 4), np.uint8)).save(tmp_path / "m.png")
    out = tmp_path / "out"
    code = main(["scan", str(captures / "finger8"), "--calib", str(captures / "rig.json"),
                 "--out", str(out), *args])
    err = capsys.readouterr().err
    assert code == 2, err
    assert message in err
    assert not out.exists()
