"""Rolled-print directories: what ``nail2nail unroll`` writes.

Layout (``docs/capture-format.md``)::

    OUT/print.png           8-bit grayscale print, legacy convention, resolution in pHYs
    OUT/print.wsq           the same, FBI WSQ (500 ppi only; at other resolutions JPEG 2000,
                            print.jp2, as the FBI's EBTS specifies for 1000 ppi)
    OUT/print_binary.png    ridges black on white (thesis Figure 37)
    OUT/print_mask.png      255 where the print has data
    OUT/print_coverage.png  each camera's share of the blend as a colour (RGB: cameras 0, 1, 2)
    OUT/print_quality.png   ridge clarity per block (grey: 0 → 1), painted on the print
    OUT/print.json          metadata (RolledPrint.metadata() and the files)

Every file is written to a temporary name and renamed; ``print.json`` is written last, so a
directory without it is incomplete.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from nail2nail.io._atomic import atomic_directory, atomic_path
from nail2nail.io._json import write_json
from nail2nail.io.prints import WSQ_BITRATE, encode_jpeg2000, write_print_image

__all__ = ["ROLLED_FORMAT", "write_rolled_print"]

ROLLED_FORMAT = "nail2nail-rolled-print"

#: Length of skin a rolled print keeps below the fingertip, mm: an inked roll records the distal
#: phalanx from the tip to about the distal interphalangeal crease, 22–28 mm on adult fingers
#: (the cameras see further down the finger, and minutiae there match nothing on a card)
ROLLED_LENGTH_MM = 25.0
_COLOURS = np.array([[230, 60, 50], [60, 170, 70], [50, 90, 230], [220, 180, 40],
                     [170, 60, 200], [40, 190, 200]], dtype=np.float32)


def _write_png(path: Path, image: np.ndarray, ppi: float) -> None:
    from PIL import Image

    with atomic_path(path) as tmp:
        Image.fromarray(image).save(tmp, format="PNG", dpi=(ppi, ppi))


def write_rolled_print(out_dir: str | os.PathLike, rolled, *, wsq: bool = True,
                       extra: dict | None = None, wsq_bitrate: float = WSQ_BITRATE) -> dict:
    """Write a :class:`~nail2nail.unroll.RolledPrint` and its metadata; return the metadata.

    Parameters
    ----------
    out_dir : path-like
        Output directory, written as a whole (:func:`nail2nail.io._atomic.atomic_directory`):
        an earlier print there is replaced only once the new one is complete; a non-empty
        directory without ``print.json`` is refused.
    rolled : RolledPrint
    wsq : bool
        Also write the compressed print (WSQ at 500 ppi, JPEG 2000 otherwise).
    wsq_bitrate : float
        WSQ bit rate, bits per pixel (:func:`nail2nail.io.prints.encode_wsq`; default 0.75,
        the FBI's); ``print.json`` records it with the achieved rate and ratio (``wsq``).
    extra : dict, optional
        Added to the metadata (e.g. the scan directory it came from, timings).

    Returns
    -------
    dict
        The content of ``print.json``; ``files`` maps each output to its name in `out_dir`.
    """
    with atomic_directory(out_dir, marker="print.json") as out:
        return _write_print(out, rolled, wsq=wsq, extra=extra, wsq_bitrate=wsq_bitrate)


def _write_print(out: Path, rolled, *, wsq: bool, extra: dict | None,
                 wsq_bitrate: float = WSQ_BITRATE) -> dict:
    ppi = rolled.ppi
    files = {}
    write_print_image(out / "print.png", rolled.image, ppi=ppi)
    files["print"] = "print.png"
    if wsq:
        if abs(ppi - 500.0) < 1e-6:
            write_print_image(out / "print.wsq", rolled.image, ppi=ppi, bitrate=wsq_bitrate)
            files["wsq"] = "print.wsq"
        else:
            with atomic_path(out / "print.jp2") as tmp:
                tmp.write_bytes(encode_jpeg2000(rolled.image))
            files["jpeg2000"] = "print.jp2"
    _write_png(out / "print_binary.png", rolled.binary, ppi)
    files["binary"] = "print_binary.png"
    _write_png(out / "print_mask.png", np.where(rolled.mask, 255, 0).astype(np.uint8), ppi)
    files["mask"] = "print_mask.png"
    share = np.asarray(rolled.share, np.float32)
    colours = _COLOURS[np.arange(share.shape[0]) % len(_COLOURS)]
    rgb = np.einsum("khw,kc->hwc", share, colours)
    rgb = np.where(rolled.mask[..., None], rgb, 255)
    _write_png(out / "print_coverage.png", np.clip(rgb, 0, 255).astype(np.uint8), ppi)
    files["coverage"] = "print_coverage.png"
    # each block's clarity painted over the central step × step part of its window
    grid = np.nan_to_num(np.asarray(rolled.quality["grid"], np.float32), nan=0.0)
    step, n = int(rolled.quality["step_px"]), int(rolled.quality["block_px"])
    big = np.kron(grid, np.ones((step, step), np.float32))
    q = np.zeros(rolled.image.shape, np.float32)
    off = (n - step) // 2
    hh = max(0, min(big.shape[0], q.shape[0] - off))
    ww = max(0, min(big.shape[1], q.shape[1] - off))
    q[off: off + hh, off: off + ww] = big[:hh, :ww]
    _write_png(out / "print_quality.png", np.clip(q * 255 + 0.5, 0, 255).astype(np.uint8), ppi)
    files["quality"] = "print_quality.png"
    meta = rolled.metadata()
    if files.get("wsq"):
        size = (out / files["wsq"]).stat().st_size
        meta["wsq_compression_ratio"] = round(rolled.image.size / max(size, 1), 2)
        meta["wsq"] = {"bitrate_bpp": float(wsq_bitrate),  # asked; achieved: the file's
                       "achieved_bpp": round(8.0 * size / rolled.image.size, 4),
                       "compression_ratio": meta["wsq_compression_ratio"], "bytes": size}
    meta["files"] = files
    if extra:
        meta.update(extra)
    write_json(out / "print.json", meta)
    return meta
