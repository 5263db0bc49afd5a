"""User-given validity masks: one image per camera, the pixels a scan may keep.

A mask is an image of the camera's size (PNG, TIFF, any format Pillow reads; 1, 8 or 16 bits,
grey or colour): a pixel is kept where the mask is non-zero (in any channel) and dropped where
it is zero. Typical use: blank out a fixture, a finger rest or a reflection that the decoder's
own checks accept. Row/column order is the camera image's (row 0 at the top), as the frames.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import cast

import numpy as np
from PIL import Image

__all__ = ["parse_mask_option", "read_mask"]


def read_mask(path: str | os.PathLike, *, shape: tuple[int, int] | None = None) -> np.ndarray:
    """Read a mask image as a boolean array, ``True`` where non-zero.

    Parameters
    ----------
    path : path-like
        Image file.
    shape : (int, int), optional
        Expected ``(H, W)`` (the camera's frames).

    Returns
    -------
    (H, W) bool

    Raises
    ------
    ValueError
        Naming the file: unreadable, not an image, or of another size than `shape`.
    """
    try:
        with Image.open(path) as im:
            values = np.asarray(im)
    except (OSError, Image.DecompressionBombError) as exc:
        raise ValueError(f"{os.fspath(path)}: cannot read the mask image ({exc})") from exc
    if values.ndim == 3:
        values = cast(np.ndarray, values.any(axis=-1))
    if values.ndim != 2:
        raise ValueError(f"{os.fspath(path)}: a mask must be a 2D image, got shape "
                         f"{values.shape}")
    mask = values != 0
    if shape is not None and mask.shape != tuple(shape):
        raise ValueError(
            f"{os.fspath(path)}: the mask is {mask.shape[1]} x {mask.shape[0]} px but the "
            f"camera's frames are {shape[1]} x {shape[0]} px")
    return mask


def parse_mask_option(values) -> dict[str, str]:
    """``["cam0=mask0.png", "cam2=m.png"]`` (the CLI's ``--mask``) as ``{camera: path}``.

    Raises
    ------
    ValueError
        For an entry without ``=``, an empty name or path, or a camera given twice.
    """
    out: dict[str, str] = {}
    for value in values or ():
        name, sep, path = str(value).partition("=")
        if not sep or not name or not path:
            raise ValueError(f"--mask: expected CAMERA=IMAGE (e.g. cam0=mask.png), got {value!r}")
        if name in out:
            raise ValueError(f"--mask: camera {name!r} is given twice")
        out[name] = path
    return out


def check_mask_names(masks: Mapping, names, where: str) -> None:
    """Refuse masks for cameras the capture does not have."""
    unknown = sorted(set(masks) - set(names))
    if unknown:
        raise ValueError(f"{where}: masks given for unknown camera(s) {unknown} "
                         f"(the capture has {list(names)})")
