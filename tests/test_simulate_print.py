"""``nail2nail simulate --scene finger --print IMAGE``: a real print on the virtual finger."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from nail2nail.cli import main
from nail2nail.io.capture import read_truth
from nail2nail.io.prints import write_print_image
from nail2nail.simulation.capture import simulate_capture
from nail2nail.simulation.scenes import make_scene


def _print_image(h=301, w=251):
    # concentric rings about an off-centre point: no symmetry hides a flip
    rows, cols = np.mgrid[0:h, 0:w]
    radius = np.hypot(rows - 0.4 * h, cols - 0.3 * w)
    return np.rint(127.5 + 120 * np.cos(2 * np.pi * radius / 24)).astype(np.uint8)


def test_cli_simulate_with_print(tmp_path, capsys):
    image = _print_image()
    write_print_image(tmp_path / "print.png", image, ppi=500)
    out = tmp_path / "cap"
    rc = main(["simulate", "--scene", "finger", "--out", str(out), "--scale", "0.125",
               "--print", str(tmp_path / "print.png"), "--json"])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["print"]["ppi"] == pytest.approx(500)
    with Image.open(out / "truth" / "rolled_print.png") as im:
        truth = np.asarray(im)
        assert im.info["dpi"][0] == pytest.approx(500, abs=0.05)
    np.testing.assert_array_equal(truth, image)
    meta = json.loads((out / "truth" / "fingerprint.json").read_text())
    assert meta["pattern"] == "image" and meta["shape"] == [301, 251]
    assert meta["convention"].startswith("legacy") and meta["col_direction"] == "-u"
    # the image centre is on the pad centre
    scene = make_scene("finger")
    assert meta["u_of_col0_mm"] == pytest.approx(meta["pitch_mm"] * 125)
    assert meta["v_of_row0_mm"] == pytest.approx(scene.pad_center[1] + meta["pitch_mm"] * 150)
    # camera truth: the skin coordinates of what cam1 sees map to pixels of the image, and the
    # albedo there follows the image (dark ridges: brighter albedo, flat skin off the image)
    truth_cam = read_truth(out, "cam1")
    seen = truth_cam["surface"]
    u, v = truth_cam["param_u"][seen].astype(float), truth_cam["param_v"][seen].astype(float)
    col = (meta["u_of_col0_mm"] - u) / meta["pitch_mm"]
    row = (meta["v_of_row0_mm"] - v) / meta["pitch_mm"]
    inside = (col > 2) & (col < 248) & (row > 2) & (row < 298)
    outside = (col < -10) | (col > 260) | (row < -10) | (row > 310)
    assert inside.sum() > 200 and outside.sum() > 200
    albedo = truth_cam["albedo"][seen]
    skin = 0.7
    np.testing.assert_allclose(albedo[outside], skin, atol=1e-6)
    value = image[np.rint(row[inside]).astype(int), np.rint(col[inside]).astype(int)]
    dark, light = value < 40, value > 215
    assert albedo[inside][dark].mean() > skin + 0.05 > skin - 0.05 > albedo[inside][light].mean()


def test_simulate_capture_print_keyword_and_errors(tmp_path):
    with pytest.raises(ValueError, match="print_image"):
        simulate_capture(tmp_path / "x", "sphere", scale=0.125, print_image=_print_image())
    assert main(["simulate", "--scene", "coin", "--out", str(tmp_path / "c"), "--print",
                 str(tmp_path / "none.png")]) == 2
    (tmp_path / "bad.png").write_text("nope")
    assert main(["simulate", "--out", str(tmp_path / "b"), "--print",
                 str(tmp_path / "bad.png")]) == 2
    assert not (tmp_path / "b").exists()


def test_print_ppi_scales_the_print(tmp_path):
    image = _print_image(61, 41)
    scene = make_scene("finger", print_image=image, print_ppi=1000)
    fp = scene.fingerprint
    assert fp.pitch == pytest.approx(25.4 / 1000)
    u0, v0 = scene.uv_from_legacy_pixel(0, 0)
    assert u0 == pytest.approx(20 * 25.4 / 1000) and v0 == pytest.approx(4 + 30 * 25.4 / 1000)
    rolled, mask = scene.rolled_print()
    np.testing.assert_array_equal(rolled, image)
    assert mask.all()
