"""Printable targets (nail2nail print-target) and calibrating from a target capture without a
nominal rig (nail2nail calibrate --mark-diameter-px)."""

import base64
import io
import json
import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from PIL import Image

from nail2nail.calibration.boards import Board, board_sheet, detect_board, target_wrap_sheet
from nail2nail.calibration.markers import TargetGeometry
from nail2nail.cli import main

SVG = "{http://www.w3.org/2000/svg}"


def _svg(path):
    root = ET.parse(path).getroot()
    width, height = root.get("width"), root.get("height")
    assert width.endswith("mm") and height.endswith("mm")
    view = [float(v) for v in root.get("viewBox").split()]
    # one user unit is one millimetre: true size
    assert view[:2] == [0, 0]
    assert view[2] == pytest.approx(float(width[:-2]))
    assert view[3] == pytest.approx(float(height[:-2]))
    text = " ".join(t.text for t in root.iter(f"{SVG}text"))
    return root, text


def test_print_checkerboard_svg_true_size(tmp_path, capsys):
    out = tmp_path / "board.svg"
    assert main(["print-target", "board", "--board", "checkerboard", "--rows", "7", "--cols",
                 "10", "--spacing", "3", "-o", str(out)]) == 0
    assert "print at 100 %" in capsys.readouterr().out
    root, text = _svg(out)
    black = [r for r in root.iter(f"{SVG}rect") if r.get("fill") == "#000000"]
    squares = [r for r in black if float(r.get("width")) == 3.0 == float(r.get("height"))]
    assert len(squares) == 35  # half of 7 x 10, black at (0, 0)
    x0 = min(float(r.get("x")) for r in squares)
    y0 = min(float(r.get("y")) for r in squares)
    corner = [r for r in squares if float(r.get("x")) == x0 and float(r.get("y")) == y0]
    assert len(corner) == 1  # the top-left square is black
    bar = [r for r in black if float(r.get("width")) == 50.0]
    assert len(bar) == 1  # the 50 mm scale bar
    for needed in ("checkerboard", "--rows 7", "--cols 10", "--spacing 3 mm",
                   "overall 36 x 27 mm", "50 mm"):
        assert needed in text


@pytest.mark.parametrize(("kind", "diameter"), [("circles", 1.5), ("asymmetric-circles", 2.0)])
def test_print_circle_grid(tmp_path, kind, diameter):
    out = tmp_path / "c.svg"
    assert main(["print-target", "board", "--board", kind, "--rows", "5", "--cols", "4",
                 "--spacing", "3", "--marker", str(diameter), "-o", str(out)]) == 0
    root, text = _svg(out)
    circles = list(root.iter(f"{SVG}circle"))
    assert len(circles) == 20
    assert all(float(c.get("r")) == diameter / 2 and c.get("fill") == "#000000"
               for c in circles)
    centres = np.array([[float(c.get("cx")), float(c.get("cy"))] for c in circles])
    board = Board(kind, rows=5, cols=4, spacing=3.0, marker=diameter)
    np.testing.assert_allclose(centres - centres[0], board.object_points()[:, :2], atol=1e-3)
    assert f"circle diameter {diameter:g} mm" in text and "dark circles on white" in text


def test_print_charuco_svg_is_detectable(tmp_path):
    out = tmp_path / "ch.svg"
    assert main(["print-target", "board", "--board", "charuco", "--rows", "5", "--cols", "6",
                 "--spacing", "4", "-o", str(out)]) == 0
    root, text = _svg(out)
    image = next(root.iter(f"{SVG}image"))
    assert float(image.get("width")) == 24.0 and float(image.get("height")) == 20.0
    href = image.get("{http://www.w3.org/1999/xlink}href")
    raster = np.asarray(Image.open(io.BytesIO(base64.b64decode(href.split(",", 1)[1]))))
    board = Board("charuco", rows=5, cols=6, spacing=4.0)
    ppm = raster.shape[1] / 24.0
    pad = int(ppm * board.margin_mm)
    small = np.asarray(Image.fromarray(np.pad(raster, pad, constant_values=255)).resize(
        (int((raster.shape[1] + 2 * pad) / 4), int((raster.shape[0] + 2 * pad) / 4)),
        Image.BOX))
    indices, xy = detect_board(small, board)
    assert len(indices) == board.n_points
    expected = (board.object_points()[indices, :2] + board.margin_mm) * ppm / 4 - 0.5
    assert np.abs(xy - expected).max() < 0.2
    assert "DICT_5X5_100" in text and "marker side 2.8 mm" in text


def test_print_cylinder_wrap(tmp_path):
    out = tmp_path / "wrap.svg"
    assert main(["print-target", "cylinder", "-o", str(out), "--json"]) == 0
    root, text = _svg(out)
    g = TargetGeometry()
    wrap = [r for r in root.iter(f"{SVG}rect") if r.get("fill") == "#000000"
            and float(r.get("height")) == pytest.approx(g.y_range[1] - g.y_range[0])]
    assert len(wrap) == 1
    assert float(wrap[0].get("width")) == pytest.approx(2 * np.pi * g.radius, abs=1e-3)
    left, top = float(wrap[0].get("x")), float(wrap[0].get("y"))
    circles = list(root.iter(f"{SVG}circle"))
    white = [c for c in circles if c.get("fill") == "#ffffff"]
    assert len(white) == g.n_rows * g.n_cols  # 59 marks and the key's outer disc
    plain = [c for c in white if float(c.get("r")) == pytest.approx(g.mark_diameter / 2)]
    assert len(plain) == g.n_rows * g.n_cols - 1
    key = [c for c in white if float(c.get("r")) == pytest.approx(g.key_outer_diameter / 2)]
    hole = [c for c in circles if c.get("fill") == "#000000"]
    assert len(key) == 1 and len(hole) == 1
    assert float(hole[0].get("r")) == pytest.approx(g.key_inner_diameter / 2)
    # the key: arc length radius * theta from the middle, Y up from the top edge
    row, col = g.key
    u = float(key[0].get("cx")) - left - np.pi * g.radius
    v = g.y_range[1] - (float(key[0].get("cy")) - top)
    assert u == pytest.approx(g.radius * np.radians(g.column_angles_deg[col]), abs=1e-3)
    assert v == pytest.approx(g.row_y[row], abs=1e-3)
    # every mark where the simulator's target has it (arc length, Y)
    centres = np.array([[float(c.get("cx")) - left - np.pi * g.radius,
                         g.y_range[1] - (float(c.get("cy")) - top)] for c in white])
    _, xyz = g.all_marks()
    expected = np.column_stack([g.radius * np.arctan2(xyz[:, 0], xyz[:, 2]), xyz[:, 1]])
    order = np.lexsort((centres[:, 0], centres[:, 1]))
    np.testing.assert_allclose(centres[order], expected[np.lexsort((expected[:, 0],
                                                                    expected[:, 1]))],
                               atol=1e-3)
    for needed in ("bright (white) discs of 1.2 mm", "dark marks", "outer diameter 1.6 mm",
                   "hole 0.8 mm", "height 95 mm", "circumference 67.508 mm", "50 mm"):
        assert needed in text


def test_print_pdf_page_size(tmp_path):
    out = tmp_path / "board.pdf"
    assert main(["print-target", "board", "-o", str(out), "--json"]) == 0
    data = out.read_bytes()
    assert data.startswith(b"%PDF")
    box = [float(v) for v in re.search(rb"/MediaBox \[([^\]]+)\]", data).group(1).split()]
    sheet = board_sheet(Board("checkerboard", rows=11, cols=8, spacing=2.5))
    assert box[2] == pytest.approx(sheet.width / 25.4 * 72, abs=0.01)
    assert box[3] == pytest.approx(sheet.height / 25.4 * 72, abs=0.01)
    wrap = target_wrap_sheet()
    assert wrap.width >= 2 * np.pi * TargetGeometry().radius


@pytest.mark.parametrize(("argv", "match"), [
    (["cylinder", "--rows", "5"], "--rows: only with print-target board"),
    (["board", "--rows", "2", "--cols", "6"], "at least 3"),
    (["board", "--spacing", "-1"], "spacing"),
])
def test_print_target_bad_input(tmp_path, capsys, argv, match):
    out = tmp_path / "x.svg"
    assert main(["print-target", *argv, "-o", str(out)]) == 2
    assert match in capsys.readouterr().err
    assert not out.exists()
    assert main(["print-target", "board", "-o", str(tmp_path / "x.png")]) == 2
    assert ".svg or .pdf" in capsys.readouterr().err


# -- calibrating from a target capture ---------------------------------------------------------
@pytest.fixture(scope="module")
def target_without_rig(tmp_path_factory):
    """A target capture (scale 0.5) whose capture.json has no nominal rig (a real capture)."""
    out = tmp_path_factory.mktemp("target") / "target"
    assert main(["simulate", "--scene", "target", "--scale", "0.5", "--no-truth",
                 "--out", str(out)]) == 0
    manifest = json.loads((out / "capture.json").read_text())
    rig = manifest.pop("rig")
    (out / "capture.json").write_text(json.dumps(manifest))
    return out, rig


def test_calibrate_capture_needs_rig_or_mark_diameter(target_without_rig, tmp_path, capsys):
    capture, _ = target_without_rig
    out = tmp_path / "rig.json"
    assert main(["calibrate", str(capture), "-o", str(out), "--json"]) == 2
    err = capsys.readouterr().err
    assert "no nominal 'rig'" in err and "--mark-diameter-px" in err
    assert not out.exists()
    assert main(["calibrate", str(capture), "-o", str(out), "--mark-diameter-px", "0"]) == 2
    assert "--mark-diameter-px" in capsys.readouterr().err


def test_calibrate_capture_with_mark_diameter(target_without_rig, tmp_path, capsys):
    capture, rig = target_without_rig
    focal = rig["cameras"][0]["K"][1][1]
    diameter = focal * TargetGeometry().mark_diameter / (150 - TargetGeometry().radius)
    out = tmp_path / "rig.json"
    assert main(["calibrate", str(capture), "-o", str(out), "--json",
                 "--mark-diameter-px", f"{diameter:.1f}"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert out.is_file()
    for summary in result["cameras"].values():
        assert summary["points"] >= 30
    # a wrong size says what the marks must look like
    assert main(["calibrate", str(capture), "-o", str(tmp_path / "r2.json"),
                 "--mark-diameter-px", str(3 * diameter)]) == 2
    err = capsys.readouterr().err
    assert "no mark of the expected size" in err and "bright" in err


def test_dark_marks_are_not_found():
    """Dark marks on a light cylinder fail with a message that says why."""
    from nail2nail.calibration.markers import find_target_marks, mark_diameter_px
    from nail2nail.simulation import default_rig, simulate
    from nail2nail.simulation.scenes import make_scene

    rig = default_rig(0.5)
    scene = make_scene("target", surface_albedo=0.85, mark_albedo=0.1)
    sim = simulate(scene, rig=rig, cameras=[1])
    mean = sim.frames["cam1"].astype(np.float64).mean(axis=0)
    with pytest.raises(ValueError, match="bright"):
        find_target_marks(mean, mark_diameter_px=mark_diameter_px(rig.cameras[1]))
