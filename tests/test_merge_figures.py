"""Tests of nail2nail.merge.figures: every figure a PNG of the expected size, written atomically."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

sys.path.insert(0, str(Path(__file__).parent))
from _synthetic import synthetic_scans

from nail2nail.merge import correspond
from nail2nail.merge.figures import (
    plot_correspondence_images,
    plot_correspondences_3d,
    plot_merge_heatmap,
    plot_merge_histogram,
    render_points,
)
from nail2nail.merge.fusion import fuse_scans

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def scans():
    return synthetic_scans(size=(64, 80), noise_px=0.05)


@pytest.fixture(scope="module")
def corr(scans):
    return correspond(scans[0], scans[1], stride=2)


def _is_png(path: Path) -> tuple[int, int]:
    assert path.read_bytes()[:8] == PNG
    assert not list(path.parent.glob(".*.tmp"))  # no temporary left behind
    with Image.open(path) as im:
        return im.size


def test_heatmap(corr, scans, tmp_path):
    out = plot_merge_heatmap(corr, tmp_path / "heat.png", background=scans[0].albedo)
    assert _is_png(out) == (600, 650)


def test_histogram(corr, tmp_path):
    assert _is_png(plot_merge_histogram(corr.distance_mm, tmp_path / "h.png")) == (600, 400)
    assert _is_png(plot_merge_histogram([], tmp_path / "empty.png")) == (600, 400)


def test_correspondence_figures(corr, scans, tmp_path):
    assert _is_png(plot_correspondences_3d(corr, tmp_path / "c3d.png", every=4)) == (700, 600)
    out = plot_correspondence_images(corr, scans[0].albedo, scans[1].albedo, tmp_path / "m.png",
                                     every=4)
    assert _is_png(out) == (1000, 650)


def test_render_points_draws_the_object(scans, tmp_path):
    sup = fuse_scans(scans)
    out = render_points(sup.vertices, tmp_path / "r.png", normals=sup.vertex_normals,
                        colors=sup.colors, azim=30, size=(200, 300))
    assert _is_png(out) == (200, 300)
    with Image.open(out) as im:
        pixels = np.asarray(im.convert("L"))
    covered = np.mean(pixels < 250)
    assert 0.2 < covered < 0.9  # the cylinder, with background around it


def test_bad_inputs(tmp_path):
    with pytest.raises(TypeError, match="corr: expected a Correspondence"):
        plot_merge_heatmap("x", tmp_path / "a.png")
    with pytest.raises(ValueError, match=r"points: expected shape \(N, 3\)"):
        render_points(np.zeros((4, 2)), tmp_path / "a.png")
    with pytest.raises(ValueError, match="no finite point"):
        render_points(np.full((4, 3), np.nan), tmp_path / "a.png")
    assert not list(tmp_path.iterdir())
