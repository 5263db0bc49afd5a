"""The virtual scanner's board scene: pose, rendering, board poses, and the simulate CLI."""

import json

import numpy as np
import pytest

from nail2nail.calibration.boards import Board, default_board, detect_board
from nail2nail.cli import main
from nail2nail.io.capture import read_capture, read_truth
from nail2nail.scan.decoding import decode
from nail2nail.scan.patterns import PatternSet
from nail2nail.simulation import default_rig
from nail2nail.simulation.board_poses import board_pose_checks, board_poses, rig_working_point
from nail2nail.simulation.rig import Rig
from nail2nail.simulation.scenes import BoardScene, make_scene


def test_board_scene_pose_and_surface():
    board = default_board("checkerboard")
    rest = BoardScene(board=board, pose=(0, 0, 0, 0, 3.175, 0))
    # at rest: printed face towards +Z, x along +X, y down (world -Y), centre on the axis point
    np.testing.assert_allclose(rest.R_world_board, np.diag([1.0, -1.0, -1.0]))
    np.testing.assert_allclose(rest.world_from_board(board.center[None])[0], [0, 3.175, 0])
    scene = BoardScene(board=board, pose=(20.0, -15.0, 5.0, 1.0, 2.0, -3.0))
    pts = board.object_points()
    world = scene.world_from_board(pts)
    np.testing.assert_allclose(scene.board_from_world(world), pts, atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(scene.R_world_board), 1.0)
    # rays from the centre camera to the corners hit them; a ray beyond the sheet misses
    origin = np.array([0.0, 3.175, 150.0])
    rays = world - origin
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    t = scene.intersect(origin, rays)
    np.testing.assert_allclose(origin + t[:, None] * rays, world, atol=1e-9)
    info = scene.surface(world)
    np.testing.assert_allclose(info.params["x"], pts[:, 0], atol=1e-9)
    np.testing.assert_allclose(info.normal @ np.array([0, 0, 1.0]) > 0.8, True)
    assert np.isinf(scene.intersect(origin, np.array([[0.3, 0.0, -1.0]]) / np.hypot(0.3, 1)))
    d = scene.to_dict()
    assert d["name"] == "board" and d["board"]["kind"] == "checkerboard"
    np.testing.assert_allclose(d["t_world_board"], scene.t_world_board)
    with pytest.raises(ValueError, match="pose"):
        BoardScene(pose=(0, 0, 0))


def test_board_geometry_round_trip():
    """As tests/test_simulation.py's round trip: panel -> projector ray -> board -> camera."""
    from nail2nail.simulation.render import camera_geometry

    rig = default_rig(0.25)
    scene = make_scene("board", rig=rig, pose=(15.0, 10.0, 0.0, 0.0, 3.0, 1.0))
    for i, cam in enumerate(rig.cameras):
        g = camera_geometry(rig, scene, i)
        rows, cols = np.nonzero(g.mask)
        assert rows.size > 1000
        np.testing.assert_allclose(cam.project(g.xyz[rows, cols]), np.column_stack([cols, rows]),
                                   atol=1e-6)
        origin, d = rig.projector_rays(np.column_stack([g.xp[rows, cols], g.yp[rows, cols]]))
        t = scene.intersect(origin, d)
        back = cam.project(origin + t[:, None] * d)
        assert np.hypot(back[:, 0] - cols, back[:, 1] - rows).max() <= 1e-6
        local = scene.board_from_world(g.xyz[rows, cols])
        np.testing.assert_allclose(local[:, 2], 0.0, atol=1e-9)
        np.testing.assert_allclose(g.params["x"][rows, cols], local[:, 0], atol=1e-9)


def test_make_scene_board_footprint_from_rig():
    rig = default_rig(0.5)
    scene = make_scene("board", rig=rig)
    pixel = 150 / (32 * 150 * 0.5)
    assert scene.footprint == pytest.approx(pixel, rel=1e-3)  # one pixel
    centre = np.array([[0.0, 3.175, 0.0]])
    # facing the centre camera: the side cameras see the board at 45 degrees
    assert scene.pixel_footprint(centre)[0] == pytest.approx(pixel / np.cos(np.radians(45)),
                                                             rel=1e-3)
    turned = make_scene("board", rig=rig, pose=(0.0, 30.0, 0.0, 0.0, 3.175, 0.0))
    assert turned.pixel_footprint(centre)[0] == pytest.approx(pixel / np.cos(np.radians(75)),
                                                              rel=1e-3)
    bare = BoardScene(footprint=0.05)
    assert bare.pixel_footprint(centre)[0] == 0.05


@pytest.mark.parametrize("kind", ["checkerboard", "charuco", "asymmetric-circles"])
def test_board_poses_in_view(kind):
    rig = default_rig(0.25)
    board = default_board(kind)
    poses = board_poses(6, rig, board=board, seed=3)
    assert len(poses) == 6 and len(set(poses)) == 6
    np.testing.assert_allclose(rig_working_point(rig), [0, 3.175, 0], atol=1e-9)
    tilts = []
    for pose in poses:
        scene = BoardScene(board=board, pose=pose)
        assert board_pose_checks(scene, rig)["ok"]
        normal = -scene.R_world_board[:, 2]
        tilts.append(np.degrees(np.arccos(normal[2])))
        assert np.linalg.norm(np.asarray(pose[3:]) - [0, 3.175, 0]) < 5
    assert min(tilts) > 10 and max(tilts) > 20  # tilted, not facing the camera
    # tilted about both axes: the normals lean in X and in Y
    normals = np.array([-BoardScene(board=board, pose=p).R_world_board[:, 2] for p in poses])
    assert np.ptp(normals[:, 0]) > 0.3 and np.ptp(normals[:, 1]) > 0.3
    assert board_poses(6, rig, board=board, seed=3) == poses  # reproducible
    with pytest.raises(ValueError, match="smaller board"):
        board_poses(1, rig, board=Board("checkerboard", rows=11, cols=8, spacing=6.0))


def _decoded_albedo(capture, name):
    pattern_set = PatternSet.from_dict(capture.manifest["pattern_set"])
    return decode(capture.load_frames(name), pattern_set).albedo


def test_simulate_board_poses_detected(tmp_path, capsys):
    """Captures of the board at drawn poses show it to detect_board in the decoded albedo."""
    out = tmp_path / "poses"
    assert main(["simulate", "--scene", "board", "--board", "checkerboard", "--rows", "11",
                 "--cols", "8", "--spacing", "2.5", "--poses", "2", "--scale", "0.5",
                 "--out", str(out)]) == 0
    assert "2 captures" in capsys.readouterr().out
    summary = json.loads((out / "board-poses.json").read_text())
    board = Board.from_dict(summary["board"])
    assert [p["capture"] for p in summary["poses"]] == ["pose00", "pose01"]
    errors = []
    for entry in summary["poses"]:
        capture = read_capture(out / entry["capture"], load=False)
        scene = capture.manifest["scene"]
        assert scene["name"] == "board"
        rig = Rig.from_dict(capture.manifest["rig"])
        r_wb = np.array(scene["R_world_board"])
        t_wb = np.array(scene["t_world_board"])
        np.testing.assert_allclose(r_wb, entry["R_world_board"])
        assert (out / entry["capture"] / "truth" / "calibration.json").is_file()
        for name, cam in zip(rig.camera_names, rig.cameras, strict=True):
            found = detect_board(_decoded_albedo(capture, name), board)
            assert found is not None, (entry["capture"], name)
            indices, xy = found
            assert len(indices) == board.n_points
            truth = cam.project(board.object_points()[indices] @ r_wb.T + t_wb)
            errors.append(np.linalg.norm(xy - truth, axis=1))
            # truth/ gives the board coordinates of every pixel
            params = read_truth(out / entry["capture"], name)
            col, row = np.rint(xy[0]).astype(int)
            assert np.hypot(params["param_x"][row, col] - board.object_points()[indices[0], 0],
                            params["param_y"][row, col]
                            - board.object_points()[indices[0], 1]) < 0.1
    errors = np.concatenate(errors)
    assert np.sqrt(np.mean(errors**2)) < 0.02 and errors.max() < 0.06  # measured 0.006, 0.018


def test_simulate_board_single_pose(tmp_path):
    out = tmp_path / "one"
    assert main(["simulate", "--scene", "board", "--board", "charuco", "--scale", "0.5",
                 "--pose", "10", "-10", "0", "0", "3", "0", "--out", str(out)]) == 0
    manifest = json.loads((out / "capture.json").read_text())
    assert manifest["scene"]["pose"] == {"rotation_vector_deg": [10.0, -10.0, 0.0],
                                         "center_mm": [0.0, 3.0, 0.0]}
    assert manifest["scene"]["board"]["dictionary"] == "DICT_5X5_100"
    capture = read_capture(out, load=False)
    board = Board.from_dict(manifest["scene"]["board"])
    rig = Rig.from_dict(manifest["rig"])
    r_wb = np.array(manifest["scene"]["R_world_board"])
    t_wb = np.array(manifest["scene"]["t_world_board"])
    for name, cam in zip(rig.camera_names, rig.cameras, strict=True):
        indices, xy = detect_board(_decoded_albedo(capture, name), board)
        assert len(indices) == board.n_points  # every corner, at 61 degrees too (cam2)
        truth = cam.project(board.object_points()[indices] @ r_wb.T + t_wb)
        assert np.linalg.norm(xy - truth, axis=1).max() < 0.03  # measured 0.007


@pytest.mark.parametrize(("argv", "match"), [
    (["--scene", "finger", "--board", "charuco"], "--board: only with --scene board"),
    (["--scene", "board", "--rows", "2", "--cols", "6"], "at least 3"),
    (["--scene", "board", "--poses", "0"], "--poses"),
    (["--scene", "board", "--poses", "2", "--pose", "0", "0", "0", "0", "0", "0"], "--pose"),
    (["--scene", "board", "--spacing", "9"], "smaller board"),
])
def test_simulate_board_bad_options(tmp_path, capsys, argv, match):
    out = tmp_path / "bad"
    extra = ["--poses", "1"] if argv[-1] == "9" else []
    assert main(["simulate", *argv, *extra, "--scale", "0.25", "--out", str(out)]) == 2
    assert match in capsys.readouterr().err
    assert not out.exists()
