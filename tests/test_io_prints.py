"""Fingerprint image files: PNG and WSQ with their resolution (nail2nail.io.prints)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from PIL import Image

from nail2nail.io.prints import read_print_image, write_print_image


@settings(max_examples=20, deadline=None)
@given(image=arrays(np.uint8, st.tuples(st.integers(1, 20), st.integers(1, 20))),
       ppi=st.sampled_from([500.0, 1000.0, 333.3]))
def test_png_round_trip(tmp_path_factory, image, ppi):
    path = tmp_path_factory.mktemp("prints") / "p.png"
    write_print_image(path, image, ppi=ppi)
    back, back_ppi = read_print_image(path)
    np.testing.assert_array_equal(back, image)
    assert back_ppi == pytest.approx(ppi, abs=0.05)


def test_wsq_round_trip_and_ppi(tmp_path):
    rows = np.arange(120)[:, None] + 0 * np.arange(100)[None, :]
    image = np.rint(127.5 + 100 * np.cos(2 * np.pi * rows / 9)).astype(np.uint8)
    write_print_image(tmp_path / "p.wsq", image)
    back, ppi = read_print_image(tmp_path / "p.wsq")
    assert back.shape == image.shape and back.dtype == np.uint8 and ppi == 500.0
    assert np.abs(back.astype(float) - image).mean() < 8  # lossy
    with pytest.raises(ValueError, match="500 ppi"):
        write_print_image(tmp_path / "q.wsq", image, ppi=1000)


def test_png_without_dpi_and_colour(tmp_path):
    Image.fromarray(np.full((4, 5, 3), (255, 0, 0), np.uint8)).save(tmp_path / "c.png")
    image, ppi = read_print_image(tmp_path / "c.png")
    assert image.shape == (4, 5) and ppi is None
    assert image[0, 0] == np.asarray(Image.new("RGB", (1, 1), (255, 0, 0)).convert("L"))[0, 0]


def test_implausible_dpi_warns(tmp_path):
    Image.fromarray(np.zeros((4, 5), np.uint8)).save(tmp_path / "a.png", dpi=(72, 72))
    with pytest.warns(UserWarning, match="implausible"):
        _, ppi = read_print_image(tmp_path / "a.png")
    assert ppi is None


def test_bad_files(tmp_path):
    with pytest.raises(ValueError, match="no such"):
        read_print_image(tmp_path / "missing.png")
    (tmp_path / "empty.png").write_bytes(b"")
    with pytest.raises(ValueError, match=r"empty\.png: empty"):
        read_print_image(tmp_path / "empty.png")
    (tmp_path / "text.png").write_text("not an image")
    with pytest.raises(ValueError, match=r"text\.png: not a readable image"):
        read_print_image(tmp_path / "text.png")
    Image.fromarray(np.zeros((4, 5), np.uint16)).save(tmp_path / "deep.png")
    with pytest.raises(ValueError, match=r"deep\.png: .*16-bit"):
        read_print_image(tmp_path / "deep.png")
    with pytest.raises(ValueError, match="image"):
        write_print_image(tmp_path / "x.png", np.zeros((3, 3), np.float32))
