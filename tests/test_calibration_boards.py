"""Planar calibration boards (nail2nail.calibration.boards): geometry, printed design, detection."""

import cv2
import numpy as np
import pytest

from nail2nail.calibration.boards import BOARD_KINDS, Board, detect_board, to_uint8

BOARDS = {
    "checkerboard": Board("checkerboard", rows=7, cols=10, spacing=2.0),
    "charuco": Board("charuco", rows=7, cols=10, spacing=2.0),
    "circles": Board("circles", rows=7, cols=9, spacing=2.0),
    "asymmetric-circles": Board("asymmetric-circles", rows=7, cols=5, spacing=1.5),
}


def _homography(board, px_per_mm, angle_deg, shape=(480, 640), tilt=(4e-4, -3e-4)):
    """Board mm -> image px: rotation by `angle_deg`, scale, perspective, centred."""
    c = board.center
    a = np.radians(angle_deg)
    rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])
    to_centre = np.array([[1, 0, -c[0]], [0, 1, -c[1]], [0, 0, 1.0]])
    scale = np.diag([px_per_mm, px_per_mm, 1.0])
    perspective = np.array([[1, 0, 0], [0, 1, 0], [tilt[0], tilt[1], 1.0]])
    shift = np.array([[1, 0, shape[1] / 2], [0, 1, shape[0] / 2], [0, 0, 1.0]])
    return shift @ perspective @ scale @ rot @ to_centre


def _render(board, hom, shape, *, ss=3, noise=0.01, seed=0):
    """Image of the board seen through `hom`: 3 x 3 samples per pixel, each box-filtered."""
    h, w = shape
    inv = np.linalg.inv(hom)
    ys, xs = np.mgrid[0:h, 0:w].astype(float)
    footprint = 1.0 / (ss * np.sqrt(abs(np.linalg.det(hom[:2, :2]))))
    acc = np.zeros(shape)
    for dy in (np.arange(ss) + 0.5) / ss - 0.5:
        for dx in (np.arange(ss) + 0.5) / ss - 0.5:
            p = np.stack([xs + dx, ys + dy, np.ones_like(xs)], -1) @ inv.T
            acc += board.albedo(p[..., 0] / p[..., 2], p[..., 1] / p[..., 2],
                                footprint=footprint)
    acc /= ss * ss
    return acc + noise * np.random.default_rng(seed).standard_normal(shape)


def _truth(board, hom, indices):
    obj = board.object_points()[indices, :2]
    p = np.column_stack([obj, np.ones(len(obj))]) @ hom.T
    return p[:, :2] / p[:, 2:]


def test_object_points_layout():
    s = 2.0
    pts = BOARDS["checkerboard"].object_points()
    assert pts.shape == (9 * 6, 3) and pts.dtype == np.float64
    np.testing.assert_allclose(pts[0], [s, s, 0])
    np.testing.assert_allclose(pts[1], [2 * s, s, 0])  # x along the columns first
    np.testing.assert_allclose(pts[9], [s, 2 * s, 0])
    charuco = BOARDS["charuco"]
    np.testing.assert_allclose(charuco.object_points(),
                               charuco.opencv_charuco().getChessboardCorners())
    acircles = BOARDS["asymmetric-circles"].object_points()
    np.testing.assert_allclose(acircles[[0, 1, 5]], [[0, 0, 0], [3.0, 0, 0], [1.5, 1.5, 0]])
    assert Board("circles", rows=4, cols=3, spacing=1.0).pattern_size == (3, 4)
    assert BOARDS["checkerboard"].size_mm == (24.0, 18.0)  # 10 x 7 squares + 2 mm margins


def test_albedo_checker_colours_and_box_filter():
    board = BOARDS["checkerboard"]
    # square (0, 0) black, (0, 1) white; margin white
    np.testing.assert_allclose(board.albedo([1.0, 3.0, -1.0], [1.0, 1.0, 1.0]),
                               [0.05, 0.9, 0.9])
    # box filter across an edge: the mean of both sides; exact average of point samples
    mid = board.albedo(2.0, 1.0, footprint=0.5)
    assert mid == pytest.approx((0.05 + 0.9) / 2)
    x = 2.1 + np.linspace(-0.25, 0.25, 20001)
    x, y = np.meshgrid(x, 1.9 + np.linspace(-0.25, 0.25, 201))
    assert board.albedo(2.1, 1.9, footprint=0.5) == pytest.approx(board.albedo(x, y).mean(),
                                                                 abs=2e-3)


@pytest.mark.parametrize("kind", ["circles", "asymmetric-circles", "charuco"])
def test_image_ink_fraction(kind):
    board = BOARDS[kind]
    image = board.image(20)
    width, height = board.size_mm
    assert image.shape == (round(height * 20), round(width * 20)) and image.dtype == np.uint8
    ink = 1 - image.mean() / 255
    if kind == "charuco":
        assert 0.35 < ink < 0.75
    else:
        expected = board.n_points * np.pi * board.marker_mm**2 / 4 / (width * height)
        assert ink == pytest.approx(expected, rel=0.02)


@pytest.mark.parametrize("kind", BOARD_KINDS)
@pytest.mark.parametrize("angle", [10.0, -70.0])
def test_detect_board_subpixel(kind, angle):
    board = BOARDS[kind]
    hom = _homography(board, 20.0, angle)
    image = _render(board, hom, (480, 640))
    found = detect_board(image, board)
    assert found is not None
    indices, xy = found
    assert indices.dtype == np.int64 and xy.shape == (len(indices), 2)
    assert np.all(np.diff(indices) > 0)
    assert len(indices) == board.n_points
    err = np.linalg.norm(xy - _truth(board, hom, indices), axis=1)
    assert np.sqrt(np.mean(err**2)) < 0.02 and err.max() < 0.05  # measured <= 0.010, 0.024


@pytest.mark.parametrize("kind", ["checkerboard", "charuco", "asymmetric-circles"])
def test_detect_board_upside_down(kind):
    """Boards without a half-turn symmetry are labelled right upside down too."""
    board = BOARDS[kind]
    hom = _homography(board, 20.0, 180.0 + 20.0)
    indices, xy = detect_board(_render(board, hom, (480, 640)), board)
    assert np.linalg.norm(xy - _truth(board, hom, indices), axis=1).max() < 0.05


@pytest.mark.parametrize("dtype", ["uint16", "float32", "uint8"])
def test_detect_board_any_bit_depth_warped(dtype):
    """The printed design warped by cv2.warpPerspective, stored at any depth."""
    board = BOARDS["checkerboard"]
    ppm = 40.0
    design = board.image(ppm).astype(np.float32) / 255
    # design pixel -> board mm -> image
    x0, _, y0, _ = board.extent()
    design_to_board = np.array([[1 / ppm, 0, x0 + 0.5 / ppm], [0, 1 / ppm, y0 + 0.5 / ppm],
                                [0, 0, 1.0]])
    hom = _homography(board, 18.0, 25.0)
    warped = cv2.warpPerspective(design, hom @ design_to_board, (640, 480),
                                 flags=cv2.INTER_AREA, borderValue=1.0)
    warped = 0.1 + 0.6 * warped
    warped += 0.01 * np.random.default_rng(1).standard_normal(warped.shape)
    if dtype == "uint16":
        image = (np.clip(warped, 0, 1) * 4095).astype(np.uint16) << 4  # 12-bit left-aligned
    elif dtype == "uint8":
        image = (np.clip(warped, 0, 1) * 255).astype(np.uint8)
    else:
        image = warped.astype(np.float32)
    indices, xy = detect_board(image, board)
    err = np.linalg.norm(xy - _truth(board, hom, indices), axis=1)
    assert np.sqrt(np.mean(err**2)) < 0.03  # measured 0.015 (INTER_AREA warp of the design)


def test_detect_board_not_found():
    blank = np.full((200, 300), 0.5) + 0.01 * np.random.default_rng(0).standard_normal((200, 300))
    for board in BOARDS.values():
        assert detect_board(blank, board) is None


def test_charuco_partial_view():
    board = BOARDS["charuco"]
    hom = _homography(board, 40.0, 5.0)  # larger than the image: part of the board is cut
    indices, xy = detect_board(_render(board, hom, (480, 640)), board)
    assert 4 <= len(indices) < board.n_points
    assert np.linalg.norm(xy - _truth(board, hom, indices), axis=1).max() < 0.1


def test_to_uint8():
    img = np.linspace(0, 1, 100 * 100).reshape(100, 100)
    img[0, 0] = np.nan
    out = to_uint8(img)
    assert out.dtype == np.uint8 and out[0, 0] == 0 and out.max() == 255
    with pytest.raises(ValueError, match="image"):
        to_uint8(np.zeros(5))


@pytest.mark.parametrize(("options", "match"), [
    ({"kind": "square", "rows": 5, "cols": 6, "spacing": 1.0}, "kind"),
    ({"kind": "checkerboard", "rows": 2, "cols": 5, "spacing": 1.0}, "at least 3"),
    ({"kind": "circles", "rows": 4, "cols": 5, "spacing": 0.0}, "spacing"),
    ({"kind": "circles", "rows": 4, "cols": 5, "spacing": 1.0, "marker": 1.5}, "marker"),
    ({"kind": "charuco", "rows": 5, "cols": 6, "spacing": 1.0, "dictionary": "DICT_NOPE"},
     "dictionary"),
    ({"kind": "charuco", "rows": 20, "cols": 20, "spacing": 1.0, "dictionary": "DICT_4X4_50"},
     "needs 200"),
])
def test_board_bad_input(options, match):
    with pytest.raises(ValueError, match=match):
        Board(**options)


def test_board_dict_round_trip():
    for board in BOARDS.values():
        again = Board.from_dict(board.to_dict())
        np.testing.assert_array_equal(again.object_points(), board.object_points())
        assert again.size_mm == board.size_mm and again.marker_mm == board.marker_mm
    with pytest.raises(TypeError, match="rows"):
        Board("circles", rows=4.5, cols=5, spacing=1.0)


@pytest.mark.parametrize("kind", BOARD_KINDS)
def test_albedo_footprint_per_point(kind):
    """A footprint per point gives what each footprint alone gives."""
    board = BOARDS[kind]
    rng = np.random.default_rng(2)
    x = rng.uniform(-1, 20, 200)
    y = rng.uniform(-1, 14, 200)
    widths = rng.choice([0.0, 0.02, 0.08], 200)
    each = np.array([board.albedo(a, b, footprint=w) for a, b, w in zip(x, y, widths,
                                                                           strict=True)])
    np.testing.assert_allclose(board.albedo(x, y, footprint=widths), each.ravel(), atol=1e-12)
    with pytest.raises(ValueError, match="footprint"):
        board.albedo(x, y, footprint=-1.0)


@pytest.mark.parametrize("kind", ["checkerboard", "charuco", "circles"])
def test_detect_board_with_lens_distortion(kind):
    """Barrel distortion (3-4 px at the board's outer points): points still within 0.08 px."""
    board = BOARDS[kind]
    hom = _homography(board, 20.0, 10.0)
    k1 = -4e-7  # per px^2 about the image centre
    centre = np.array([320.0, 240.0])

    def distort(p):
        d = p - centre
        return centre + d * (1 + k1 * np.sum(d**2, axis=-1, keepdims=True))

    h, w = 480, 640
    ys, xs = np.mgrid[0:h, 0:w].astype(float)
    inv = np.linalg.inv(hom)
    acc = np.zeros((h, w))
    for dy in (-1 / 3, 0, 1 / 3):
        for dx in (-1 / 3, 0, 1 / 3):
            pd = np.stack([xs + dx, ys + dy], -1)
            pu = pd.copy()
            for _ in range(10):  # undistort by fixed point
                pu = centre + (pd - centre) / (1 + k1 * np.sum((pu - centre) ** 2, -1,
                                                               keepdims=True))
            q = np.concatenate([pu, np.ones((h, w, 1))], -1) @ inv.T
            acc += board.albedo(q[..., 0] / q[..., 2], q[..., 1] / q[..., 2], footprint=1 / 60)
    image = acc / 9 + 0.01 * np.random.default_rng(3).standard_normal((h, w))
    indices, xy = detect_board(image, board)
    truth = distort(_truth(board, hom, indices))
    assert np.abs(truth - _truth(board, hom, indices)).max() > 3  # distortion is there
    err = np.linalg.norm(xy - truth, axis=1)
    assert np.sqrt(np.mean(err**2)) < 0.03 and err.max() < 0.08


def test_symmetric_circles_half_turn_labelled_upright():
    """A symmetric grid turned by 180 degrees looks the same: labelled with +x to the right."""
    board = BOARDS["circles"]
    hom = _homography(board, 20.0, 185.0)
    indices, xy = detect_board(_render(board, hom, (480, 640)), board)
    mirrored = board.n_points - 1 - indices  # the same circles counted from the other corner
    assert np.linalg.norm(xy - _truth(board, hom, mirrored), axis=1).max() < 0.05
    first = xy[np.argmin(indices)]
    last = xy[np.argmax(indices)]
    assert first[0] < last[0] and first[1] < last[1]  # origin top-left in the image
