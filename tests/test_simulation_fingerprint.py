"""Synthetic fingerprints (SFinGe-like growth) and the finger's rolled print."""

from __future__ import annotations

import numpy as np
import pytest

from nail2nail.simulation.fingerprint import (
    find_minutiae,
    generate_fingerprint,
    orientation_field,
)
from nail2nail.simulation.scenes import make_scene


@pytest.fixture(scope="module")
def small_print():
    return generate_fingerprint(u_range=(-6, 6), v_range=(-6, 6), core=(0, 1), delta=(-3, -4),
                                seed=1)


def test_orientation_field_singularities():
    # around a core the orientation turns by +pi, around a delta by -pi
    t = np.linspace(0, 2 * np.pi, 721)
    for point, sign in (((0.0, 0.0), 1), ((0.0, -5.0), -1)):
        u, v = point[0] + 0.5 * np.cos(t), point[1] + 0.5 * np.sin(t)
        theta = orientation_field(u, v, core=(0, 0), delta=(0, -5))
        turn = np.sum(np.angle(np.exp(2j * np.diff(theta)))) / 2
        assert turn == pytest.approx(sign * np.pi, abs=1e-6)


def test_ridge_period_and_range(small_print):
    fp = small_print
    assert fp.ppi == pytest.approx(500)
    assert fp.ridges.dtype == np.float32
    assert fp.ridges.min() >= -1 and fp.ridges.max() <= 1
    # dominant spatial period of the ridge field: 0.46 mm +- 10 %
    spec = np.abs(np.fft.fft2(fp.ridges - fp.ridges.mean()))
    fy = np.fft.fftfreq(fp.shape[0], fp.pitch)[:, None]
    fx = np.fft.fftfreq(fp.shape[1], fp.pitch)[None, :]
    f = np.hypot(fx, fy)
    peak = np.sum(f * spec**2) / np.sum(spec**2)
    assert 1 / peak == pytest.approx(0.46, rel=0.1)


def test_minutiae_found_and_reproducible(small_print):
    fp = small_print
    assert len(fp.minutiae) >= 5
    assert set(np.unique(fp.minutiae[:, 4])) <= {1.0, 3.0}
    col, row = fp.pixel_from_uv(fp.minutiae[:, 0], fp.minutiae[:, 1])
    np.testing.assert_allclose(np.column_stack([col, row]), fp.minutiae[:, 2:4], atol=1e-9)
    again = generate_fingerprint(u_range=(-6, 6), v_range=(-6, 6), core=(0, 1), delta=(-3, -4),
                                 seed=1)
    np.testing.assert_array_equal(again.ridges, fp.ridges)
    other = generate_fingerprint(u_range=(-6, 6), v_range=(-6, 6), core=(0, 1), delta=(-3, -4),
                                 seed=2)
    assert np.any(other.ridges != fp.ridges)


def test_find_minutiae_on_a_drawn_ridge():
    image = -np.ones((60, 60))
    image[28:32, 10:40] = 1.0  # one ridge: two endings
    image[20:40, 38:42] = 1.0  # joined to a vertical one: a T-junction, i.e. a bifurcation
    found = find_minutiae(image, border_px=2, min_distance_px=3)
    kinds = sorted(found[:, 2].tolist())
    assert kinds.count(1.0) == 3 and kinds.count(3.0) == 1
    ending = found[(found[:, 2] == 1) & (found[:, 0] < 20)]
    assert ending.shape[0] == 1 and 9 <= ending[0, 0] <= 13 and 28 <= ending[0, 1] <= 31


def test_sample_matches_grid(small_print):
    fp = small_print
    rows, cols = np.array([10, 100, 200]), np.array([5, 150, 230])
    u, v = fp.u0 + fp.pitch * cols, fp.v0 - fp.pitch * rows
    np.testing.assert_allclose(fp.sample(u, v), fp.ridges[rows, cols], atol=1e-5)


def test_generate_bad_input():
    with pytest.raises(ValueError, match="ridge_period"):
        generate_fingerprint(ridge_period=5.0)
    with pytest.raises(ValueError, match="u_range"):
        generate_fingerprint(u_range=(3, 1))


def test_rolled_print():
    scene = make_scene("finger")
    image, mask = scene.rolled_print()
    fp = scene.fingerprint
    assert image.shape == fp.shape and image.dtype == np.uint8
    assert fp.ppi == pytest.approx(500)
    assert np.all(image[~mask] == 255)
    # the tip: above y0 + meridian length nothing maps onto the finger
    v = fp.v0 - fp.pitch * np.arange(fp.shape[0])
    assert not np.any(mask[v > scene.y0 + scene._m[-1] + 0.1])
    assert np.all(mask[v < scene.y0 - 1][:, fp.shape[1] // 2])
    # ridges dark: the ink of ridge crests
    assert image[mask][fp.ridges[mask] > 0.9].mean() < 30
    assert len(fp.minutiae) > 50
