"""Finding and identifying the cylinder target's marks (issue 3)."""

from __future__ import annotations

import numpy as np
import pytest

from nail2nail.calibration.markers import TargetGeometry, find_target_marks, mark_diameter_px
from nail2nail.io.points import read_points
from nail2nail.scan.patterns import PatternSet, make_patterns
from nail2nail.simulation.render import camera_geometry, render_frames
from nail2nail.simulation.rig import default_rig
from nail2nail.simulation.scenes import make_scene
from tests.conftest import thesis_table_path

WHITE = np.full((1, 1040, 1280), 255, dtype=np.uint8)


@pytest.fixture(scope="module")
def target_images():
    """White-lit images of the target, and the mean of three phase-shifted fringe frames."""
    rig = default_rig(0.5)
    scene = make_scene("target")
    fringes = make_patterns(PatternSet(x=[(1, 3)], gamma=2.2))
    images, means = [], []
    for i in range(3):
        g = camera_geometry(rig, scene, i)
        frames = render_frames(g, np.concatenate([WHITE, fringes]), rig.photometry, seed=7,
                               camera_index=i, scale=0.5)
        images.append(frames[0])
        means.append(frames[1:].astype(float).mean(axis=0))
    return rig, images, means


@pytest.mark.parametrize("camera", [0, 1])
def test_grid_matches_thesis_tables(camera):
    table = read_points(thesis_table_path(camera))
    grid, xyz = TargetGeometry().all_marks()
    dist = np.linalg.norm(table.xyz_world[:, None, :] - xyz[None], axis=-1)
    assert np.all(dist.min(axis=1) < 2e-3)  # every thesis point is a mark of the grid
    # X = -7.2817, Z = 7.9003 is the column at -42.66 degrees
    col = grid[np.argmin(np.linalg.norm(xyz - [-7.2817, 19.05, 7.9003], axis=1)), 1]
    assert TargetGeometry().column_angles_deg[col] == pytest.approx(-42.66, abs=0.01)


@pytest.mark.parametrize("camera", [0, 1, 2])
def test_marks_found_at_world_coordinates(target_images, camera):
    rig, images, _ = target_images
    cam = rig.cameras[camera]
    marks = find_target_marks(images[camera], mark_diameter_px=mark_diameter_px(cam))
    # each camera sees at least five columns and all six rows
    assert len(np.unique(marks.grid[:, 1])) >= 5
    assert len(np.unique(marks.grid[:, 0])) == 6
    assert np.count_nonzero(marks.is_key) == 1
    assert tuple(marks.grid[marks.is_key][0]) == (2, 5)
    # identities are right: the centroid is where the camera projects the mark's world point
    err = np.linalg.norm(marks.xy - cam.project(marks.xyz_world), axis=1)
    assert err.max() < 0.5, f"max centroid error {err.max():.3f} px"
    assert np.median(err) < 0.2
    np.testing.assert_allclose(marks.xyz_world, TargetGeometry().mark_world(marks.grid))


def test_marks_bad_input(target_images):
    _, images, _ = target_images
    with pytest.raises(ValueError, match="2-D"):
        find_target_marks(images[0][None], mark_diameter_px=20)
    with pytest.raises(ValueError, match="mark_diameter_px"):
        find_target_marks(images[0], mark_diameter_px=0)
    with pytest.raises(ValueError, match="no bright marks"):
        find_target_marks(np.zeros((50, 50)), mark_diameter_px=10)
    with pytest.raises(ValueError, match="grid"):
        TargetGeometry().mark_world([[6, 0]])


def test_missing_key_is_an_error(target_images):
    rig, images, _ = target_images
    image = images[1].copy()
    cam = rig.cameras[1]
    x, y = cam.project(TargetGeometry().mark_world([[2, 5]]))[0]
    image[int(y) - 20 : int(y) + 21, int(x) - 20 : int(x) + 21] = image[int(y) + 40, int(x)]
    with pytest.raises(ValueError, match="key mark"):
        find_target_marks(image, mark_diameter_px=mark_diameter_px(cam))


def test_marks_on_the_mean_of_fringe_frames(target_images):
    """The mean of an N-step phase sequence is uniformly lit: the marks are found in it too."""
    rig, _, means = target_images
    for camera in range(3):
        cam = rig.cameras[camera]
        marks = find_target_marks(means[camera], mark_diameter_px=mark_diameter_px(cam))
        err = np.linalg.norm(marks.xy - cam.project(marks.xyz_world), axis=1)
        assert len(np.unique(marks.grid[:, 1])) >= 5 and err.max() < 0.5
