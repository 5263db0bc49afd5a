"""Fingerprint images: 8-bit grayscale PNG (or any Pillow format) and FBI WSQ, with their ppi.

Prints are ``(H, W) uint8`` arrays, ridges dark on light, in the legacy convention
(``docs/conventions.md``, "Rolled prints"). The resolution is read from a PNG's ``pHYs`` chunk
(Pillow's ``info["dpi"]``) or from the ``PPI`` line of a WSQ file's ``NIST_COM`` comment.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
from PIL import Image

from nail2nail.io._atomic import atomic_path

__all__ = ["read_print_image", "write_print_image"]

# a resolution outside this range is taken as "unknown" (e.g. 72 or 96 dpi written by
# tools that know nothing of the scan)
_PPI_RANGE = (200.0, 4000.0)


def _wsq_ppi(data: bytes) -> float | None:
    """PPI of a WSQ file from its NIST_COM comment (``None`` if absent or ``-1``)."""
    pos = 2  # after the SOI marker FFA0
    while pos + 4 <= len(data):
        marker = data[pos : pos + 2]
        if marker in (b"\xff\xa2", b"\xff\xa1") or marker[:1] != b"\xff":
            break  # start of frame (or end / garbage): no more header segments
        length = int.from_bytes(data[pos + 2 : pos + 4], "big")
        if marker == b"\xff\xa8":
            text = data[pos + 4 : pos + 2 + length].decode("latin-1")
            if text.startswith("NIST_COM"):
                match = re.search(r"^PPI\s+(-?\d+(?:\.\d+)?)\s*$", text, re.MULTILINE)
                if match and float(match.group(1)) > 0:
                    return float(match.group(1))
        pos += 2 + length
    return None


def read_print_image(path: str | os.PathLike) -> tuple[np.ndarray, float | None]:
    """Read a fingerprint image as 8-bit grey, with its resolution if the file records it.

    Grayscale 8-bit images are returned unchanged; colour (RGB, RGBA, palette) and 1-bit
    images are converted to grey with Pillow's ``convert("L")`` (ITU-R 601 luma); 16-bit and
    floating-point images are refused (convert them to 8-bit first, e.g. ``value >> 8``).

    Parameters
    ----------
    path : path-like
        PNG (or another format Pillow reads) or WSQ (``wsq`` plugin).

    Returns
    -------
    image : (H, W) uint8
    ppi : float or None
        PNG: ``info["dpi"]`` rounded to 0.1 (PNG stores pixels per metre); WSQ: the
        ``NIST_COM`` ``PPI``; ``None`` when absent, or (with a warning) outside 200–4000.

    Raises
    ------
    ValueError
        Naming the file: missing, not an image, empty, or 16-bit / floating point.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "print.png"
    >>> _ = write_print_image(path, np.full((4, 6), 200, np.uint8), ppi=500)
    >>> image, ppi = read_print_image(path)
    >>> image.shape, image.dtype.name, ppi
    ((4, 6), 'uint8', 500.0)
    """
    import wsq  # noqa: F401  (registers the WSQ plugin with Pillow)

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such print image file")
    data = path.read_bytes()
    if not data:
        raise ValueError(f"{path}: empty file, expected a PNG or WSQ print image")
    if data[:2] == b"\xff\xa0":  # WSQ: decoded in a child process (see _decode_wsq)
        image, fmt, info = _decode_wsq(path), "WSQ", {}
        size = image.shape[::-1]
    else:
        try:
            with warnings.catch_warnings(), Image.open(path) as im:
                warnings.simplefilter("error", Image.DecompressionBombWarning)
                im.load()
                mode, size, info = im.mode, im.size, dict(im.info)
                if mode in ("I", "I;16", "I;16B", "I;16L", "I;16N", "F"):
                    raise ValueError(f"{path}: {mode} ({'16-bit' if 'I' in mode else 'float'}) "
                                     "image; expected 8-bit grayscale (convert first, e.g. "
                                     "value >> 8)")
                image = np.asarray(im if mode == "L" else im.convert("L"))
                fmt = im.format
        except ValueError as exc:
            if str(exc).startswith(f"{path}: "):
                raise
            raise ValueError(f"{path}: not a readable image ({_short(exc)})") from exc
        except Exception as exc:  # Pillow raises many types on corrupt data
            raise ValueError(f"{path}: not a readable image ({_short(exc)})") from exc
    if image.size == 0 or 0 in size:
        raise ValueError(f"{path}: empty image ({size[0]}x{size[1]})")
    if fmt == "WSQ":
        ppi = _wsq_ppi(data)
    else:
        dpi = info.get("dpi")
        ppi = round(float(dpi[0]), 1) if dpi else None
    if ppi is not None and not _PPI_RANGE[0] <= ppi <= _PPI_RANGE[1]:
        warnings.warn(f"{path}: recorded resolution {ppi} ppi is implausible for a print; "
                      "ignored", stacklevel=2)
        ppi = None
    return np.ascontiguousarray(image, dtype=np.uint8), ppi


_WSQ_CHILD = r"""
import sys, warnings
from PIL import Image
import wsq  # registers the WSQ plugin
warnings.simplefilter("error", Image.DecompressionBombWarning)
with Image.open(sys.argv[1]) as im:
    im.load()
    im = im if im.mode == "L" else im.convert("L")
    sys.stdout.buffer.write(b"%d %d\n" % im.size + im.tobytes())
"""


def _decode_wsq(path: Path, *, timeout: float = 60.0) -> np.ndarray:
    """A WSQ file's pixels ``(H, W) uint8``, decoded by the NBIS decoder in a child process.

    The decoder (C, package ``wsq``) crashes the process (SIGSEGV) on some corrupt files and
    prints ``ERROR : …`` lines on stderr for others (found by ``bench/fuzz_readers.py``); in a
    child, a crash is a ``ValueError`` naming the file and the decoder's lines go into the
    message, not onto the terminal (about 0.1 s per file).
    """
    try:
        proc = subprocess.run([sys.executable, "-c", _WSQ_CHILD, os.fspath(path)],
                              capture_output=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired as exc:
        raise ValueError(f"{path}: not a readable image (the WSQ decoder took over "
                         f"{timeout:g} s)") from exc
    lines = [" ".join(line.split())[:160]
             for line in proc.stderr.decode("utf-8", "replace").splitlines() if line.strip()]
    native = [line for line in lines if line.startswith("ERROR")]
    if proc.returncode < 0:
        try:
            name = signal.Signals(-proc.returncode).name
        except ValueError:
            name = f"signal {-proc.returncode}"
        said = f"; {native[0]}" if native else ""
        raise ValueError(f"{path}: not a readable image (the WSQ decoder crashed: {name}{said})")
    if proc.returncode != 0:
        said = lines[-1] if lines else f"exit status {proc.returncode}"
        said += f"; {native[0]}" if native and native[0] != said else ""
        raise ValueError(f"{path}: not a readable image ({said})")
    header, _, pixels = proc.stdout.partition(b"\n")
    try:
        width, height = (int(v) for v in header.split())
    except ValueError as exc:
        raise ValueError(f"{path}: not a readable image (WSQ decoder output)") from exc
    image = np.frombuffer(pixels, dtype=np.uint8)
    if image.size != width * height:
        raise ValueError(f"{path}: not a readable image (WSQ decoder output)")
    if native:
        warnings.warn(f"{path}: the WSQ decoder reported {native[0]!r} ({len(native)} "
                      "message(s)); the image may be damaged", stacklevel=3)
    return image.reshape(height, width).copy()


def _short(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 120 else text[:117] + "..."


def write_print_image(path: str | os.PathLike, image, *, ppi: float = 500.0) -> Path:
    """Write a print ``(H, W) uint8`` as PNG (with its dpi) or WSQ (by suffix), atomically.

    WSQ (``.wsq``, lossy, bit rate 0.75) records ``PPI 500`` whatever the image, so it is
    refused for another `ppi`.

    Raises
    ------
    ValueError
        If `image` is not a non-empty 2-D uint8 array, or WSQ is asked for at another ppi.
    """
    import wsq  # noqa: F401

    path = Path(path)
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 2 or image.size == 0:
        raise ValueError(f"image: expected a non-empty (H, W) uint8 array, got {image.dtype} "
                         f"{image.shape}")
    is_wsq = path.suffix.lower() == ".wsq"
    if is_wsq and abs(ppi - 500.0) > 1e-6:
        raise ValueError(f"{path}: the WSQ writer records 500 ppi only, got ppi={ppi}")
    with atomic_path(path) as tmp:
        if is_wsq:
            Image.fromarray(image).save(tmp, format="WSQ")
        else:
            Image.fromarray(image).save(tmp, format="PNG", dpi=(float(ppi), float(ppi)))
    return path
